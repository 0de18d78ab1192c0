"""Create the dataset store (or keep the matching one) and warm numba's kernel cache once."""
from condor.stages import start_job
from condor.stages.build import init_store

init_store(start_job(snakemake), snakemake.params.store, snakemake.output[0])
