# --- repairs: a flag file claims a batch is done but the store lost its samples ---------------
# The main process compares the flags with the store (condor.folder.store_gaps: chunk files
# listed and their headers read; only the flags and the layout decompressed). Each stale
# job gets a marker input, touched now, so it is newer than the job's flag and Snakemake
# reruns exactly those jobs (and, by mtime, what follows them); `snakemake -n` shows them.
# A marker is an input only while its job is stale; results/.repair keeps them as a record.
# Lost inputs are written again by the batch's fields job, from the moulds JSON its
# simulations used (rerunning the moulds job would rerun the simulations, whose timings
# differ); the layout and the expected fields by the dataset job.
#
# A deleted store (or its manifest, dataset.json) is built again the same way, from the
# folder's own files: check_folder has found the folder's record to match the config (a
# changed data key stops the run before this), init_store creates the store, every batch's
# fields job writes its inputs and fields again, the dataset job the rest. Meanwhile a job
# that waits for the store (`store_first`: moulds, fields, stability, fidelity), has its
# outputs and is not stale does not wait for it, so that it does not run again (the moulds'
# simulations would follow them; a manifest deleted alone reruns init_store alone).
from condor.folder import store_gaps, unwritable

REPAIR = {"init_store": False, "simulate": set(), "fields": set(), "dataset": False}
REBUILD = False  # the store or its manifest is gone from a folder that holds data
if workflow.is_main_process:
    REBUILD = bool(data_files(R)) and not (Path(STORE).exists() and Path(STORE_MANIFEST).exists())
    if Path(STORE).exists():
        GAPS = store_gaps(STORE, CONFIG.splits())
    else:  # nothing is in the store
        REPAIR["init_store"] = Path(STORE_MANIFEST).exists()
        GAPS = {"inputs": set(range(CONFIG.n_moulds)), "fields": set(range(CONFIG.n_moulds)),
                "dataset": {"the store"}}
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


try:
    for _stage, _stale in REPAIR.items():
        for _bid in (["all"] if _stale is True else [] if _stale is False else sorted(_stale)):
            repair_marker(_stage, _bid).parent.mkdir(parents=True, exist_ok=True)
            repair_marker(_stage, _bid).touch()
except OSError as err:  # a read-only folder (a dry run takes no lock, which would say so)
    sys.exit(f"condor: {unwritable(R, err)}")


def repair(stage):
    """Input function: the touched marker of a job the store shows to be stale, else nothing."""

    def marker(wildcards):
        batch = getattr(wildcards, "batch", None)
        stale = REPAIR[stage] if batch is None else batch in REPAIR[stage]
        return [str(repair_marker(stage, batch or "all"))] if stale else []

    return marker


def store_first(rule):
    """Input function: the store's manifest, which a job of `rule` waits for (it writes or
    reads the store, or uses the numba cache init_store warms); not while the store is built
    again (REBUILD) for a job whose outputs are all there and that is not stale (above).
    `ancient`: a manifest written again (a rebuild, --forcerun init_store) is not newer input
    to the moulds and studies made before it, which would run them all again."""

    def manifest(wildcards):
        outputs = expand([str(p) for p in getattr(rules, rule).output], **dict(wildcards.items()))
        batch = getattr(wildcards, "batch", None)
        stale = batch in REPAIR[rule] if rule in REPAIR and batch is not None else False
        done = all(Path(p).exists() for p in outputs) and not stale
        return [] if REBUILD and done else [ancient(STORE_MANIFEST)]

    return manifest
