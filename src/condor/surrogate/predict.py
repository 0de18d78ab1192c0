"""Prediction from a trained checkpoint: mould inputs -> the 8 fields, raw and normalised."""

from __future__ import annotations

import warnings
from dataclasses import dataclass

import numpy as np
import torch

from .checkpoint import generator_from_checkpoint, load_checkpoint, scaling_from_checkpoint
from .data import (FIELD_NAMES, N_SYMMETRIES, FieldScaling, apply_symmetry, resample_fields,
                   resample_masks)
from .models import UNetGenerator, prediction_mode


def default_device(device=None) -> torch.device:
    """`device` if given, else CUDA when present, else CPU."""
    if device is not None:
        return torch.device(device)
    return torch.device("cuda" if torch.cuda.is_available() else "cpu")


def _symmetrised(model, scaling: FieldScaling, x: torch.Tensor) -> np.ndarray:
    """Mean over the 16 symmetries g of g^-1 G(g x), physical units (float64). The z-flip
    leaves the inputs unchanged, so each of the 8 planar transforms runs once and its z-flipped
    twin is its output with SxSz, SySz negated: the mean of those two sets them to zero."""
    total = 0.0
    for k in range(N_SYMMETRIES // 2):  # the planar ones (FLIP_Z is the highest bit)
        gx, _ = apply_symmetry(k, inputs=x)
        y = scaling.unscale(model(gx.contiguous()).double().cpu().numpy())
        for z in (0, N_SYMMETRIES // 2):
            total = total + apply_symmetry(k + z, fields=y, inverse=True)[1]
    return total / N_SYMMETRIES


def run_generator(model: UNetGenerator, scaling: FieldScaling, inputs: np.ndarray, mode: str = "eval",
                  batch_size: int = 16, device=None, symmetrise: bool = False) -> np.ndarray:
    """Inputs (S, 2, H, W) 0/1 at the native resolution -> physical fields (S, 8, H, W)
    float32 at the native resolution. The model runs at its own resolution (inputs resampled
    nearest, outputs resampled conserving sums). Modes other than "eval" depend on the batch,
    so they run one sample at a time as the paper did. `symmetrise`: the mean over the 16
    symmetries of the transformed-back predictions (8 model runs: see _symmetrised)."""
    device = default_device(device) if device is None else torch.device(device)
    native = inputs.shape[-1]
    size = model.cfg.size
    if mode != "eval":
        batch_size = 1
    out = np.empty((inputs.shape[0], model.cfg.out_channels, native, native), dtype=np.float32)
    with prediction_mode(model, mode), torch.no_grad():
        for start in range(0, inputs.shape[0], batch_size):
            x = resample_masks(np.asarray(inputs[start:start + batch_size], dtype=np.float32), size)
            x = torch.from_numpy(np.ascontiguousarray(x)).to(device)
            y = _symmetrised(model, scaling, x) if symmetrise else \
                scaling.unscale(model(x).double().cpu().numpy())
            out[start:start + batch_size] = resample_fields(y, native)
    return out


def normalise(raw: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """Paper eq. (normalisation): Z_bar = Z * N_p / N_c with N_p the pixel count and N_c the
    sum of the (predicted) density P over the grid. raw (..., 8, H, W) -> (normalised, N_c);
    N_c <= 0 gives NaN fields."""
    n_pixels = raw.shape[-1] * raw.shape[-2]
    n_cells = raw[..., 0, :, :].sum(axis=(-2, -1), dtype=np.float64)
    with np.errstate(divide="ignore", invalid="ignore"):
        factor = np.where(n_cells > 0, n_pixels / n_cells, np.nan)
    return (raw * factor[..., None, None, None]).astype(np.float32), n_cells


@dataclass
class Prediction:
    raw: np.ndarray  # (8, H, W) or (S, 8, H, W): the weighted sums Z_p, as trained
    normalised: np.ndarray  # raw * N_p / N_c
    n_cells: np.ndarray | float  # N_c, predicted sum of P


class Predictor:
    """A loaded checkpoint, for repeated predictions."""

    def __init__(self, checkpoint_path, device=None, mode: str | None = None,
                 symmetrise: bool | None = None):
        self.path = str(checkpoint_path)
        self.device = default_device(device)
        state = load_checkpoint(checkpoint_path)
        self.model = generator_from_checkpoint(state, self.path).to(self.device)
        self.scaling = scaling_from_checkpoint(state)
        self.native = int(state["data"]["native_size"])
        self.mode = mode or state["config"].get("prediction_mode", "eval")
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

    def __call__(self, inputs, batch_size: int = 16) -> Prediction:
        inputs = np.asarray(inputs)
        single = inputs.ndim == 3
        batch = inputs[None] if single else inputs
        if batch.ndim != 4 or batch.shape[1] != 2:
            raise ValueError(f"inputs must be (2, H, W) or (S, 2, H, W), got shape {inputs.shape}")
        if batch.shape[-2:] != (self.native, self.native):
            raise ValueError(f"inputs are {batch.shape[-2]}x{batch.shape[-1]} px but checkpoint "
                             f"{self.path!r} was trained on {self.native}x{self.native} px")
        raw = run_generator(self.model, self.scaling, batch, self.mode, batch_size, self.device,
                            self.symmetrise)
        normalised, n_cells = normalise(raw)
        if single:
            return Prediction(raw[0], normalised[0], float(n_cells[0]))
        return Prediction(raw, normalised, n_cells)


def predict(checkpoint_path, inputs, mode: str | None = None, device=None,
            symmetrise: bool | None = None) -> Prediction:
    """Predict fields for mould inputs (2, H, W) or (S, 2, H, W) (channels mould, tether; 0/1;
    native resolution of the training data). `mode` (a models.PREDICTION_MODES entry)
    and `symmetrise` (test-time symmetrisation) default to the checkpoint's training config."""
    return Predictor(checkpoint_path, device=device, mode=mode, symmetrise=symmetrise)(inputs)


def plot_prediction(inputs: np.ndarray, fields: np.ndarray, path=None, title: str = "",
                    field_names=FIELD_NAMES):
    """Figure: mould and tether inputs, then each field. Returns the matplotlib Figure (saved
    to `path` when given)."""
    import matplotlib
    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    n = 2 + len(field_names)
    fig, axes = plt.subplots(2, (n + 1) // 2, figsize=(2.4 * ((n + 1) // 2), 5))
    panels = [("mould", inputs[0]), ("tether", inputs[1])] + list(zip(field_names, fields))
    for ax, (name, image) in zip(axes.flat, panels):
        im = ax.imshow(image, origin="lower", cmap="viridis")
        ax.set_title(name, fontsize=9)
        ax.set_xticks([]), ax.set_yticks([])
        fig.colorbar(im, ax=ax, fraction=0.046)
    for ax in list(axes.flat)[len(panels):]:
        ax.axis("off")
    fig.suptitle(title)
    fig.tight_layout()
    if path is not None:
        fig.savefig(path, dpi=100)
        plt.close(fig)
    return fig


# --- reading moulds, writing predictions (the `condor predict` command) -------------------

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
    """Input channels (2, pixels, pixels) uint8 for the mould in `path`:

    - .json: a mould from `condor mould` / `condor.moulds.save_json`, rasterised with
      `condor.moulds.input_channels` (its box must equal `box` in l0, when given);
    - .npy: a (2, H, W) 0/1 array (mould, tether);
    - .png: a two-channel picture (see _png_channels).
    Arrays at another resolution are resampled when the ratio is an integer."""
    from pathlib import Path

    path = Path(path)
    suffix = path.suffix.lower()
    if suffix == ".json":
        from condor.moulds import input_channels, load_json

        mould = load_json(path)
        if box is not None and abs(mould.box - box) > 1e-6 * box:
            raise ValueError(f"{path} is a mould for a {mould.box:g} l0 box, the checkpoint was "
                             f"trained on a {box:g} l0 box")
        return input_channels(mould, pixels)
    if suffix == ".npy":
        array = np.load(path, allow_pickle=False)
    elif suffix == ".png":
        array = _png_channels(path)
    else:
        raise ValueError(f"mould file {str(path)!r} must end in .json, .npy or .png")
    if array.ndim != 3 or array.shape[0] != 2 or array.shape[1] != array.shape[2]:
        raise ValueError(f"{path}: inputs must have shape (2, H, H), got {array.shape}")
    array = _binary(array, str(path))
    if array.shape[-1] != pixels:
        raise ValueError(f"{path}: inputs are {array.shape[-1]} x {array.shape[-1]} px, the "
                         f"checkpoint was trained on {pixels} x {pixels} px (resample them "
                         "yourself if you mean it: a pixel is a length in l0)")
    return array


def prediction_dataset(prediction: Prediction, inputs: np.ndarray, pixel_size: float | None,
                       attrs: dict | None = None):
    """One prediction as an xarray.Dataset: `raw` and `normalised` (field, y, x), `inputs`
    (channel, y, x), x/y pixel centres in l0 (in pixels when pixel_size is None)."""
    import xarray as xr

    n = inputs.shape[-1]
    step = 1.0 if pixel_size is None else float(pixel_size)
    centres = (np.arange(n) + 0.5) * step
    return xr.Dataset(
        {"raw": (("field", "y", "x"), prediction.raw),
         "normalised": (("field", "y", "x"), prediction.normalised),
         "inputs": (("channel", "y", "x"), np.asarray(inputs, dtype=np.uint8))},
        coords={"field": list(FIELD_NAMES), "channel": ["mould", "tether"], "y": centres,
                "x": centres},
        attrs={"n_cells": float(prediction.n_cells),
               "length_unit": "l0" if pixel_size is not None else "pixel", **(attrs or {})})


def plot_raw_and_normalised(inputs: np.ndarray, prediction: Prediction, path, title: str = ""):
    """Figure: the inputs, then each field raw (middle row) and normalised (bottom row)."""
    import matplotlib
    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    n = len(FIELD_NAMES)
    fig, axes = plt.subplots(3, n, figsize=(2.2 * n, 6.6))
    rows = [[("mould", inputs[0]), ("tether", inputs[1])],
            [(f"{k} raw", f) for k, f in zip(FIELD_NAMES, prediction.raw)],
            [(f"{k} normalised", f) for k, f in zip(FIELD_NAMES, prediction.normalised)]]
    for ax_row, panels in zip(axes, rows):
        for ax in ax_row:
            ax.axis("off")
        for ax, (name, image) in zip(ax_row, panels):
            ax.axis("on")
            im = ax.imshow(image, origin="lower", cmap="viridis")
            ax.set_title(name, fontsize=8)
            ax.set_xticks([]), ax.set_yticks([])
            fig.colorbar(im, ax=ax, fraction=0.046)
    fig.suptitle(title)
    fig.tight_layout()
    fig.savefig(path, dpi=90)
    plt.close(fig)


def write_prediction(path, prediction: Prediction, inputs: np.ndarray,
                     pixel_size: float | None = None, attrs: dict | None = None,
                     overwrite: bool = False) -> None:
    """Write a prediction to `path`: a .zarr store (xarray, see prediction_dataset) or a
    .png picture; ValueError for another suffix. An existing .zarr is replaced only with
    `overwrite`."""
    from pathlib import Path

    path = Path(path)
    suffix = path.suffix.lower()
    if suffix == ".zarr":
        with warnings.catch_warnings():
            # zarr 3 warns that string coordinates and consolidated metadata are outside the
            # v3 spec; xarray reads both back.
            warnings.filterwarnings("ignore", module="zarr")
            prediction_dataset(prediction, inputs, pixel_size, attrs).to_zarr(
                path, mode="w" if overwrite else "w-")
    elif suffix == ".png":
        title = f"predicted fields, N_c = {float(prediction.n_cells):.1f}"
        plot_raw_and_normalised(inputs, prediction, path, title)
    else:
        raise ValueError(f"--out {str(path)!r} must end in .zarr or .png")
