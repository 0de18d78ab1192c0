"""Named model variants: flat settings (as the workflow config and the CLI spell them) ->
TrainConfig, and the `surrogate:` section of the workflow config.

A variant's settings are a flat dict: `model` (one of MODEL_KINDS) plus any of
SETTING_KEYS. U-Net keys (base, depth, max_width, n_dropout, dropout, upsample) size the
generator of "unet_gan"/"unet_l1"/"unet" at the dataset's native resolution; "pix2pix" is the paper's fixed
256 px networks and takes no U-Net key.
"""

from __future__ import annotations

import os
import re
import shutil
from pathlib import Path

from .models import UNetConfig
from .train import MODEL_KINDS, TrainConfig, train

UNET_KEYS = ("base", "depth", "max_width", "n_dropout", "dropout", "upsample")
TRAIN_KEYS = ("epochs", "batch_size", "lr", "lam", "adversarial_target", "seed", "val_every",
              "max_val_samples", "prediction_mode", "num_threads", "augment", "symmetrise",
              "head", "loss", "scaling", "loss_region", "nll_weight", "detach_spread")
SETTING_KEYS = ("model",) + UNET_KEYS + TRAIN_KEYS
VARIANT_NAME = re.compile(r"^[A-Za-z][A-Za-z0-9_]*$")  # used in file names and wildcards


def train_config(settings: dict, native_size: int) -> TrainConfig:
    """TrainConfig for a variant's flat `settings` on data of `native_size` px. Keys whose
    value is None are ignored (the TrainConfig / UNetConfig.for_size default applies)."""
    given = {k: v for k, v in settings.items() if v is not None}
    unknown = sorted(set(given) - set(SETTING_KEYS))
    if unknown:
        raise ValueError(f"unknown surrogate setting(s) {unknown}; expected some of {SETTING_KEYS}")
    model = given.get("model")
    if model not in MODEL_KINDS:
        raise ValueError(f"surrogate setting model = {model!r} is not one of {MODEL_KINDS}")
    unet_kw = {k: given[k] for k in UNET_KEYS if k in given}
    if model == "pix2pix" and unet_kw:
        raise ValueError(f"surrogate settings {sorted(unet_kw)} size a U-Net, but model "
                         "'pix2pix' is the paper's fixed 256 px network")
    unet = UNetConfig.for_size(native_size, **unet_kw) if model != "pix2pix" else None
    train_kw = {k: given[k] for k in TRAIN_KEYS if k in given}
    return TrainConfig(model=model, unet=unet, **train_kw)


def workflow_variants(config: dict) -> dict[str, dict]:
    """The variants the workflow trains: {name: settings} for each name in
    config["surrogate"]["variants"], looked up in config["surrogate"]["models"]. ValueError
    names a variant that is not defined or whose name cannot be a file name."""
    section = config.get("surrogate", {})
    models = section.get("models", {})
    chosen = {}
    for name in section.get("variants", []):
        if not VARIANT_NAME.match(str(name)) or name == "baselines":
            raise ValueError(f"config key surrogate/variants: variant name {name!r} must match "
                             f"{VARIANT_NAME.pattern} and not be 'baselines'")
        if name not in models:
            raise ValueError(f"config key surrogate/variants: {name!r} is not defined under "
                             f"surrogate/models (defined: {sorted(models)})")
        chosen[name] = dict(models[name])
    return chosen


# --- the workflow's stages (thin scripts call these) ---------------------------------------

def working_checkpoint(checkpoint) -> Path:
    """Where a workflow job trains, epoch by epoch: beside the final checkpoint, hidden. It
    is not a Snakemake output, so a killed job's progress survives `--rerun-incomplete`."""
    checkpoint = Path(checkpoint)
    return checkpoint.with_name(f".{checkpoint.stem}.training{checkpoint.suffix}")


def train_variant(store, settings: dict, checkpoint, history_csv=None, threads: int | None = None,
                  device=None, log=print) -> list[dict]:
    """Train a variant on the dataset `store` (resuming a killed run's working checkpoint;
    a working checkpoint of other settings is discarded), then publish it atomically at
    `checkpoint` and its per-epoch history as `history_csv`."""
    import pandas as pd

    from condor.store import open_dataset

    from .checkpoint import CheckpointMismatchError

    ds = open_dataset(store)
    settings = dict(settings)
    if threads:
        settings["num_threads"] = threads
    cfg = train_config(settings, int(ds.sizes["x"]))
    work = working_checkpoint(checkpoint)
    try:
        history = train(ds, cfg, work, device=device, log=log)
    except CheckpointMismatchError as err:
        log(f"starting over: {err}")
        history = train(ds, cfg, work, device=device, log=log, resume=False)
    tmp = Path(checkpoint).with_name(f".{Path(checkpoint).name}.publish")
    shutil.copyfile(work, tmp)
    os.replace(tmp, checkpoint)
    if history_csv is not None:
        pd.DataFrame(history).to_csv(history_csv, index=False)
    return history


def evaluate_variant(store, checkpoint, out_dir, name: str, modes=None, device=None) -> dict:
    """Evaluate one workflow variant on the test split (no baselines: `evaluate_baselines`
    runs them once): CSV tables in out_dir, figures in out_dir/figures."""
    from condor.store import open_dataset

    from .evaluate import evaluate

    out_dir = Path(out_dir)
    return evaluate(checkpoint, open_dataset(store), out_dir=out_dir, modes=modes,
                    baselines=False, device=device, name=name, figure_dir=out_dir / "figures")


def evaluate_workflow_baselines(store, out_dir) -> dict:
    from condor.store import open_dataset

    from .evaluate import evaluate_baselines

    out_dir = Path(out_dir)
    return evaluate_baselines(open_dataset(store), out_dir=out_dir, figure_dir=out_dir / "figures")
