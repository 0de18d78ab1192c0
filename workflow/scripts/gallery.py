"""The mould gallery figure and the regime/removal frequency table."""
from condor.stages import start_job
from condor.stages.build import write_gallery

start_job(snakemake)
write_gallery(snakemake.input, snakemake.params.n, snakemake.output.gallery, snakemake.output.regimes)
