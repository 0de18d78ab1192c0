"""Train one surrogate variant on the dataset store (resumes a killed job's epochs)."""
from condor.stages import start_job
from condor.stages.surrogate import train_variant

start_job(snakemake)
train_variant(snakemake.params.store, snakemake.params.settings, snakemake.output.checkpoint,
              snakemake.output.history, threads=snakemake.threads, device=snakemake.params.device)
