"""Generate one batch of moulds: geometry JSON + input channels in the store."""
from condor.stages import start_job
from condor.stages.build import make_moulds

make_moulds(start_job(snakemake), snakemake.params.ids, snakemake.output[0], snakemake.params.store)
