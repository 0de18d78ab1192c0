"""Evaluate one surrogate variant on the test split."""
import os

from condor.stages import start_job
from condor.stages.surrogate import evaluate_variant

start_job(snakemake)
evaluate_variant(snakemake.params.store, snakemake.input.checkpoint,
                 os.path.dirname(snakemake.output.summary), snakemake.wildcards.variant,
                 modes=snakemake.params.modes, device=snakemake.params.device)
