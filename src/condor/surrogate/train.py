"""Training loop for the surrogate: pix2pix (the paper), a right-sized U-Net with the same GAN
objective, or a U-Net trained on a pixel loss alone ("unet_l1"; "unet" with `loss` l1, mse, or
gaussian with the physics head of condor.surrogate.physics).

Checkpoint = one dict written atomically at the end of every epoch; `train` resumes from it
an interrupted run of the same config and data: the whole config but `num_threads` (epochs
included: another count is another schedule) and a sha256 fingerprint of the data it reads
(`data_fingerprint`) must match, else CheckpointMismatchError. On CPU with a fixed seed the
run is deterministic, and a run killed after epoch 1 of 2 and resumed gives the same weights
as 2 epochs straight: the data order and the torch RNG (dropout) are re-seeded from
(seed, epoch) at the start of every epoch, so nothing but the checkpoint carries state.
"""

from __future__ import annotations

import math
import time
from contextlib import contextmanager
from dataclasses import asdict, dataclass, replace
from pathlib import Path

import numpy as np
import torch

from .checkpoint import (CheckpointMismatchError, discriminator_from_checkpoint,
                         generator_from_checkpoint, load_checkpoint, save_checkpoint,
                         scaling_from_checkpoint)
from condor.data.inputs import INPUT_KINDS

from .samples import (CHANNEL_NAMES, FIELD_NAMES, N_SYMMETRIES, FieldScaling, SampleSource,
                   apply_symmetry, check_dataset, compute_scaling, data_fingerprint,
                   dataset_pixel_size, INPUT_VARIABLES, model_inputs, n_input_channels,
                   usable_samples)
from .modes import PREDICTION_MODES
from .networks import (PatchConfig, PatchDiscriminator, UNetConfig,
                     UNetGenerator, discriminator_loss, generator_loss)
