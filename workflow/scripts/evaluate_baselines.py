"""Evaluate the baselines on the test split, once."""
import os

from condor.stages import start_job
from condor.stages.surrogate import evaluate_store_baselines

start_job(snakemake)
evaluate_store_baselines(snakemake.params.store, os.path.dirname(snakemake.output.summary))
