"""Named model variants: the registry of presets (`PRESETS`; `unet` is the default run's),
flat settings (as the workflow config and the CLI spell them) -> TrainConfig, and the
`surrogate:` section of the workflow config.

A variant's settings are a flat dict: `model` (the network kind, one of
train.NETWORK_KINDS: TrainConfig.network; the workflow config spells it `model`) plus any of
SETTING_KEYS. U-Net keys (base, depth, max_width, n_dropout, dropout, upsample, blocks) size
the generator of "unet_gan"/"unet_l1"/"unet" at the dataset's native resolution; "pix2pix" is
the paper's fixed 256 px networks and takes no U-Net key. A setting left out takes
TrainConfig's field default (the paper's settings) or UNetConfig.for_size's (base 32, down to
a 4x4 bottleneck); a preset names only what it changes from them, and a workflow config's
`surrogate: models:` entry names only what it changes from its preset (`resolve`).
"""

from __future__ import annotations

import re
from types import MappingProxyType

from .settings import NETWORK_KINDS, TrainConfig, UNetConfig

UNET_KEYS = ("base", "depth", "max_width", "n_dropout", "dropout", "upsample", "blocks")
TRAIN_KEYS = ("epochs", "batch_size", "lr", "betas", "lam", "adversarial_target", "seed",
              "val_every", "max_val_samples", "prediction_mode", "num_threads", "augment",
              "symmetrise", "head", "loss", "scaling", "loss_region", "nll_weight", "sum_weight",
              "field_weights", "area_weight", "tension_floor", "noise_weight", "detach_spread",
              "replicas", "lr_schedule", "inputs")
SETTING_KEYS = ("model",) + UNET_KEYS + TRAIN_KEYS
VARIANT_NAME = re.compile(r"^[A-Za-z][A-Za-z0-9_]*$")  # used in file names and wildcards

# The registry: the one home of every named recipe. `unet` is the default run's (the schema's
# surrogate/variants); the studies behind each of its settings are in docs/experiments (and
# docs/surrogate.md's sections named below).
PRESETS = MappingProxyType({
    "unet": MappingProxyType({
        "model": "unet",
        # the physics head: sum P = N_c, Sx2+Sy2+Sz2 = P and a spread map; its loss the mean's
        # squared error + the spread's NLL; the spread reads the last features without
        # training them (TrainConfig.detach_spread's default)
        "head": "physics", "loss": "gaussian",
        "upsample": "bilinear",             # checkerboard-free decoder (the cause study)
        "n_dropout": 0, "lr_schedule": "cosine",  # the recipe study: T field error -20%
        # experiments/generalisation: on 250 moulds half from the lab families, 120 epochs
        # against 60 took the paper test moulds from 0.80x to 0.70x one simulation's scatter,
        # a fresh generator seed's from 0.73x to 0.61x, the worst lab family from 1.68x to 1.35x
        "epochs": 120,
        "batch_size": 8, "lr": 0.002,
        "betas": (0.9, 0.999),              # "Adam's momentum": not the paper's GAN 0.5
        "augment": True, "symmetrise": True,  # train on, and predict the mean of, the 16 symmetries
        "inputs": "mechanics",              # "The inputs", "A mechanical prior"
        "field_weights": (2, 1, 2, 2, 1, 0.5, 0.5, 0.5), "area_weight": 1.0,  # "Weighing the fields"
        "tension_floor": 0.5,               # "196 moulds": each mould's T error relative to its own
        # each mould's error against its own predicted scatter, as the noise ceiling scores it
        # (experiments/generalisation/README.md, "Each mould's error against its own scatter")
        "noise_weight": 1.0,
        "val_every": 10,                    # a diagnostic: a quarter of each epoch's time saved
    }),
    # the previous default (L1 on [-1, 1]-scaled fields): biased low
    "unet_l1": MappingProxyType({"model": "unet_l1", "epochs": 240, "batch_size": 8, "lr": 0.002,
                                 "augment": True, "symmetrise": True}),
    "unet_gan": MappingProxyType({"model": "unet_gan", "base": 16, "epochs": 40, "batch_size": 8,
                                  "lr": 0.001, "lam": 100}),
    "pix2pix": MappingProxyType({"model": "pix2pix"}),  # the paper's networks and settings (256 px)
})


def preset(name: str) -> dict:
    """A copy of the registry's preset `name`; ValueError names the presets."""
    if name not in PRESETS:
        raise ValueError(f"no model variant preset {name!r}; presets: {sorted(PRESETS)}")
    return dict(PRESETS[name])


def resolve(name: str, models=None) -> dict:
    """The flat settings of variant `name`: its preset (the entry's `preset`, else the preset
    of the same name) with what the `models` entry of that name changes. A name that is no
    preset needs an entry that names a `preset` or a `model`."""
    entry = dict((models or {}).get(name, {}))
    base = entry.pop("preset", name if name in PRESETS else None)
    if base is None and "model" not in entry:
        raise ValueError(f"variant {name!r} is no preset ({sorted(PRESETS)}) and its entry "
                         "under surrogate/models names neither a preset nor a model")
    settings = preset(base) if base is not None else {}
    settings.update(entry)
    return settings


def train_config(settings: dict, native_size: int) -> TrainConfig:
    """TrainConfig for a variant's flat `settings` on data of `native_size` px. Keys whose
    value is None are ignored (the TrainConfig / UNetConfig.for_size default applies)."""
    given = {k: v for k, v in settings.items() if v is not None}
    unknown = sorted(set(given) - set(SETTING_KEYS))
    if unknown:
        raise ValueError(f"unknown surrogate setting(s) {unknown}; expected some of {SETTING_KEYS}")
    model = given.get("model")
    if model not in NETWORK_KINDS:
        raise ValueError(f"surrogate setting model = {model!r} is not one of {NETWORK_KINDS}")
    unet_kw = {k: given[k] for k in UNET_KEYS if k in given}
    if model == "pix2pix" and unet_kw:
        raise ValueError(f"surrogate settings {sorted(unet_kw)} size a U-Net, but model "
                         "'pix2pix' is the paper's fixed 256 px network")
    unet = UNetConfig.for_size(native_size, **unet_kw) if model != "pix2pix" else None
    train_kw = {k: given[k] for k in TRAIN_KEYS if k in given}
    return TrainConfig(network=model, unet=unet, **train_kw)


def workflow_variants(config) -> dict[str, dict]:
    """The variants the workflow trains: {name: settings} for each name in the Config's
    surrogate["variants"], resolved from the registry and surrogate["models"] (`resolve`).
    ValueError names a variant that is not defined or whose name cannot be a file name."""
    section = config.surrogate
    models = section["models"]
    chosen = {}
    for name in section["variants"]:
        if not VARIANT_NAME.match(str(name)) or name == "baselines":
            raise ValueError(f"config key surrogate/variants: variant name {name!r} must match "
                             f"{VARIANT_NAME.pattern} and not be 'baselines'")
        if name not in models and name not in PRESETS:
            raise ValueError(f"config key surrogate/variants: {name!r} is neither a preset "
                             f"({sorted(PRESETS)}) nor defined under surrogate/models "
                             f"(defined: {sorted(models)})")
        try:
            chosen[name] = resolve(name, models)
        except ValueError as err:
            raise ValueError(f"config key surrogate/models/{name}: {err}") from None
    return chosen
