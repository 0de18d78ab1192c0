"""The surrogate's settings without torch: the training recipe (TrainConfig, its allowed
values), the networks' shapes (UNetConfig, PatchConfig) and what a model reads
(INPUT_VARIABLES), so that a config is checked (condor.config: at every `snakemake` start)
without importing torch, which costs about a second. condor.surrogate.train, .networks and
.samples build on them and export the same names.
"""

from __future__ import annotations

import math
from dataclasses import asdict, dataclass, replace

import numpy as np

from condor.data.fields import FIELD_NAMES
from condor.data.inputs import INPUT_KINDS

from .modes import PREDICTION_MODES

UPSAMPLE_MODES = ("transpose", "resize", "bilinear")
OUTPUT_ACTIVATIONS = ("tanh", "linear")
PAPER_SIZE = 256
PAPER_GENERATOR_PARAMETERS = 54_435_080  # Appendix table, BN running statistics included
PAPER_DISCRIMINATOR_PARAMETERS = 2_774_529
PAIRED_FIELDS = (("Sx2", "Sy2"), ("SxSz", "SySz"))  # swapped by the transpose: one range
PHYSICS_OUTPUTS = 16  # the physics head's channels: 8 for the fields, 8 for their spread

# What a model reads (TrainConfig.inputs, condor.data.inputs): the store variables of each kind,
# two channels each, in this order.
INPUT_VARIABLES = {"mask": ("inputs",), "lattice": ("lattice",), "both": ("inputs", "lattice"),
                   "mechanics": ("inputs", "lattice", "stress"),
                   "mechanics_shear": ("inputs", "lattice", "stress_tensor")}
# Inputs computed from a store variable, not stored: condor.data.inputs.DERIVED_CHANNELS from
# the masks (stress: sigma_xx, sigma_yy; stress_tensor: and sigma_xy).
DERIVED_INPUTS = {"stress": "inputs", "stress_tensor": "inputs"}
VARIABLE_CHANNELS = {"inputs": 2, "lattice": 2, "stress": 2, "stress_tensor": 3}


def n_input_channels(kind: str) -> int:
    """Channels a network of inputs `kind` reads (the sum over its INPUT_VARIABLES)."""
    return sum(VARIABLE_CHANNELS[name] for name in INPUT_VARIABLES[kind])


def check_field_weights(weights) -> np.ndarray:
    """`weights` as 8 floats normalised to mean 1; ValueError unless they are finite, >= 0,
    not all 0, and equal within each transpose pair (PAIRED_FIELDS)."""
    w = np.asarray(weights, dtype=np.float64).reshape(-1)
    if w.shape != (len(FIELD_NAMES),) or not np.all(np.isfinite(w)) or np.any(w < 0) \
            or w.sum() <= 0:
        raise ValueError(f"field_weights must be {len(FIELD_NAMES)} finite values >= 0, not all "
                         f"0 (one per field of {FIELD_NAMES}), got {list(weights)}")
    for a, b in PAIRED_FIELDS:
        if w[FIELD_NAMES.index(a)] != w[FIELD_NAMES.index(b)]:
            raise ValueError(f"field_weights of {a} and {b} must be equal (a transpose swaps "
                             f"them), got {w[FIELD_NAMES.index(a)]} and {w[FIELD_NAMES.index(b)]}")
    return w / w.mean()


