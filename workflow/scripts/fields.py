"""Rasterise one batch of simulations into the store's fields."""
from condor.stages import start_job
from condor.stages.build import write_fields

write_fields(start_job(snakemake), snakemake.input.sims, snakemake.input.moulds,
             snakemake.params.store, snakemake.output[0])
