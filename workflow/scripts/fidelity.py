"""The dataset's solver and the surrogates against the paper's CONDOR (the shipped reference
anneals)."""
from condor.stages import start_job
from condor.stages.studies import fidelity

fidelity(start_job(snakemake), dict(zip(snakemake.params.variants, snakemake.input.checkpoints)),
         snakemake.output[0])
