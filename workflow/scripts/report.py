"""The self-contained HTML report of the run (condor.report.page)."""
from condor.report.page import condor_report
from condor.stages import start_job

condor_report(start_job(snakemake), snakemake.input, snakemake.params.store, snakemake.output[0])
