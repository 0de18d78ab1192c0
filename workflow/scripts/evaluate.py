"""Evaluation on the test split: one variant (rule evaluate), the baselines (rule
evaluate_baselines), or the summary of all of them (rule surrogate_summary)."""
import logging
import os

from condor.pipeline import setup_logging, store_path
from condor.surrogate.evaluate import combine_summaries, format_correlations, format_summary
from condor.surrogate.variants import evaluate_variant, evaluate_workflow_baselines

setup_logging(snakemake.log[0])
log = logging.getLogger("condor")
if snakemake.rule == "surrogate_summary":
    summary = combine_summaries(snakemake.input)
    summary.to_csv(snakemake.output[0])
elif snakemake.rule == "evaluate_baselines":
    summary = evaluate_workflow_baselines(store_path(snakemake.config),
                                          os.path.dirname(snakemake.output.summary))["summary"]
else:
    summary = evaluate_variant(store_path(snakemake.config), snakemake.input.checkpoint,
                               os.path.dirname(snakemake.output.summary), snakemake.wildcards.variant,
                               modes=snakemake.params.modes, device=snakemake.params.device)["summary"]
log.info("mean test MAE per field:\n%s", format_summary(summary))
log.info("Pearson r, simulation vs prediction:\n%s", format_correlations(summary))
