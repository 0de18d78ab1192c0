# The Config (validated once), the results folder's checks, paths, and the helpers the rules
# use. Rules only declare: inputs, outputs, params, resources and a script calling one stage.
import sys
from pathlib import Path

from condor.config import Config, ConfigError
from condor.folder import FolderError, RunLock, check_folder, store_gaps, store_path

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


# --- repairs: a flag file claims a batch is done but the store lost its samples ---------------
# The main process compares the flags with the store (condor.folder.store_gaps: chunk files
# listed and their headers read; only the flags and the layout decompressed). Each stale
# job gets a marker input, touched now, so it is newer than the job's flag and Snakemake
# reruns exactly those jobs (and, by mtime, what follows them); `snakemake -n` shows them.
# A marker is an input only while its job is stale; results/.repair keeps them as a record.
# Lost inputs are written again by the batch's fields job, from the moulds JSON its
# simulations used (rerunning the moulds job would rerun the simulations, whose timings
# differ); the layout and the expected fields by the dataset job.
REPAIR = {"init_store": False, "simulate": set(), "fields": set(), "dataset": False}
if workflow.is_main_process and Path(STORE_MANIFEST).exists():
    if not Path(STORE).exists():
        REPAIR["init_store"] = True
    else:
        GAPS = store_gaps(STORE)
        for _b, _ids in enumerate(BATCHES):
            _bid, _ids = f"{_b:04d}", set(_ids)
            fields_done = Path(f"{R}/fields/batch_{_bid}.json").exists()
            if fields_done and GAPS["fields"] & _ids:
                REPAIR["fields"].add(_bid)
            sims = Path(f"{R}/sims/batch_{_bid}")
            lost = sims.exists() and any(
                not (sims / f"{m:06d}_{r:02d}.npz").exists() for m in _ids for r in range(REPLICAS[m]))
            if lost and (not fields_done or _bid in REPAIR["fields"]):
                REPAIR["simulate"].add(_bid)
        REPAIR["dataset"] = bool(GAPS["dataset"]) and Path(f"{R}/dataset_summary.csv").exists()


def repair_marker(stage, batch="all"):
    return Path(f"{R}/.repair/{stage}_{batch}")


for _stage, _stale in REPAIR.items():
    for _bid in (["all"] if _stale is True else [] if _stale is False else sorted(_stale)):
        repair_marker(_stage, _bid).parent.mkdir(parents=True, exist_ok=True)
        repair_marker(_stage, _bid).touch()


def repair(stage):
    """Input function: the touched marker of a job the store shows to be stale, else nothing."""

    def marker(wildcards):
        batch = getattr(wildcards, "batch", None)
        stale = REPAIR[stage] if batch is None else batch in REPAIR[stage]
        return [str(repair_marker(stage, batch or "all"))] if stale else []

    return marker


localrules:
    all,
    init_store,
    dataset,
    dataset_card,
