"""Simulate one batch of moulds, one result file per mould."""
from condor.pipeline import setup_logging, simulate_moulds

setup_logging(snakemake.log[0])
simulate_moulds(snakemake.config, snakemake.input[0], snakemake.output[0])
