"""The scene convergence study (depth and box size against seed noise)."""
from condor.stages import start_job
from condor.stages.studies import convergence

convergence(start_job(snakemake), snakemake.input[0], snakemake.params.mould,
            snakemake.output.table, snakemake.output.chart)
