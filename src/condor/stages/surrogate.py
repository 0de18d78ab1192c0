"""The surrogate's stages: train a variant, evaluate it, evaluate the baselines, gather them.

Training resumes the same way from the workflow and from `condor train`: epochs are written
to a working checkpoint beside the final one (`.NAME.training.pt`, not a Snakemake output,
so a killed job's progress survives `--rerun-incomplete`), and the final checkpoint is
published atomically when training ends. Only an interrupted run of the same settings and
the same data resumes: the working checkpoint records the whole config and the fingerprint
of the data it read (condor.surrogate.train), so changed data or any changed setting
(`epochs` included) trains from scratch, and the published model always claims the config
and data it was trained with.
"""

from __future__ import annotations

import logging
import shutil
import tempfile
from pathlib import Path

import pandas as pd

from condor.config import check_device
from condor.files import WriteError, atomic_path, fault_message, write_fault
from condor.model.scenes import same_length
from condor.plots import evaluation_figures
from condor.data.store import open_store
from condor.surrogate.checkpoint import CheckpointMismatchError, load_checkpoint
from condor.surrogate.evaluate import combine_summaries, evaluate, evaluate_baselines
from condor.surrogate.train import train
from condor.surrogate.variants import train_config

log = logging.getLogger("condor")


def working_checkpoint(checkpoint) -> Path:
    """Where training writes epoch by epoch, beside the final checkpoint (hidden)."""
    checkpoint = Path(checkpoint)
    return checkpoint.with_name(f".{checkpoint.stem}.training{checkpoint.suffix}")


def check_checkpoint_path(checkpoint) -> Path:
    """ValueError when `checkpoint` cannot be a checkpoint file (a directory), WriteError
    (condor.files) when its folder cannot be written: before any epoch is spent."""
    checkpoint = Path(checkpoint)
    if checkpoint.is_dir():
        raise ValueError(f"checkpoint path {str(checkpoint)!r} is a directory; give a file "
                         "name such as model.pt")
    checkpoint.parent.mkdir(parents=True, exist_ok=True)
    try:
        tempfile.TemporaryFile(dir=checkpoint.parent).close()
    except OSError as err:
        if write_fault(err) is None:
            raise
        raise WriteError(checkpoint, err.errno, fault_message(checkpoint.parent, err)) from err
    return checkpoint


def train_variant(store, settings: dict, checkpoint, history_csv=None,
                  threads: int | None = None, device=None, fresh: bool = False,
                  restart_on_mismatch: bool = True, log_line=log.info) -> list[dict]:
    """Train a variant (flat `settings`, condor.surrogate.variants) on the dataset `store`,
    resuming its working checkpoint when that is an interrupted run of the same settings and
    data, then publish `checkpoint` and the per-epoch history CSV. A working checkpoint of
    other settings (`epochs` included) or other data is discarded and training starts from
    scratch, said in one log line: always with `restart_on_mismatch` (the workflow), else
    (the CLI) when it is finished, a copy of what was published; an interrupted one raises
    CheckpointMismatchError there, unless `fresh`, which always starts over."""
    checkpoint = check_checkpoint_path(checkpoint)
    if device is not None:
        check_device(device, "--device")
    ds = open_store(store)
    settings = dict(settings)
    if threads:
        settings["num_threads"] = threads
    cfg = train_config(settings, int(ds.sizes["x"]))
    work = working_checkpoint(checkpoint)
    if fresh:
        work.unlink(missing_ok=True)
    try:
        history = train(ds, cfg, work, device=device, log=log_line)
    except CheckpointMismatchError as err:
        if not (restart_on_mismatch or _finished(work)):
            raise CheckpointMismatchError(f"{err} (pass --fresh to start over)") from err
        log_line(f"training from scratch: {err}")
        history = train(ds, cfg, work, device=device, log=log_line, resume=False)
    with atomic_path(checkpoint) as tmp:
        shutil.copyfile(work, tmp)
    if history_csv is not None:
        with atomic_path(history_csv) as tmp:
            pd.DataFrame(history).to_csv(tmp, index=False)
    return history


def _finished(work: Path) -> bool:
    """Whether a working checkpoint ran all the epochs of its own config."""
    state = load_checkpoint(work)
    return state["epoch"] >= state["config"].get("epochs", 0)


def check_same_grid(state: dict, ds, checkpoint, store) -> None:
    """CheckpointMismatchError when a checkpoint was trained on another grid (pixels or pixel
    size, i.e. another scene) than the store's."""
    data = state["data"]
    native, pixel = int(ds.sizes["x"]), ds.attrs.get("pixel_size")
    trained_pixel = data.get("pixel_size")
    if data.get("native_size") != native or (
            pixel is not None and trained_pixel is not None
            and not same_length(pixel, trained_pixel)):
        raise CheckpointMismatchError(
            f"checkpoint {str(checkpoint)!r} was trained on {data.get('native_size')} px of "
            f"{trained_pixel} l0; store {str(store)!r} is {native} px of {pixel} l0 "
            f"(scene {ds.attrs.get('scene', {}).get('name')!r}): evaluate it on its own scene")


def evaluate_variant(store, checkpoint, out_dir, name: str | None = None, modes=None, device=None,
             baselines: bool = False, split: str = "test") -> dict:
    """One variant on `split`: CSV tables in out_dir, figures in out_dir/figures."""
    if device is not None:
        check_device(device, "--device")
    ds = open_store(store)
    check_same_grid(load_checkpoint(checkpoint), ds, checkpoint, store)
    out_dir = Path(out_dir)
    result = evaluate(checkpoint, ds, out_dir=out_dir, split=split, modes=modes,
                      baselines=baselines, device=device, name=name)
    _draw(result, out_dir / "figures")
    return result


def evaluate_store_baselines(store, out_dir) -> dict:
    """The baselines alone, with the same tables and figures as `evaluate_variant`."""
    out_dir = Path(out_dir)
    result = evaluate_baselines(open_store(store), out_dir=out_dir)
    _draw(result, out_dir / "figures")
    return result


def _draw(result: dict, folder: Path) -> None:
    for method, ev in result["evaluations"].items():
        evaluation_figures(ev, result["truth"], result["predictions"][method], folder)


def summarise(summary_csvs, out_csv) -> pd.DataFrame:
    """One table of every variant's and baseline's summary row."""
    table = combine_summaries(summary_csvs)
    table.to_csv(out_csv)
    return table
