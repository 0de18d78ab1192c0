"""The self-contained HTML report of the run (condor.report)."""
import os
from pathlib import Path

from condor.pipeline import setup_logging, store_path
from condor.report import ReportInputs, condor_report

setup_logging(snakemake.log[0])
i = snakemake.input
folders = {v: Path(p).parent for v, p in zip(snakemake.params.variants, i.evaluations)}
folders["baselines"] = Path(i.baselines).parent
inputs = ReportInputs(
    gallery=i.gallery, regimes=i.regimes, samples=i.samples, dataset_summary=i.dataset_summary,
    speed_accuracy=i.speed_accuracy, speed_accuracy_summary=i.speed_accuracy_summary,
    speed_accuracy_chart=i.speed_accuracy_chart, convergence=i.convergence,
    convergence_summary=i.convergence_summary, convergence_chart=i.convergence_chart,
    stability=i.stability, cost_accuracy=i.cost_accuracy, cost_accuracy_chart=i.cost_accuracy_chart,
    surrogate_summary=i.surrogate_summary, evaluations=folders, store=store_path(snakemake.config),
)
path = condor_report(inputs, snakemake.config, snakemake.output[0])
print(f"report: {path} ({os.path.getsize(path) / 1e6:.1f} MB)")
