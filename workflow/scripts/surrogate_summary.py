"""Every variant's and baseline's summary row in one table."""
from condor.stages import start_job
from condor.stages.surrogate import summarise

start_job(snakemake)
summarise(snakemake.input, snakemake.output[0])
