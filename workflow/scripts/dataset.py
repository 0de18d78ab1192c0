"""Fan-in: the store's layout where damaged, the expected fields of replicated moulds and the
per-sample table of the store."""
import sys

from condor.stages import start_job
from condor.stages.build import IncompleteStoreError, finish_dataset

config = start_job(snakemake)
try:
    finish_dataset(snakemake.params.store, snakemake.output[0], split=config.splits())
except IncompleteStoreError as err:
    sys.exit(f"condor: {err}")  # one line, no traceback