from .physics import PhysicsHead, check_field_weights, fit_physics_head, tissue_mask
from .inference import default_device
from .novelty import training_bank
from .predict import run_model

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
        for name in ("sum_weight", "area_weight"):
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
            unet = replace(unet, out_channels=PhysicsHead.n_outputs, output="linear",
                           detached_outputs=PhysicsHead.n_outputs - len(FIELD_NAMES)
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



@contextmanager
def _torch_settings(cfg: TrainConfig):
    """Fix threads and deterministic algorithms for the run; restore them afterwards."""
    threads = torch.get_num_threads()
    deterministic = torch.are_deterministic_algorithms_enabled()
    try:
        if cfg.num_threads:
            torch.set_num_threads(cfg.num_threads)
        torch.use_deterministic_algorithms(cfg.deterministic, warn_only=True)
        yield
    finally:
        torch.set_num_threads(threads)
        torch.use_deterministic_algorithms(deterministic)


def _epoch_seed(seed: int, epoch: int) -> int:
    return int(np.random.default_rng([seed, epoch, 7]).integers(2 ** 62))


def augmentation_choices(seed: int, epoch: int, n_samples: int) -> np.ndarray:
    """Symmetry index (0..15) for each training sample (position in the training split) in
    `epoch`: a pure function of (seed, epoch), so a resumed run draws the same ones."""
    return np.random.default_rng([seed, epoch, 13]).integers(N_SYMMETRIES, size=n_samples)


def augment_batch(x: torch.Tensor, y: torch.Tensor, choices,
                  input_kind: str = "mask") -> tuple[torch.Tensor, torch.Tensor]:
    """Apply symmetry choices[i] to sample i of a batch (inputs x of `input_kind`, fields y
    scaled by a symmetrised FieldScaling)."""
    pairs = [apply_symmetry(int(k), x[i], y[i], input_kind=input_kind)
             for i, k in enumerate(choices)]
    return (torch.stack([p[0] for p in pairs]).contiguous(),
            torch.stack([p[1] for p in pairs]).contiguous())


ADDED_DATA_KEYS = ("sigma",)  # data signature keys that older checkpoints lack


def _data_signature(ds, train_idx: np.ndarray, val_idx: np.ndarray, cfg: TrainConfig) -> dict:
    """What a checkpoint records of its data: the grid and kernel (prediction checks and
    reuses them), the training set's size and the fingerprint of every value training reads
    (data_fingerprint: the training and validation samples)."""
    fingerprint = data_fingerprint(ds, {"train": train_idx, "val": val_idx}, cfg.inputs,
                                   replica_mean=cfg.replicas == "mean")
    try:  # recorded so that prediction can check a mould's box against the training grid
        pixel_size = dataset_pixel_size(ds)
    except ValueError:
        pixel_size = None
    scene = ds.attrs.get("scene")
    scene = scene if isinstance(scene, dict) else {}
    depth = float(scene["depth"]) if "depth" in scene else None
    # the kernel width the store's lattice channels were drawn with: prediction draws a new
    # mould's channels with the same one
    sigma = scene.get("sigma", ds.attrs.get("sigma"))
    return {"native_size": int(ds.sizes["x"]), "pixel_size": pixel_size, "depth": depth,
            "sigma": None if sigma is None else float(sigma),
            "field_names": list(FIELD_NAMES), "channel_names": list(CHANNEL_NAMES),
            "n_train": int(len(train_idx)), "fingerprint": fingerprint}


def _check_resumable(state: dict, cfg: TrainConfig, data: dict, path) -> None:
    """Raise CheckpointMismatchError naming `path` and every differing setting."""
    # a setting added after the checkpoint was written takes its default there
    old = {k: v for k, v in {**TrainConfig().to_dict(), **state["config"]}.items()
           if k not in RESUMABLE_KEYS}
    new = {k: v for k, v in cfg.to_dict().items() if k not in RESUMABLE_KEYS}
    diffs = [f"{k}: checkpoint {old.get(k)!r} vs now {new.get(k)!r}"
             for k in sorted(set(old) | set(new)) if old.get(k) != new.get(k)]
    # a data key added after the checkpoint was written (ADDED_DATA_KEYS) is not compared
    recorded = {k: state["data"].get(k, v if k in ADDED_DATA_KEYS else None)
                for k, v in data.items()}
    diffs += [f"the training data changed (fingerprint {str(recorded[k])[:12]} in the "
              f"checkpoint, {v[:12]} now)" if k == "fingerprint" else
              f"data {k}: checkpoint {recorded[k]!r} vs now {v!r}"
              for k, v in data.items() if recorded[k] != v]
    if diffs:
        raise CheckpointMismatchError(f"cannot resume from {str(path)!r}; it was written for a "
                                      "different run: " + "; ".join(diffs))


def _set_grads(params, grads) -> None:
    for p, g in zip(params, grads):
        p.grad = g


def pixel_loss(out: torch.Tensor, y: torch.Tensor, x: torch.Tensor, n_cells, head,
               cfg: TrainConfig) -> tuple[torch.Tensor, dict]:
    """The pixel loss of a "unet_l1"/"unet" step (see TrainConfig.loss, loss_region)."""
    if cfg.loss == "gaussian":
        return head.loss(out, y, n_cells)
    error = (out - y).abs() if cfg.loss == "l1" else (out - y) ** 2
    if cfg.loss_region == "tissue":
        weight = tissue_mask(x)
        loss = (error * weight).sum() / (weight.sum() * error.shape[1]).clamp_min(1.0)
    else:
        loss = error.mean()
    return loss, {cfg.loss: loss.item()}


def _train_step(G, D, opt_g, opt_d, x, y, cfg: TrainConfig, head=None, n_cells=None) -> dict:
    """One update as TensorFlow's pix2pix does it: both losses from the same forward pass,
    gradients for both networks, then both optimiser steps."""
    fake = G(x)
    if D is None:
        loss, parts = pixel_loss(fake, y, x, n_cells, head, cfg)
        opt_g.zero_grad(set_to_none=True)
        loss.backward()
        opt_g.step()
        return {**parts, "g_loss": loss.item()}
    real_logits = D(x, y)
    fake_logits = D(x, fake)
    g_total, l1, adversarial = generator_loss(fake_logits, fake, y, cfg.lam, cfg.adversarial_target)
    d_total = discriminator_loss(real_logits, fake_logits)
    g_params, d_params = list(G.parameters()), list(D.parameters())
    _set_grads(g_params, torch.autograd.grad(g_total, g_params, retain_graph=True))
    _set_grads(d_params, torch.autograd.grad(d_total, d_params))
    opt_g.step()
    opt_d.step()
    return {"l1": l1.item(), "g_loss": g_total.item(), "adversarial": adversarial.item(),
            "d_loss": d_total.item()}


def validation_mae(G, scaling, source: SampleSource, mode: str, device,
                   symmetrise: bool = False) -> float:
    """Mean absolute error over pixels, fields and samples, physical units, native grid.
    A physics head's spread is recalibrated on these moulds (PhysicsHead.calibrate_spread,
    inside the tissue: the mould and tether pixels)."""
    if len(source) == 0:
        return float("nan")
    items = np.arange(len(source))
    inputs = source.native_inputs()
    pred, spread = run_model(G, scaling, inputs, mode, device=device, symmetrise=symmetrise,
                             n_cells=source.n_cells, inputs_kind=source.inputs)
    truth = source.native_fields(items)
    if spread is not None:
        masks = inputs[:, :2] if INPUT_VARIABLES[source.inputs][0] == "inputs" else \
            model_inputs(source.ds, source.indices, "mask")  # masks first when it reads them
        scaling.calibrate_spread(pred, spread, truth, masks.astype(bool).any(axis=1))
    return float(np.abs(pred - truth).mean())


def output_map(cfg: TrainConfig, ds, train_idx, size: int):
    """The map between physical fields and the network's outputs, fitted on the training
    split: a FieldScaling (tanh head: min/max, symmetrised when augmenting so that sign flips
    and swaps commute with it; or standard: each field / its RMS) or a PhysicsHead."""
    if cfg.head == "physics":
        pixel = dataset_pixel_size(ds) * int(ds.sizes["x"]) / size  # of the training grid
        return fit_physics_head(ds, train_idx, nll_weight=cfg.nll_weight,
                                sum_weight=cfg.sum_weight, field_weights=cfg.field_weights,
                                area_weight=cfg.area_weight, pixel_size=pixel,
                                tension_floor=cfg.tension_floor)
    if cfg.scaling == "standard":
        rms = fit_physics_head(ds, train_idx).field_scale
        return FieldScaling(-rms, rms)
    scaling = compute_scaling(ds, train_idx, size)
    return scaling.symmetrised() if cfg.augment else scaling


def _build(cfg: TrainConfig, native: int, device):
    gcfg, pcfg = cfg.networks(native)
    init = torch.Generator().manual_seed(cfg.seed)
    G = UNetGenerator(gcfg, init).to(device)
    D = PatchDiscriminator(pcfg, init).to(device) if pcfg else None
    opt_g = torch.optim.Adam(G.parameters(), lr=cfg.lr, betas=cfg.betas)
    opt_d = torch.optim.Adam(D.parameters(), lr=cfg.lr, betas=cfg.betas) if D else None
    return G, D, opt_g, opt_d


def train(dataset, cfg: TrainConfig, checkpoint_path, device=None, log=print,
          resume: bool = True, stop_after: int | None = None) -> list[dict]:
    """Train on the "train" split of `dataset` (an xarray.Dataset), validating on "val".

    Writes `checkpoint_path` after every epoch; if it exists (and `resume`), continues from it
    (CheckpointMismatchError if it belongs to another config, `epochs` included, or other
    data: `_check_resumable`). Calls
    `log(str)` once per epoch (and once on resuming). `stop_after`: stop after that many
    epochs of the run, as if interrupted (a snapshot of the run, which the next call resumes).
    Returns the history: one dict per epoch with l1, g_loss,
    d_loss (GAN kinds), val_mae (physical units; None when not validated) and seconds."""
    check_dataset(dataset)
    device = default_device(device)
    native = int(dataset.sizes["x"])
    train_idx = usable_samples(dataset, "train", all_replicas=cfg.replicas == "all")
    if len(train_idx) == 0:
        raise ValueError("dataset has no usable ('ok') samples in the 'train' split")
    val_idx = usable_samples(dataset, "val")[:cfg.max_val_samples]
    data = _data_signature(dataset, train_idx, val_idx, cfg)
    path = Path(checkpoint_path)
    with _torch_settings(cfg):
        G, D, opt_g, opt_d = _build(cfg, native, device)
        state = load_checkpoint(path, map_location=device) if resume and path.exists() else None
        if state is not None:
            _check_resumable(state, cfg, data, path)
            G.load_state_dict(generator_from_checkpoint(state, path).state_dict())
            opt_g.load_state_dict(state["opt_g"])
            if D is not None:
                D.load_state_dict(discriminator_from_checkpoint(state, path).state_dict())
                opt_d.load_state_dict(state["opt_d"])
            scaling, history, start = scaling_from_checkpoint(state), list(state["history"]), state["epoch"]
            log(f"resuming from {path} after epoch {start} of {cfg.epochs}")
        else:
            scaling, history, start = output_map(cfg, dataset, train_idx, G.cfg.size), [], 0
        train_src = SampleSource(dataset, train_idx, scaling, G.cfg.size,
                                 replica_mean=cfg.replicas == "mean", inputs=cfg.inputs)
        val_src = SampleSource(dataset, val_idx, None, native, preload=False, inputs=cfg.inputs)
        for epoch in range(start, min(cfg.epochs, stop_after or cfg.epochs)):
            t0 = time.perf_counter()
            torch.manual_seed(_epoch_seed(cfg.seed, epoch))
            for opt in (opt_g, opt_d):
                for group in opt.param_groups if opt is not None else ():
                    group["lr"] = cfg.lr_at(epoch)
            order = np.random.default_rng([cfg.seed, epoch]).permutation(len(train_src))
            choices = augmentation_choices(cfg.seed, epoch, len(train_src))
            G.train()
            if D is not None:
                D.train()
            sums: dict[str, float] = {}
            n_batches = 0
            for start_item in range(0, len(order), cfg.batch_size):
                items = order[start_item:start_item + cfg.batch_size]
                x, y = train_src.batch(items)
                if cfg.augment:
                    x, y = augment_batch(x, y, choices[items], cfg.inputs)
                n_cells = torch.as_tensor(train_src.n_cells[items], device=device)
                for k, v in _train_step(G, D, opt_g, opt_d, x.to(device), y.to(device), cfg,
                                        scaling, n_cells).items():
                    sums[k] = sums.get(k, 0.0) + v
                n_batches += 1
            record = {"epoch": epoch + 1, **{k: v / n_batches for k, v in sums.items()}}
            last = epoch + 1 == cfg.epochs
            validate = len(val_src) > 0 and ((epoch + 1) % cfg.val_every == 0 or last)
            record["val_mae"] = validation_mae(G, scaling, val_src, cfg.prediction_mode, device,
                                               cfg.symmetrise) if validate else None
            record["seconds"] = time.perf_counter() - t0
            history.append(record)
            # what predict measures a new mould's novelty against (condor.surrogate.novelty)
            bank = training_bank(G, cfg.inputs, dataset, train_idx) if last and isinstance(
                G, UNetGenerator) else None
            save_checkpoint({
                "config": cfg.to_dict(), "generator_config": G.cfg.to_dict(),
                "patch_config": D.cfg.to_dict() if D is not None else None,
                "generator": G.state_dict(), "discriminator": D.state_dict() if D else None,
                "opt_g": opt_g.state_dict(), "opt_d": opt_d.state_dict() if D else None,
                "epoch": epoch + 1, "scaling": scaling.to_dict(), "history": history,
                "data": data, **({"novelty": bank} if bank is not None else {})}, path)
            log(_format_record(record, cfg.epochs))
    return history


def _format_record(r: dict, epochs: int) -> str:
    parts = [f"epoch {r['epoch']}/{epochs}"] + [f"{k} {r[k]:.4f}" for k in ("l1", "mse", "nll")
                                                   if k in r] + [f"g_loss {r['g_loss']:.4f}"]
    if "d_loss" in r:
        parts.append(f"d_loss {r['d_loss']:.4f}")
    if r.get("val_mae") is not None:
        parts.append(f"val_mae {r['val_mae']:.5f}")
    parts.append(f"{r['seconds']:.1f} s")
    return "  ".join(parts)
