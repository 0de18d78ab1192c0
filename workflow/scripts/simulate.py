"""Simulate every replica of every mould of one batch, one result file each."""
from condor.stages import start_job
from condor.stages.build import simulate_batch

simulate_batch(start_job(snakemake), snakemake.input.moulds, snakemake.output[0])