@dataclass(frozen=True)
class UNetConfig:
    """A pix2pix-style U-Net generator.

    size: input side in pixels (must be divisible by 2**depth); base: channels of the first
    level; depth: number of stride-2 levels (log2(size) reaches a 1x1 bottleneck, as the
    paper); max_width: channel cap; n_dropout: decoder blocks (from the bottleneck) with dropout;
    blocks: residual 3x3 convolution blocks after each level's resampling convolution, in the
    encoder and the decoder (0: the paper's one convolution per level).
    """

    in_channels: int = 2
    out_channels: int = 8
    size: int = PAPER_SIZE
    base: int = 64
    depth: int = 8
    max_width: int = 512
    n_dropout: int = 3
    dropout: float = 0.5
    leaky_slope: float = 0.3
    upsample: str = "transpose"
    output: str = "tanh"
    detached_outputs: int = 0
    blocks: int = 0

    def __post_init__(self):
        if self.upsample not in UPSAMPLE_MODES:
            raise ValueError(f"UNetConfig.upsample {self.upsample!r} is not one of {UPSAMPLE_MODES}")
        if self.output not in OUTPUT_ACTIVATIONS:
            raise ValueError(f"UNetConfig.output {self.output!r} is not one of "
                             f"{OUTPUT_ACTIVATIONS}")
        for name in ("in_channels", "out_channels", "size", "base", "depth", "max_width"):
            if getattr(self, name) < 1:
                raise ValueError(f"UNetConfig.{name} must be >= 1, got {getattr(self, name)}")
        if self.blocks < 0:
            raise ValueError(f"UNetConfig.blocks must be >= 0, got {self.blocks}")
        if not 0 <= self.detached_outputs <= self.out_channels:
            raise ValueError(f"UNetConfig.detached_outputs={self.detached_outputs} is not in "
                             f"[0, out_channels={self.out_channels}]")
        if self.size % (2 ** self.depth):
            raise ValueError(f"UNetConfig.size={self.size} is not divisible by "
                             f"2**depth={2 ** self.depth}")
        if not 0.0 <= self.dropout < 1.0:
            raise ValueError(f"UNetConfig.dropout must be in [0, 1), got {self.dropout}")

    @classmethod
    def paper(cls) -> "UNetConfig":
        """The Appendix generator: 2 -> 8 channels at 256 px, 8 levels, widths 64..512."""
        return cls()

    @classmethod
    def for_size(cls, size: int, base: int = 32, depth: int | None = None,
                 max_width: int = 256, **kw) -> "UNetConfig":
        """A right-sized U-Net: `depth` defaults to reaching a 4x4 bottleneck."""
        if depth is None:
            depth = max(1, int(math.log2(size)) - 2)
        return cls(size=size, base=base, depth=depth, max_width=max_width, **kw)

    def widths(self) -> list[int]:
        return [min(self.base * 2 ** i, self.max_width) for i in range(self.depth)]

    def to_dict(self) -> dict:
        return asdict(self)


@dataclass(frozen=True)
class PatchConfig:
    """A PatchGAN discriminator: `n_down` stride-2 convolutions, then two stride-1
    convolutions behind zero padding. n_down=3 at 256 px is the paper's 70x70, 30x30 output."""

    in_channels: int = 10
    base: int = 64
    n_down: int = 3
    max_width: int = 512
    leaky_slope: float = 0.3

    def __post_init__(self):
        if self.n_down < 1 or self.base < 1 or self.in_channels < 1:
            raise ValueError(f"invalid PatchConfig {self}")

    def output_side(self, size: int) -> int:
        return size // 2 ** self.n_down - 2

    def to_dict(self) -> dict:
        return asdict(self)


NETWORK_KINDS = ("pix2pix", "unet_gan", "unet_l1", "unet")
HEADS = ("tanh", "physics")
LOSSES = ("l1", "mse", "gaussian")
SCALINGS = ("minmax", "standard")
LOSS_REGIONS = ("all", "tissue")
# How training uses the replicas of a training mould (simulation.replicas.train > 1): replica
# 0 only, every replica as a sample, or replica 0's inputs with the replicas' mean as target.
REPLICA_USES = ("first", "all", "mean")
# Learning rate over the run: constant, or a cosine from lr down to 0 at the last epoch (the
# final weights then settle instead of drifting with Adam's step; docs/surrogate.md).
LR_SCHEDULES = ("constant", "cosine")
# Config keys that may change between a run and its resumption: resources only. Every
# training setting, `epochs` included, is part of what a checkpoint claims; another value is
# another run (resuming is for an interrupted run of the identical config and data).
RESUMABLE_KEYS = {"num_threads"}


