"""The dataset's solver against the paper's CONDOR (the shipped reference anneals)."""
from condor.stages import start_job
from condor.stages.studies import fidelity

fidelity(start_job(snakemake), snakemake.output[0])
