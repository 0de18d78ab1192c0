"""The dataset card (README.md beside the store), generated from the store."""
from condor.data.dataset import write_card
from condor.stages import start_job

config = start_job(snakemake)
write_card(snakemake.params.store, snakemake.output[0], config.to_dict())
