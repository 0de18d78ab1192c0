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

import time
from contextlib import contextmanager
from pathlib import Path

import numpy as np
import torch

from .checkpoint import (CheckpointMismatchError, discriminator_from_checkpoint,
                         generator_from_checkpoint, load_checkpoint, save_checkpoint,
                         scaling_from_checkpoint)
from .samples import (CHANNEL_NAMES, FIELD_NAMES, N_SYMMETRIES, FieldScaling, SampleSource,
                      apply_symmetry, check_dataset, compute_scaling, data_fingerprint,
                      dataset_pixel_size, INPUT_VARIABLES, model_inputs, usable_samples)
from .networks import PatchDiscriminator, UNetGenerator, discriminator_loss, generator_loss
from .physics import fit_physics_head, tissue_mask
from .inference import default_device
from .novelty import training_bank
from .predict import run_model
# The settings (torch-free, condor.surrogate.settings), exported here too, as before
from .settings import (HEADS, LOSS_REGIONS, LOSSES, LR_SCHEDULES, NETWORK_KINDS,  # noqa: F401
                       REPLICA_USES, RESUMABLE_KEYS, SCALINGS, PatchConfig, TrainConfig,
                       UNetConfig)


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
                                tension_floor=cfg.tension_floor, noise_weight=cfg.noise_weight)
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
