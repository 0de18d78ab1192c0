"""Fan-in: per-sample state of the finished store, as a CSV."""
from condor.pipeline import setup_logging, store_path
from condor.store import check_store

setup_logging(snakemake.log[0])
table = check_store(store_path(snakemake.config))
table.to_csv(snakemake.output[0], index=False)
print(table["state"].value_counts().to_string())
