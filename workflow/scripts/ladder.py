"""The anneal ladder against the dataset solver's replicas."""
from condor.stages import start_job
from condor.stages.studies import ladder

ladder(start_job(snakemake), snakemake.params.store, snakemake.input.moulds, snakemake.output[0])
