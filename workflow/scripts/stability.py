"""Every stability case with every solver: one table."""
from condor.stages import start_job
from condor.stages.studies import stability

stability(start_job(snakemake), snakemake.output[0])
