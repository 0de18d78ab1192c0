"""Prediction from a trained checkpoint: mould inputs -> the 8 fields, raw and normalised."""

from __future__ import annotations

import contextlib
import warnings
import weakref
from dataclasses import dataclass
from pathlib import Path

import numpy as np
import torch
import xarray as xr

from condor.data.inputs import stress_channels
from condor.measures.metrics import density_sums, normalise_predicted
from condor.data.store import quiet_zarr

from .checkpoint import generator_from_checkpoint, load_checkpoint, scaling_from_checkpoint
from .samples import (FIELD_NAMES, INPUT_VARIABLES, N_SYMMETRIES, FieldScaling, apply_symmetry,
                   resample_fields, resample_inputs)
from .models import UNetGenerator, inference_copy, prediction_mode
from .physics import estimate_n_cells


def default_device(device=None) -> torch.device:
    """`device` if given, else CUDA when present, else CPU."""
    if device is not None:
        return torch.device(device)
    return torch.device("cuda" if torch.cuda.is_available() else "cpu")


# "eval" prediction's copies of the models it ran (inference_copy), each with the identity and
# version of every tensor of the model's state it was made from: a model trained or loaded
# since gets a new copy.
_INFERENCE_COPIES: "weakref.WeakKeyDictionary" = weakref.WeakKeyDictionary()


# The arithmetic of "eval" prediction's network: float32 (the model's own), or bfloat16 (the
# inference copy's weights and activations; CPUs with native bfloat16 arithmetic, such as
# AVX512-BF16 or AMX, run it about twice as fast; measured on the default run's test moulds:
# docs/surrogate.md, "Prediction time").
PRECISIONS = ("float32", "bfloat16")
# Predictor's default: bfloat16 where the CPU has it natively (bfloat16_is_native), else
# float32. "auto" is resolved once, when the Predictor is made (Predictor.precision).
AUTO_PRECISION = "auto"
DEFAULT_PRECISION = AUTO_PRECISION


def bfloat16_is_native() -> bool:
    """True when this CPU has bfloat16 arithmetic (oneDNN's check: AVX512-BF16 or AMX)."""
    try:
        return bool(torch.backends.mkldnn.is_available()
                    and torch.ops.mkldnn._is_mkldnn_bf16_supported())
    except (AttributeError, RuntimeError):
        return False


def resolve_precision(precision: str) -> str:
    """`precision` as the network will run it: one of PRECISIONS ("auto": bfloat16 where
    bfloat16_is_native, else float32); anything else is refused by name."""
    if precision == AUTO_PRECISION:
        return "bfloat16" if bfloat16_is_native() else "float32"
    if precision not in PRECISIONS:
        raise ValueError(f"precision {precision!r} is not one of {(AUTO_PRECISION,) + PRECISIONS}")
    return precision


def _inference_model(model: UNetGenerator, precision: str = "float32") -> UNetGenerator:
    """`model`'s inference_copy (BatchNorm folded, channels_last) in `precision`, made once per
    state of the model's weights."""
    if precision not in PRECISIONS:
        raise ValueError(f"precision {precision!r} is not one of {PRECISIONS}")
    state = tuple((t.data_ptr(), t._version) for t in model.state_dict().values())
    held = _INFERENCE_COPIES.setdefault(model, {})
    if precision not in held or held[precision][0] != state:
        copy = inference_copy(model)
        held[precision] = (state, copy if precision == "float32" else copy.to(torch.bfloat16))
    return held[precision][1]


def _network(model, x: torch.Tensor) -> torch.Tensor:
    """One run of the network on x (float32), in the memory order and the precision of its
    weights; float32 out."""
    first = next(model.parameters())
    x = x.to(first.dtype)
    if first.dim() == 4 and first.is_contiguous(memory_format=torch.channels_last) and \
            not first.is_contiguous():
        out = model(x.contiguous(memory_format=torch.channels_last))
    else:
        out = model(x.contiguous())
    return out if out.dtype == torch.float32 else out.float()


