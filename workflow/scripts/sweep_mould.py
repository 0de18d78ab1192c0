"""Every simulation method of the accuracy study on one test mould."""
from condor.stages import start_job
from condor.stages.studies import sweep_mould

sweep_mould(start_job(snakemake), snakemake.input[0], int(snakemake.wildcards.mould),
            snakemake.output.fields, snakemake.output.table)
