"""A few samples' moulds and 8 fields, as the paper's example figure shows them."""
from condor.figures import sample_panels
from condor.pipeline import setup_logging, store_path

setup_logging(snakemake.log[0])
sample_panels(store_path(snakemake.config), snakemake.output[0], n=4)
