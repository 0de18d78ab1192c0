"""Fan-in: the expected fields of replicated moulds and the per-sample table of the store."""
from condor.stages import start_job
from condor.stages.dataset import finish_dataset

start_job(snakemake)
finish_dataset(snakemake.params.store, snakemake.output[0])
