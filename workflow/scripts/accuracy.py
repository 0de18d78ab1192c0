"""Every method, surrogate and baseline against the expected fields of the test moulds."""
from condor.stages import start_job
from condor.stages.studies import accuracy

accuracy(start_job(snakemake), snakemake.params.store, snakemake.input.sweeps,
         dict(zip(snakemake.params.variants, snakemake.input.checkpoints)),
         snakemake.output.accuracy, snakemake.output.statistics, snakemake.output.calibration,
         snakemake.output.chart, snakemake.output.spread_chart,
         snakemake.output.statistics_test, snakemake.output.calibration_test,
         snakemake.output.accuracy_test,
         {key: snakemake.output[f"{key}_lab"]
          for key in ("accuracy", "statistics", "calibration", "families")})
