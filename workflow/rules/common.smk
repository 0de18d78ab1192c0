# The Config (validated once), the results folder's checks, paths, and the helpers the rules
# use. Rules only declare: inputs, outputs, params, resources and a script calling one stage.
import sys
from pathlib import Path

from snakemake.io import strip_wildcard_constraints

from condor.config import Config, ConfigError
from condor.folder import FolderError, RunLock, check_folder, data_files, store_path

try:
    CONFIG = Config.from_dict(config)
    check_folder(CONFIG)
except (ConfigError, FolderError) as err:
    sys.exit(f"condor: {err}")  # one line, no traceback, nothing run

R = str(CONFIG.results)
STORE = str(store_path(R))
# init_store's output: the store exists and matches the config. The store itself is not a
# Snakemake output on purpose: Snakemake deletes outputs before re-running a job, and
# --forcerun init_store must never delete samples.
STORE_MANIFEST = f"{R}/dataset.json"
BATCHES = CONFIG.batches()
BATCH_IDS = [f"{b:04d}" for b in range(len(BATCHES))]
REPLICAS = CONFIG.replicas()
CONDA_ENV = "../envs/condor.yaml"  # software for --software-deployment-method conda
FINAL_TARGETS = []  # each stage file appends the outputs `all` needs


wildcard_constraints:
    batch=r"\d{4}",
    mould=r"\d+",


def batch_ids(wildcards):
    return list(BATCHES[int(wildcards.batch)])


def evaluation_tables(prefix):
    """The per-method CSV tables the surrogate evaluation writes into one folder."""
    return [f"{prefix}_{table}.csv" for table in ("mae", "correlations")]


def report_settings(*keys):
    """Report settings as params: changing one reruns exactly the jobs that use it."""
    return {k: CONFIG.to_dict()["report"][k] for k in keys}


def report_inputs(wildcards):
    """Every file the report reads, by the key condor.report.page.REPORT_INPUTS names it with."""
    return {
        "dataset_summary": rules.dataset.output[0],
        "regimes": rules.gallery.output.regimes,
        "gallery": rules.gallery.output.gallery,
        "samples": rules.sample_figure.output[0],
        "accuracy": rules.accuracy.output.accuracy,
        "statistics": rules.accuracy.output.statistics,
        "accuracy_chart": rules.accuracy.output.chart,
        "calibration": rules.accuracy.output.calibration,
        "statistics_test": rules.accuracy.output.statistics_test,
        "accuracy_test": rules.accuracy.output.accuracy_test,
        "calibration_test": rules.accuracy.output.calibration_test,
        "accuracy_lab": rules.accuracy.output.accuracy_lab,
        "statistics_lab": rules.accuracy.output.statistics_lab,
        "calibration_lab": rules.accuracy.output.calibration_lab,
        "families_lab": rules.accuracy.output.families_lab,
        "spread_chart": rules.accuracy.output.spread_chart,
        "ladder": rules.ladder.output[0],
        "convergence": rules.convergence.output.table,
        "convergence_chart": rules.convergence.output.chart,
        "stability": rules.stability.output[0],
        "fidelity": rules.fidelity.output[0],
        "surrogate_summary": rules.surrogate_summary.output[0],
        "evaluations": [*expand(f"{EVALUATION}/{{variant}}/figures", variant=list(VARIANTS)),
                        f"{EVALUATION}/baselines/figures"],
        "histories": expand(f"{R}/models/{{variant}}_history.csv", variant=list(VARIANTS)),
        "design_table": rules.design.output.table,
        "design_summary": rules.design.output.summary,
        "design_confirmation": rules.design.output.confirmation,
        "design_history": rules.design.output.history,
        "design_figure": rules.design.output.designs,
    }


def moulds_of_batch(mould):
    """The moulds JSON of the batch that holds `mould`."""
    return f"{R}/moulds/batch_{int(mould) // CONFIG.batch_size:04d}.json"


# The rules whose outputs are the per-batch files the store is built from (moulds/, sims/,
# fields/): made again when the store needs them (repair.smk), not for their own sake.
INTERMEDIATE = ("moulds", "simulate", "fields")


def every_output():
    """Every output of every rule but `all`'s and INTERMEDIATE's, for each value of its
    wildcards, that FINAL_TARGETS lacks: `all` asks for them all, so that a deleted one is
    built again (Snakemake reruns a job for a missing output only when a job that reads it
    runs, or when a target asks for it)."""
    values = {"batch": BATCH_IDS, "variant": list(VARIANTS), "mould": list(map(str, STUDY_MOULDS))}
    wanted = set(map(str, FINAL_TARGETS))
    found = []
    for declared in workflow.rules:
        if declared.name == "all" or declared.name in INTERMEDIATE:
            continue
        for pattern in declared.output:
            found += [path for path in expand(strip_wildcard_constraints(str(pattern)),
                                              **{name: values[name]
                                                 for name in declared.wildcard_names})
                      if path not in wanted and path not in found]
    return found


localrules:
    all,
    init_store,
    dataset,
    dataset_card,
