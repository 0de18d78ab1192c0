"""Create the dataset store (or accept a matching one) and warm numba's kernel cache once,
before the per-batch jobs fan out."""
from condor.pipeline import init_store, setup_logging, warm_kernels

setup_logging(snakemake.log[0])
warm_kernels()
created = init_store(snakemake.config)
print("store created" if created else "store exists and matches the config; kept")
