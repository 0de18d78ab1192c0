"""Rasterise one batch of simulations into the store's fields."""
from condor.pipeline import setup_logging, store_path, write_fields

setup_logging(snakemake.log[0])
write_fields(snakemake.config, snakemake.input.sims, snakemake.input.moulds, store_path(snakemake.config),
             snakemake.output[0])
