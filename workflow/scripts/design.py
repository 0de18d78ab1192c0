"""Design moulds for the configured objective; confirm by simulation; hand over drawings."""
import os

from condor.stages import start_job
from condor.stages.design import design

config = start_job(snakemake)
s = snakemake.params.settings
design(config.scene, snakemake.input.checkpoint, os.path.dirname(snakemake.output.table),
       s["objective"], budget=s["budget"], seed=s["seed"], n_top=s["top"], n_random=s["random"],
       replicas=s["replicas"], store=snakemake.params.store, l0_um=s["l0_um"],
       solver=config.solver()[0], force=True)
