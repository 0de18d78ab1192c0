"""Train one surrogate variant on the dataset store (resumes a killed job's epochs)."""
import logging

from condor.pipeline import setup_logging, store_path
from condor.surrogate.variants import train_variant

setup_logging(snakemake.log[0])
train_variant(store_path(snakemake.config), snakemake.params.settings, snakemake.output.checkpoint,
              snakemake.output.history, threads=snakemake.threads, device=snakemake.params.device,
              log=logging.getLogger("condor").info)
