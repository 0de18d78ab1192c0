"""Named model variants: flat settings (as the workflow config and the CLI spell them) ->
TrainConfig, and the `surrogate:` section of the workflow config.

A variant's settings are a flat dict: `model` (one of MODEL_KINDS) plus any of
SETTING_KEYS. U-Net keys (base, depth, max_width, n_dropout, dropout, upsample, blocks) size
the generator of "unet_gan"/"unet_l1"/"unet" at the dataset's native resolution; "pix2pix" is
the paper's fixed 256 px networks and takes no U-Net key.
"""

from __future__ import annotations

import re

from .models import UNetConfig
from .train import MODEL_KINDS, TrainConfig

UNET_KEYS = ("base", "depth", "max_width", "n_dropout", "dropout", "upsample", "blocks")
TRAIN_KEYS = ("epochs", "batch_size", "lr", "betas", "lam", "adversarial_target", "seed",
              "val_every", "max_val_samples", "prediction_mode", "num_threads", "augment",
              "symmetrise", "head", "loss", "scaling", "loss_region", "nll_weight", "sum_weight",
              "field_weights", "area_weight", "tension_floor", "detach_spread", "replicas",
              "lr_schedule", "inputs")
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


def workflow_variants(config) -> dict[str, dict]:
    """The variants the workflow trains: {name: settings} for each name in the Config's
    surrogate["variants"], looked up in surrogate["models"]. ValueError names a variant that
    is not defined or whose name cannot be a file name."""
    section = config.surrogate
    models = section["models"]
    chosen = {}
    for name in section["variants"]:
        if not VARIANT_NAME.match(str(name)) or name == "baselines":
            raise ValueError(f"config key surrogate/variants: variant name {name!r} must match "
                             f"{VARIANT_NAME.pattern} and not be 'baselines'")
        if name not in models:
            raise ValueError(f"config key surrogate/variants: {name!r} is not defined under "
                             f"surrogate/models (defined: {sorted(models)})")
        chosen[name] = dict(models[name])
    return chosen
