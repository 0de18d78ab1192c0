"""Prediction from a trained checkpoint: mould inputs -> the 8 fields, raw and normalised, and
their spread (`Predictor`, `predict`; the network's run itself: `run_model`).

Beside it: how the network runs (condor.surrogate.inference: device, precision, decode), the
test-time symmetrisation (condor.surrogate.symmetrise), a mould's inputs from a picture
(condor.surrogate.pictures) and the CF Zarr store of a prediction
(condor.surrogate.prediction_zarr)."""

from __future__ import annotations

import contextlib
import warnings
from dataclasses import dataclass

import numpy as np
import torch

from condor.data.inputs import derived_channels
from condor.measures.metrics import density_sums, normalise_predicted

from .checkpoint import generator_from_checkpoint, load_checkpoint, scaling_from_checkpoint
from .inference import decode, default_device, inference_model, resolve_precision, run_network
from .modes import DEFAULT_PRECISION
from .networks import UNetGenerator, prediction_mode
from .physics import estimate_n_cells
from .samples import DERIVED_INPUTS, FIELD_NAMES, INPUT_VARIABLES, resample_fields, resample_inputs
from .symmetrise import symmetrised


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
    predictions (8 model runs: condor.surrogate.symmetrise). `n_cells` (S,): N_c per mould, needed by a
    physics head (condor.surrogate.physics). `precision` (PRECISIONS): the network's arithmetic
    in "eval" mode (other modes run the model itself, in float32)."""
    device = default_device(device)
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
    network = inference_model(model, precision) if fast else model
    with contextlib.nullcontext() if fast else prediction_mode(model, mode), \
            torch.inference_mode():
        for start in range(0, inputs.shape[0], batch_size):
            part = slice(start, start + batch_size)
            x = resample_inputs(np.asarray(inputs[part], dtype=np.float32), size, inputs_kind)
            x = torch.from_numpy(np.ascontiguousarray(x)).to(device)
            cells = n_cells[part] if physics else None
            if symmetrise:
                y, spread = symmetrised(network, scaling, x, cells, inputs_kind,
                                        batched=mode == "eval")
            else:
                y, spread = decode(scaling, run_network(network, x).contiguous().double(), cells)
                y, spread = y.cpu().numpy(), None if spread is None else spread.cpu().numpy()
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
        for name in DERIVED_INPUTS:
            if name in INPUT_VARIABLES[self.inputs_kind]:
                by_variable[name] = derived_channels(batch, name)
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
    native resolution of the training data). `mode` (a modes.PREDICTION_MODES entry)
    and `symmetrise` (test-time symmetrisation) default to the checkpoint's training config;
    `n_cells`: see Predictor.__call__."""
    return Predictor(checkpoint_path, device=device, mode=mode, symmetrise=symmetrise,
                     precision=precision)(inputs, n_cells=n_cells)