def _decode(model, scaling, x: torch.Tensor, n_cells) -> tuple[np.ndarray, np.ndarray | None]:
    """Physical fields (float64) and spread (or None) of one network run on x."""
    return _decode_output(scaling, _network(model, x).contiguous(), n_cells)


def _decode_tensor(scaling, out: torch.Tensor, n_cells) -> tuple[torch.Tensor,
                                                                 torch.Tensor | None]:
    """Physical fields and spread (or None) of the network's output `out`, in out's dtype."""
    if getattr(scaling, "kind", None) == "physics":
        return scaling.decode(out, torch.as_tensor(np.asarray(n_cells), dtype=out.dtype,
                                                   device=out.device))
    lo, span = (torch.as_tensor(v, dtype=out.dtype, device=out.device)[:, None, None]
                for v in (scaling.lo, scaling._span()))
    return (out + 1) * (span / 2) + lo, None


def _decode_output(scaling, out: torch.Tensor, n_cells) -> tuple[np.ndarray, np.ndarray | None]:
    """Physical fields (float64) and spread (or None) of the network's output `out`."""
    if getattr(scaling, "kind", None) == "physics":
        fields, spread = scaling.decode(out.double(), torch.tensor(np.asarray(n_cells), dtype=torch.float64,
                                                                        device=out.device))
        return fields.cpu().numpy(), spread.cpu().numpy()
    return scaling.unscale(out.double().cpu().numpy()), None


