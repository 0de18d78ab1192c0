"""A few samples' moulds and 8 fields, as the paper's example figure shows them."""
from condor.stages import start_job
from condor.stages.build import sample_figure

start_job(snakemake)
sample_figure(snakemake.params.store, snakemake.output[0])