@dataclass
class TrainConfig:
    """Training settings; the field defaults are the paper's (pix2pix, lambda 1000, Adam 2e-4,
    betas 0.5/0.999, batch 1, 10 epochs): the baseline every preset of
    condor.surrogate.variants.PRESETS names its changes against, and what a checkpoint written
    before a setting existed is read with (`_check_resumable`). The default network is the
    preset `unet` (`variants.resolve("unet")`, what `condor train` trains by default).

    network: "pix2pix" (paper generator and discriminator at 256 px; data resampled to 256),
    "unet_gan" (U-Net `unet` + PatchGAN `patch`, same losses) or "unet_l1" (U-Net, L1 only).
    unet/patch: None picks UNetConfig.for_size(native size) / PatchConfig().
    prediction_mode: BatchNorm/dropout mode for validation and default for prediction.
    adversarial_target: the generator's adversarial target (1 standard; the paper writes 0).
    num_threads: torch CPU threads during training (None leaves the current setting).
    augment: train on a random one of the 16 exact symmetries (data.apply_symmetry) of each
    sample, drawn from (seed, epoch, sample); the field scaling is then symmetrised.
    symmetrise: predict (validation, and by default `predict`/`evaluate`) as the mean over the
    16 symmetries of the prediction, each transformed back (test-time symmetrisation).
    head: "tanh" (fields min/max-scaled to [-1, 1] through tanh, the paper's) or "physics"
    (condor.surrogate.physics: sum(P) = N_c, Sx2+Sy2+Sz2 = P, a spread map; network "unet" and
    loss "gaussian" only).
    loss: pixel loss of "unet_l1"/"unet": "l1" (the paper's; its minimiser is the per-pixel
    median), "mse" (the mean) or "gaussian" (physics head: MSE of the mean + NLL of the spread).
    scaling: "minmax" ([lo, hi] of the training split -> [-1, 1], tanh output) or "standard"
    (each field divided by its RMS, linear output); tanh head only.
    loss_region: "all" pixels or "tissue" (the mould and tethers dilated by the kernel reach).
    nll_weight: weight of the spread's NLL against the mean's squared error (physics head).
    sum_weight: weight of each mould's relative error in sum(T) (physics head; 0 leaves it out).
    field_weights: 8 weights of the fields' squared errors, in FIELD_NAMES order (physics head;
    None: all 1; normalised to mean 1; transpose pairs equal).
    area_weight: weight of each mould's relative error in its soft tissue area, N(P>0.2)
    (physics head; 0 leaves it out).
    tension_floor: weigh each mould's T error relative to its own tension per cell, floored at
    this many tau_0 (physics head, PhysicsHead.tension_weights; None: absolute).
    noise_weight: weigh each mould's squared error by its predicted noise to this power, minus
    (physics head, PhysicsHead.noise_weights; 0: every mould alike).
    detach_spread: the spread channels read the network's last features without training
    them (UNetConfig.detached_outputs): only the mean's squared error shapes the network.
    replicas: what a training mould with several replicas contributes (REPLICA_USES).
    lr_schedule: "constant" or "cosine" (LR_SCHEDULES; `lr_at`): a pure function of the
    epoch, so a resumed run follows the same schedule.
    inputs: what the network reads of a mould (condor.data.inputs.INPUT_KINDS): "mask" (the
    paper's two 0/1 masks, the store's `inputs`), "lattice" (its initial cells rasterised,
    the store's `lattice`) or "both" (the four channels).
    """

    network: str = "pix2pix"
    unet: UNetConfig | None = None
    patch: PatchConfig | None = None
    epochs: int = 10
    batch_size: int = 1
    lr: float = 2e-4
    betas: tuple = (0.5, 0.999)
    lam: float = 1000.0
    adversarial_target: float = 1.0
    seed: int = 0
    val_every: int = 1
    max_val_samples: int | None = None
    prediction_mode: str = "eval"
    num_threads: int | None = 1
    deterministic: bool = True
    augment: bool = False
    symmetrise: bool = False
    head: str = "tanh"
    loss: str = "l1"
    scaling: str = "minmax"
    loss_region: str = "all"
    nll_weight: float = 1.0
    sum_weight: float = 0.0
    field_weights: tuple | None = None
    area_weight: float = 0.0
    tension_floor: float | None = None
    noise_weight: float = 0.0
    detach_spread: bool = True
    replicas: str = "all"
    lr_schedule: str = "constant"
    inputs: str = "mask"

    def __post_init__(self):
        if isinstance(self.unet, dict):
            self.unet = UNetConfig(**self.unet)
        if isinstance(self.patch, dict):
            self.patch = PatchConfig(**self.patch)
        self.betas = tuple(self.betas)
        if not (len(self.betas) == 2 and all(isinstance(b, (int, float)) and 0 <= b < 1
                                             for b in self.betas)):
            raise ValueError(f"TrainConfig.betas = {list(self.betas)} must be Adam's two "
                             f"decay rates, each in [0, 1)")
        if self.network not in NETWORK_KINDS:
            raise ValueError(f"TrainConfig.network {self.network!r} is not one of {NETWORK_KINDS}")
        if self.prediction_mode not in PREDICTION_MODES:
            raise ValueError(f"TrainConfig.prediction_mode {self.prediction_mode!r} is not one "
                             f"of {PREDICTION_MODES}")
        for name, allowed in (("head", HEADS), ("loss", LOSSES), ("scaling", SCALINGS),
                              ("loss_region", LOSS_REGIONS), ("replicas", REPLICA_USES),
                              ("lr_schedule", LR_SCHEDULES), ("inputs", INPUT_KINDS)):
            if getattr(self, name) not in allowed:
                raise ValueError(f"TrainConfig.{name} {getattr(self, name)!r} is not one of {allowed}")
        if (self.head == "physics") != (self.loss == "gaussian"):
            raise ValueError(f"TrainConfig: loss 'gaussian' and head 'physics' go together (got "
                             f"loss {self.loss!r}, head {self.head!r})")
        if self.head == "physics" and self.network != "unet":
            raise ValueError(f"TrainConfig: head 'physics' needs network 'unet', got {self.network!r}")
        if self.network != "unet" and self.loss != "l1":
            raise ValueError(f"TrainConfig: network {self.network!r} trains on L1; loss "
                             f"{self.loss!r} needs model 'unet'")
        for name in ("sum_weight", "area_weight", "noise_weight"):
            value = getattr(self, name)
            if not (math.isfinite(value) and value >= 0):
                raise ValueError(f"TrainConfig.{name} = {value} must be finite and >= 0")
            if value > 0 and self.head != "physics":
                raise ValueError(f"TrainConfig.{name} = {value} needs head 'physics' "
                                 f"(got {self.head!r})")
        if self.tension_floor is not None:
            if not (math.isfinite(self.tension_floor) and self.tension_floor > 0):
                raise ValueError(f"TrainConfig.tension_floor = {self.tension_floor} must be "
                                 "finite and > 0")
            if self.head != "physics":
                raise ValueError(f"TrainConfig.tension_floor = {self.tension_floor} needs head "
                                 f"'physics' (got {self.head!r})")
        if self.field_weights is not None:
            if self.head != "physics":
                raise ValueError(f"TrainConfig.field_weights = {self.field_weights} needs head "
                                 f"'physics' (got {self.head!r})")
            try:
                check_field_weights(self.field_weights)
            except (TypeError, ValueError) as err:
                raise ValueError(f"TrainConfig.{err}") from None
            self.field_weights = tuple(float(w) for w in self.field_weights)
        if self.head == "physics" and self.scaling != "minmax":
            raise ValueError("TrainConfig: scaling applies to the tanh head only")
        for name in ("epochs", "batch_size", "val_every"):
            if getattr(self, name) < (0 if name == "epochs" else 1):
                raise ValueError(f"TrainConfig.{name} = {getattr(self, name)} is out of range")

    def networks(self, native_size: int) -> tuple[UNetConfig, PatchConfig | None]:
        """Generator and discriminator configs for data of `native_size` px."""
        n_inputs = n_input_channels(self.inputs)
        if self.network == "pix2pix":
            return replace(UNetConfig.paper(), in_channels=n_inputs), \
                PatchConfig(in_channels=n_inputs + len(FIELD_NAMES))
        unet = replace(self.unet or UNetConfig.for_size(native_size), in_channels=n_inputs)
        if self.head == "physics":
            unet = replace(unet, out_channels=PHYSICS_OUTPUTS, output="linear",
                           detached_outputs=PHYSICS_OUTPUTS - len(FIELD_NAMES)
                           if self.detach_spread else 0)
        elif self.scaling == "standard":
            unet = replace(unet, output="linear")
        if self.network in ("unet_l1", "unet"):
            return unet, None
        patch = self.patch or PatchConfig(in_channels=unet.in_channels + unet.out_channels)
        return unet, patch

    def lr_at(self, epoch: int) -> float:
        """Learning rate of 0-based `epoch` (of `epochs`)."""
        if self.lr_schedule == "constant":
            return self.lr
        return self.lr * 0.5 * (1.0 + math.cos(math.pi * epoch / max(self.epochs, 1)))

    def to_dict(self) -> dict:
        d = asdict(self)
        d["betas"] = list(self.betas)
        return d

    @classmethod
    def from_dict(cls, d: dict) -> "TrainConfig":
        return cls(**d)