def _field_maps() -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """Per planar transform k (0..7), how the symmetrisation sums the inverse of k and of its
    z-flipped twin k + FLIP_Z on a prediction's fields (pixels already moved back): field f of
    the sum is weight[k, f] x field source[k, f], and of the variances' sum variance_weight[k,
    f] x variance source[k, f] (the signs do not apply). Read off apply_symmetry on one-pixel
    unit fields, so they are its maps exactly: each field comes from one field (a swap), with
    weight +-2, or 0 where the twins cancel (SxSz, SySz)."""
    n = len(FIELD_NAMES)
    unit = np.eye(n).reshape(n, n, 1, 1)  # unit field g as sample g
    source, weight, variance_weight = [], [], []
    for k in range(N_SYMMETRIES // 2):
        maps = [apply_symmetry(k + z, fields=unit, inverse=True)[1][..., 0, 0].T
                for z in (0, N_SYMMETRIES // 2)]  # (f, g): field f of the result from field g
        absolute = np.abs(maps[0]) + np.abs(maps[1])
        assert np.all((absolute != 0).sum(axis=1) == 1), "a symmetry that mixes fields"
        g = absolute.argmax(axis=1)
        source.append(g)
        weight.append((maps[0] + maps[1])[np.arange(n), g])
        variance_weight.append(absolute[np.arange(n), g])
    return np.stack(source), np.stack(weight), np.stack(variance_weight)


_FIELD_MAPS = _field_maps()
_DECODE_MOULDS = 2  # moulds decoded at a time by the batched symmetrisation


# The physics head's symmetrisation decoded in place and summed in one compiled pass
# (_symmetrised_physics) instead of torch's strided moves, decode and sums, which measured
# about half of a prediction's time; the same numbers to float32 rounding
# (tests/test_surrogate_predict.py).
FUSED_DECODE = True
_PIXEL_SOURCES: dict = {}


def _pixel_sources(side: int) -> np.ndarray:
    """(8, side*side) int64: for each planar transform k, the pixel of its output that
    apply_symmetry(k, inverse=True) moves onto each pixel (row-major)."""
    if side not in _PIXEL_SOURCES:
        index = torch.arange(side * side, dtype=torch.float64).reshape(1, 1, side, side)
        _PIXEL_SOURCES[side] = np.stack([
            apply_symmetry(k, inputs=index, inverse=True)[0].reshape(-1).numpy().astype(np.int64)
            for k in range(N_SYMMETRIES // 2)])
    return _PIXEL_SOURCES[side]


def _symmetrised_physics(head, out: torch.Tensor, n: int, n_cells) -> tuple[np.ndarray,
                                                                             np.ndarray]:
    """_symmetrised's batched mean and spread for a physics head, from the network's output
    `out` (8 n, 16, H, H) float32 of the 8 planar transforms of n moulds: decoded where the
    network wrote them (decode is per pixel but for the softmax over the grid, which does not
    depend on the pixels' order), then moved back and summed in one compiled pass
    (physics.symmetrised_sum_kernel): float64 (n, 8, H, H) each."""
    from .physics import symmetrised_sum_kernel

    planar, side = N_SYMMETRIES // 2, out.shape[-1]
    cells = torch.from_numpy(np.tile(np.asarray(n_cells, dtype=np.float32).reshape(n), planar))
    fields, spread = head.decode(out.contiguous(), cells)  # NCHW: decode's slices are planes
    shape = (planar, n, len(FIELD_NAMES), side * side)
    source, weight, variance_weight = _FIELD_MAPS
    mean = np.zeros((n, len(FIELD_NAMES), side * side))
    variance = np.zeros_like(mean)
    symmetrised_sum_kernel(fields.numpy().reshape(shape), spread.numpy().reshape(shape),
                           _pixel_sources(side), source.astype(np.int64),
                           weight.astype(np.float64), variance_weight.astype(np.float64),
                           mean, variance)
    shape = (n, len(FIELD_NAMES), side, side)
    return (mean / N_SYMMETRIES).reshape(shape), np.sqrt(variance / N_SYMMETRIES).reshape(shape)


def _symmetrised(model, scaling, x: torch.Tensor, n_cells,
                 input_kind: str = "mask", batched: bool = False) -> tuple[np.ndarray, np.ndarray | None]:
    """Mean over the 16 symmetries g of g^-1 G(g x), physical units (float64), and the root
    mean of the transformed-back spread variances. The z-flip leaves the inputs unchanged, so
    each of the 8 planar transforms runs once and its z-flipped twin is its output with SxSz,
    SySz negated: the mean of those two sets them to zero. `batched`: the 8 transforms run as
    one batch of the network (the same numbers in "eval" mode, where a sample's output does
    not depend on its batch; a few times faster on a CPU), and the outputs are moved back
    before they are decoded (the output map is the same at every pixel, and its softmax over
    the grid does not depend on the pixels' order), so that one decode and one sum of the
    fields' sign and swap maps (_FIELD_MAPS) finish the mean."""
    planar = range(N_SYMMETRIES // 2)  # the planar ones (FLIP_Z is the highest bit)
    if batched:
        n = x.shape[0]
        out = _network(model, torch.cat([apply_symmetry(k, inputs=x, input_kind=input_kind)[0]
                                         for k in planar]))
        if getattr(scaling, "kind", None) == "physics" and out.device.type == "cpu" \
                and out.shape[-1] == out.shape[-2] and FUSED_DECODE:
            return _symmetrised_physics(scaling, out, n, n_cells)
        out = out.reshape((len(planar), n) + out.shape[1:])
        source, weight, variance_weight = (torch.from_numpy(a).to(out.device)
                                           for a in _FIELD_MAPS)
        weight, variance_weight = (w.to(torch.float32)[..., None, None]
                                   for w in (weight, variance_weight))
        means, spreads = [], []
        # a few moulds at a time (float32: the network's own precision), so that the
        # decode's many passes run in the cache
        for start in range(0, n, _DECODE_MOULDS):
            part = slice(start, start + _DECODE_MOULDS)
            # the pixels moved back, the channels as the network wrote them
            moved = torch.stack([apply_symmetry(k, inputs=out[k, part], inverse=True)[0]
                                 for k in planar])
            m = moved.shape[1]
            cells = None if n_cells is None else np.tile(np.asarray(n_cells)[part], len(planar))
            ys, spread = _decode_tensor(scaling, moved.reshape((-1,) + moved.shape[2:])
                                        .contiguous(), cells)
            ys = ys.reshape((len(planar), m) + ys.shape[1:])
            mean = sum(weight[k] * ys[k][:, source[k]] for k in planar) / N_SYMMETRIES
            means.append(mean)
            if spread is not None:
                variances = spread.reshape(ys.shape) ** 2
                spreads.append(torch.sqrt(sum(variance_weight[k] * variances[k][:, source[k]]
                                              for k in planar) / N_SYMMETRIES))
        return torch.cat(means).cpu().numpy(), \
            torch.cat(spreads).cpu().numpy() if spreads else None
    outputs = (_decode(model, scaling, apply_symmetry(k, inputs=x, input_kind=input_kind)[0],
                       n_cells) for k in planar)
    total, variance = 0.0, 0.0
    for k, (y, spread) in zip(planar, outputs):
        for z in (0, N_SYMMETRIES // 2):
            total = total + apply_symmetry(k + z, fields=y, inverse=True)[1]
            if spread is not None:  # variances move with the pixels; signs do not apply
                variance = variance + np.abs(apply_symmetry(k + z, fields=spread ** 2,
                                                            inverse=True)[1])
    spread = None if np.isscalar(variance) else np.sqrt(variance / N_SYMMETRIES)
    return total / N_SYMMETRIES, spread


def run_model(model: UNetGenerator, scaling, inputs: np.ndarray, mode: str = "eval",
              batch_size: int = 16, device=None, symmetrise: bool = False,
              n_cells=None, inputs_kind: str = "mask",
              precision: str = "float32") -> tuple[np.ndarray, np.ndarray | None]:
    """Model inputs (S, C, H, W) at the native resolution (0/1 masks, lattice or stress
    channels: `inputs_kind`) -> (physical fields (S, 8, H, W),
    spread (S, 8, H, W) or None) float32 at the native resolution. The model runs at its own
    resolution (inputs resampled nearest, outputs resampled conserving sums; spreads as
    variances). Modes other than "eval" depend on the batch, so they run one sample at a time
    as the paper did. `symmetrise`: the mean over the 16 symmetries of the transformed-back
    predictions (8 model runs: see _symmetrised). `n_cells` (S,): N_c per mould, needed by a
    physics head (condor.surrogate.physics). `precision` (PRECISIONS): the network's arithmetic
    in "eval" mode (other modes run the model itself, in float32)."""
    device = default_device(device) if device is None else torch.device(device)
    native = inputs.shape[-1]
    size = model.cfg.size
    physics = getattr(scaling, "kind", None) == "physics"
    if physics:
        if n_cells is None:
            raise ValueError("this checkpoint's physics head needs n_cells (N_c per mould)")
        n_cells = np.asarray(n_cells, dtype=np.float64).reshape(-1)
        if n_cells.shape != (inputs.shape[0],) or not np.all(np.isfinite(n_cells) & (n_cells > 0)):
            raise ValueError(f"n_cells must be {inputs.shape[0]} positive numbers, got {n_cells}")
    if mode != "eval":
        batch_size = 1
    n_fields = len(FIELD_NAMES) if physics else model.cfg.out_channels
    out = np.empty((inputs.shape[0], n_fields, native, native), dtype=np.float32)
    spread_out = np.empty_like(out) if physics else None
    # "eval" runs the network's inference_copy (the same map, BatchNorm folded; always in
    # eval mode, so the model's own flags and buffers are left alone)
    fast = mode == "eval" and isinstance(model, UNetGenerator)
    network = _inference_model(model, precision) if fast else model
    with contextlib.nullcontext() if fast else prediction_mode(model, mode), \
            torch.inference_mode():
        for start in range(0, inputs.shape[0], batch_size):
            part = slice(start, start + batch_size)
            x = resample_inputs(np.asarray(inputs[part], dtype=np.float32), size, inputs_kind)
            x = torch.from_numpy(np.ascontiguousarray(x)).to(device)
            cells = n_cells[part] if physics else None
            y, spread = _symmetrised(network, scaling, x, cells, inputs_kind,
                                     batched=mode == "eval") if symmetrise else \
                _decode(network, scaling, x, cells)
            out[part] = resample_fields(y, native)
            if physics:
                spread_out[part] = np.sqrt(resample_fields(spread ** 2, native))
    return out, spread_out


def run_generator(model: UNetGenerator, scaling, inputs: np.ndarray, mode: str = "eval",
                  batch_size: int = 16, device=None, symmetrise: bool = False,
                  n_cells=None) -> np.ndarray:
    """The fields of `run_model` alone: (S, 8, H, W) float32, physical, native resolution."""
    return run_model(model, scaling, inputs, mode, batch_size, device, symmetrise, n_cells)[0]


@dataclass
class Prediction:
    raw: np.ndarray  # (8, H, W) or (S, 8, H, W): the weighted sums Z_p, as trained
    normalised: np.ndarray  # raw * N_p / N_c
    n_cells: np.ndarray | float  # N_c, the sum of P (given or estimated, for a physics head)
    # Per pixel and field, the standard deviation of one simulation around the predicted
    # (expected) fields, same shape and units as raw; None for a checkpoint without a spread
    # head. A q-interval is raw -/+ z_q * spread (condor.surrogate.calibration).
    spread: np.ndarray | None = None


# Moulds a Predictor runs at a time (8 transforms each when it symmetrises): small enough that
# the network's activations and the symmetrisation's passes stay in the CPU's cache. Measured
# on this 2-core machine, the default checkpoint, stress cached (CPU ms a mould, medians of 5):
# batches of 4 took 11.7 (bfloat16) and 15.3 (float32), of 16 14.1 and 19.1, of 1 13.9 and
# 17.3 (docs/surrogate.md, "Prediction time").
PREDICT_BATCH = 4


class Predictor:
    """A loaded checkpoint, for repeated predictions."""

    def __init__(self, checkpoint_path, device=None, mode: str | None = None,
                 symmetrise: bool | None = None, precision: str = DEFAULT_PRECISION):
        """`precision` ("auto" or PRECISIONS): the network's arithmetic in "eval" mode;
        "bfloat16" is about twice as fast on a CPU with bfloat16 arithmetic
        (bfloat16_is_native) and changes the fields by a few 1e-3 of their largest value
        (docs/surrogate.md, "Prediction time"); "auto" (the default) takes it where it is
        native, float32 elsewhere. `self.precision` is the one resolved."""
        self.precision = resolve_precision(precision)
        self.path = str(checkpoint_path)
        self.device = default_device(device)
        state = load_checkpoint(checkpoint_path)
        self.model = generator_from_checkpoint(state, self.path).to(self.device)
        self.scaling = scaling_from_checkpoint(state)
        self.native = int(state["data"]["native_size"])
        self.mode = mode or state["config"].get("prediction_mode", "eval")
        # what the network reads (TrainConfig.inputs); checkpoints from before it read masks
        self.inputs_kind = state["config"].get("inputs", "mask")
        self.symmetrise = state["config"].get("symmetrise", False) if symmetrise is None \
            else bool(symmetrise)
        self.state = state

    @property
    def pixel_size(self) -> float | None:
        """Pixel side (l0) of the training grid; None for a checkpoint that did not record it."""
        return self.state["data"].get("pixel_size")

    @property
    def box(self) -> float | None:
        """Box side (l0) of the training scene, or None when unknown."""
        return None if self.pixel_size is None else self.pixel_size * self.native

    @property
    def depth(self) -> float | None:
        """Mould depth (l0) of the training scene, or None when the checkpoint lacks it."""
        return self.state["data"].get("depth")

    @property
    def sigma(self) -> float:
        """The fields' kernel width (l0) of the training scene."""
        from condor.model.scenes import SIGMA_L0

        return float(self.state["data"].get("sigma") or SIGMA_L0)

    @property
    def needs_lattice(self) -> bool:
        """True when the network reads the lattice channels (condor.data.inputs), not the masks."""
        return "lattice" in INPUT_VARIABLES[self.inputs_kind]

    def lattice_of(self, mould) -> np.ndarray:
        """The exact lattice channels (2, H, W) of a condor.moulds.mould.Mould on the training grid."""
        from condor.data.inputs import lattice_channels

        if self.box is None or self.depth is None:
            raise ValueError(f"checkpoint {self.path!r} records no pixel size or depth")
        return lattice_channels(mould.polygon, mould.tethers, self.depth, self.box, self.native,
                                self.sigma)

    def estimate_lattice(self, inputs: np.ndarray) -> np.ndarray:
        """Lattice channels from masks alone (condor.data.inputs.estimate_lattice_channels):
        approximate; a mould's geometry gives the exact ones (lattice_of)."""
        from condor.data.inputs import estimate_lattice_channels

        if self.pixel_size is None or self.depth is None:
            raise ValueError(f"checkpoint {self.path!r} records no pixel size or depth; pass "
                             "lattice")
        return estimate_lattice_channels(inputs, self.pixel_size, self.depth, self.sigma)

    def mould_arguments(self, moulds) -> dict:
        """Keyword arguments of __call__ for condor.moulds.mould.Mould objects beyond their masks:
        each mould's exact N_c and, for a lattice checkpoint, its lattice channels."""
        from condor.data.inputs import channels_of_sites
        from condor.model.lattice import lattice_sites

        if self.depth is None:
            return {}
        sites = [lattice_sites(m.polygon, m.tethers, self.depth) for m in moulds]
        extra = {"n_cells": np.array([len(positions) for positions, _ in sites], np.float64)}
        if self.needs_lattice:
            if self.box is None:
                raise ValueError(f"checkpoint {self.path!r} records no pixel size")
            extra["lattice"] = np.stack([channels_of_sites(*s, self.depth, self.box, self.native,
                                                           self.sigma) for s in sites])
        return extra

    @property
    def needs_n_cells(self) -> bool:
        """True when the checkpoint's output is built on the mould's cell count N_c."""
        return getattr(self.scaling, "kind", None) == "physics"

    def estimate_n_cells(self, inputs: np.ndarray):
        """N_c from input channels alone (physics.estimate_n_cells on the training grid)."""
        if self.pixel_size is None or self.depth is None:
            raise ValueError(f"checkpoint {self.path!r} records no pixel size or depth; pass "
                             "n_cells")
        return estimate_n_cells(inputs, self.pixel_size, self.depth)

    def __call__(self, inputs, batch_size: int = PREDICT_BATCH, n_cells=None,
                 lattice=None) -> Prediction:
        """Predict for inputs (2, H, W) or (S, 2, H, W) (the masks). `n_cells`: N_c per mould
        (a number or (S,)), the lattice count (physics.n_cells_of_mould, or the store's
        `n_cells`); when None and the checkpoint needs it, it is estimated from the inputs.
        `lattice`: the lattice channels, same shape (the store's `lattice`, lattice_of(mould),
        or mould_arguments); when None and the checkpoint reads them, they are estimated from
        the masks (estimate_lattice: less accurate, with a warning)."""
        inputs = np.asarray(inputs)
        single = inputs.ndim == 3
        batch = inputs[None] if single else inputs
        if batch.ndim != 4 or batch.shape[1] != 2:
            raise ValueError(f"inputs must be (2, H, W) or (S, 2, H, W), got shape {inputs.shape}")
        if batch.shape[-2:] != (self.native, self.native):
            raise ValueError(f"inputs are {batch.shape[-2]}x{batch.shape[-1]} px but checkpoint "
                             f"{self.path!r} was trained on {self.native}x{self.native} px")
        if self.needs_n_cells:
            n_cells = self.estimate_n_cells(batch) if n_cells is None else \
                np.broadcast_to(np.asarray(n_cells, dtype=np.float64), (len(batch),))
        else:
            n_cells = None
        if self.needs_lattice:
            if lattice is None:
                warnings.warn(f"checkpoint {self.path!r} reads the lattice channels; estimating "
                              "them from the mask pixels (pass lattice= from the mould's "
                              "geometry for the exact ones)", stacklevel=2)
                lattice = self.estimate_lattice(batch)
            else:
                lattice = np.asarray(lattice, dtype=np.float32).reshape(batch.shape)
        by_variable = {"inputs": batch, "lattice": lattice}  # the store's names (samples.py)
        for name in ("stress", "stress_tensor"):
            if name in INPUT_VARIABLES[self.inputs_kind]:
                by_variable[name] = stress_channels(batch, name == "stress_tensor")
        network_inputs = np.concatenate([np.asarray(by_variable[name], dtype=np.float32)
                                         for name in INPUT_VARIABLES[self.inputs_kind]], axis=1)
        raw, spread = run_model(self.model, self.scaling, network_inputs, self.mode, batch_size,
                                self.device, self.symmetrise, n_cells, self.inputs_kind,
                                self.precision)
        normalised, sums = normalise_predicted(raw), density_sums(raw)
        if single:
            return Prediction(raw[0], normalised[0], float(sums[0]),
                              None if spread is None else spread[0])
        return Prediction(raw, normalised, sums, spread)


def predict(checkpoint_path, inputs, mode: str | None = None, device=None,
            symmetrise: bool | None = None, n_cells=None,
            precision: str = DEFAULT_PRECISION) -> Prediction:
    """Predict fields for mould inputs (2, H, W) or (S, 2, H, W) (channels mould, tether; 0/1;
    native resolution of the training data). `mode` (a models.PREDICTION_MODES entry)
    and `symmetrise` (test-time symmetrisation) default to the checkpoint's training config;
    `n_cells`: see Predictor.__call__."""
    return Predictor(checkpoint_path, device=device, mode=mode, symmetrise=symmetrise,
                     precision=precision)(inputs, n_cells=n_cells)


def _binary(mask: np.ndarray, what: str) -> np.ndarray:
    values = np.unique(mask)
    if not np.isin(values, (0, 1)).all():
        raise ValueError(f"{what} must hold 0/1 values, found {values[:6].tolist()}")
    return mask.astype(np.uint8)


def _png_channels(path) -> np.ndarray:
    """A picture -> (2, H, W) 0/1: channels (mould, tether) from grey+alpha ("LA") or from
    red and green (RGB/RGBA); a pixel is set where the channel is >= 50%. Row 0 of the
    picture is the top, i.e. the highest y (pictures are drawn with origin="lower")."""
    from PIL import Image

    with Image.open(path) as image:
        mode = image.mode
        if mode not in ("LA", "RGB", "RGBA"):
            raise ValueError(f"{path}: picture mode {mode!r} has no two channels; expected LA, "
                             "RGB or RGBA (mould in the first channel, tether in the second)")
        pixels = np.asarray(image)
    return (pixels[::-1, :, :2].transpose(2, 0, 1) >= 128).astype(np.uint8)


def read_mould_inputs(path, pixels: int, box: float | None = None) -> np.ndarray:
    """Input channels (2, pixels, pixels) uint8 given as a picture of them: a (2, H, W) 0/1
    .npy array (mould, tether) or a two-channel .png (see _png_channels), at the checkpoint's
    grid. (A mould itself, as JSON, SVG or DXF: condor.moulds.read.load_mould.)"""
    path = Path(path)
    suffix = path.suffix.lower()
    if suffix == ".npy":
        array = np.load(path, allow_pickle=False)
    elif suffix == ".png":
        array = _png_channels(path)
    else:
        raise ValueError(f"input channels {str(path)!r} must end in .npy or .png (a mould: "
                         ".json, .svg or .dxf)")
    if array.ndim != 3 or array.shape[0] != 2 or array.shape[1] != array.shape[2]:
        raise ValueError(f"{path}: inputs must have shape (2, H, H), got {array.shape}")
    array = _binary(array, str(path))
    if array.shape[-1] != pixels:
        raise ValueError(f"{path}: inputs are {array.shape[-1]} x {array.shape[-1]} px, the "
                         f"checkpoint was trained on {pixels} x {pixels} px (resample them "
                         "yourself if you mean it: a pixel is a length in l0)")
    return array


FIELD_LONG_NAMES = {
    "P": "cell density", "T": "tension", "Sx2": "orientation tensor s_x s_x",
    "Sy2": "orientation tensor s_y s_y", "Sz2": "orientation tensor s_z s_z",
    "SxSy": "orientation tensor s_x s_y", "SxSz": "orientation tensor s_x s_z (zero by the "
    "mould's z-mirror symmetry)", "SySz": "orientation tensor s_y s_z (zero by the mould's "
    "z-mirror symmetry)"}


def grid_coordinates(n: int, pixel_size: float | None, l0_um: float | None = None) -> dict:
    """CF coordinates x and y of an n-pixel grid: pixel centres in mm given l0_um (with
    x_l0, y_l0 beside them), else in l0 (in pixels when pixel_size is None); each with
    units, long_name, standard_name and axis."""
    step = 1.0 if pixel_size is None else float(pixel_size)
    centres = (np.arange(n) + 0.5) * step
    unit = "pixel" if pixel_size is None else "l0"
    coords = {}
    for axis in ("x", "y"):
        base = {"standard_name": f"projection_{axis}_coordinate", "axis": axis.upper()}
        if l0_um is not None and pixel_size is not None:
            coords[axis] = (axis, centres * float(l0_um) / 1000.0,
                            {**base, "units": "mm", "long_name": f"{axis} of the pixel centre "
                             f"from the box's {'left' if axis == 'x' else 'lower'} edge "
                             f"(l0 = {float(l0_um):g} um)"})
            coords[f"{axis}_l0"] = (axis, centres, {"units": "l0", "long_name": f"{axis} in "
                                    "cell spacings l0"})
        else:
            coords[axis] = (axis, centres, {**base, "units": unit, "long_name": f"{axis} of "
                            f"the pixel centre from the box's {'left' if axis == 'x' else 'lower'} edge"
                            + (" (l0: the cells' spacing)" if unit == "l0" else "")})
    return coords


def prediction_dataset(prediction: Prediction, inputs: np.ndarray, pixel_size: float | None,
                       attrs: dict | None = None, l0_um: float | None = None):
    """One prediction as an xarray.Dataset: `raw` and `normalised` (field, y, x), `spread`
    (field, y, x; when the checkpoint predicts it), `inputs` (channel, y, x); x/y pixel
    centres (grid_coordinates: in mm given l0_um, else l0; pixels when pixel_size is None),
    every variable and coordinate with CF `units` and `long_name`."""
    n = inputs.shape[-1]
    per_field = {"field_long_names": [FIELD_LONG_NAMES[f] for f in FIELD_NAMES]}
    variables = {
        "raw": (("field", "y", "x"), prediction.raw,
                {"long_name": "predicted expected fields: per pixel, the kernel-weighted sum over "
                 "cells (P in cells; T in the model's tension units)", "units": "1",
                 **per_field}),
        "normalised": (("field", "y", "x"), prediction.normalised,
                       {"long_name": "predicted expected fields, normalised per cell (raw * "
                        "N_pixels / N_c)", "units": "1", **per_field}),
        "inputs": (("channel", "y", "x"), np.asarray(inputs, dtype=np.uint8),
                   {"long_name": "input masks: mould, tether (0/1)", "units": "1"})}
    if prediction.spread is not None:
        variables["spread"] = (("field", "y", "x"), prediction.spread,
                               {"long_name": "standard deviation of one simulation's field "
                                "around the expected (raw) field, per pixel", "units": "1",
                                "description": "standard deviation of one simulation's field "
                                               "around the expected (raw) field, per pixel"})
    coords = {"field": ("field", list(FIELD_NAMES), {"long_name": "field name"}),
              "channel": ("channel", ["mould", "tether"], {"long_name": "input channel"}),
              **grid_coordinates(n, pixel_size, l0_um)}
    length_unit = "pixel" if pixel_size is None else ("mm" if l0_um is not None else "l0")
    return xr.Dataset(
        variables, coords=coords,
        attrs={"Conventions": "CF-1.10", "n_cells": float(prediction.n_cells),
               "length_unit": length_unit, **(attrs or {})})


def write_prediction(path, prediction: Prediction, inputs: np.ndarray,
                     pixel_size: float | None = None, attrs: dict | None = None,
                     overwrite: bool = False, l0_um: float | None = None) -> None:
    """Write a prediction as a .zarr store (xarray, see prediction_dataset); an existing one is
    replaced only with `overwrite`. (A picture of it: condor.plots.prediction_panels.)"""
    path = Path(path)
    if path.suffix.lower() != ".zarr":
        raise ValueError(f"prediction store {str(path)!r} must end in .zarr")
    with quiet_zarr():
        prediction_dataset(prediction, inputs, pixel_size, attrs, l0_um).to_zarr(
            path, mode="w" if overwrite else "w-")
