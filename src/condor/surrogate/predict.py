"""Prediction from a trained checkpoint: mould inputs -> the 8 fields, raw and normalised."""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np
import torch

from .checkpoint import generator_from_checkpoint, load_checkpoint, scaling_from_checkpoint
from .data import FIELD_NAMES, FieldScaling, resample_fields, resample_masks
from .models import UNetGenerator, prediction_mode


def default_device(device=None) -> torch.device:
    """`device` if given, else CUDA when present, else CPU."""
    if device is not None:
        return torch.device(device)
    return torch.device("cuda" if torch.cuda.is_available() else "cpu")


def run_generator(model: UNetGenerator, scaling: FieldScaling, inputs: np.ndarray, mode: str = "eval",
                  batch_size: int = 16, device=None) -> np.ndarray:
    """Inputs (S, 2, H, W) 0/1 at the native resolution -> physical fields (S, 8, H, W)
    float32 at the native resolution. The model runs at its own resolution (inputs resampled
    nearest, outputs resampled conserving sums). Modes other than "eval" depend on the batch,
    so they run one sample at a time as the paper did."""
    device = default_device(device) if device is None else torch.device(device)
    native = inputs.shape[-1]
    size = model.cfg.size
    if mode != "eval":
        batch_size = 1
    out = np.empty((inputs.shape[0], model.cfg.out_channels, native, native), dtype=np.float32)
    with prediction_mode(model, mode), torch.no_grad():
        for start in range(0, inputs.shape[0], batch_size):
            x = resample_masks(np.asarray(inputs[start:start + batch_size], dtype=np.float32), size)
            y = model(torch.from_numpy(np.ascontiguousarray(x)).to(device)).double().cpu().numpy()
            out[start:start + batch_size] = resample_fields(scaling.unscale(y), native)
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

    def __init__(self, checkpoint_path, device=None, mode: str | None = None):
        self.path = str(checkpoint_path)
        self.device = default_device(device)
        state = load_checkpoint(checkpoint_path)
        self.model = generator_from_checkpoint(state, self.path).to(self.device)
        self.scaling = scaling_from_checkpoint(state)
        self.native = int(state["data"]["native_size"])
        self.mode = mode or state["config"].get("prediction_mode", "eval")
        self.state = state

    def __call__(self, inputs, batch_size: int = 16) -> Prediction:
        inputs = np.asarray(inputs)
        single = inputs.ndim == 3
        batch = inputs[None] if single else inputs
        if batch.ndim != 4 or batch.shape[1] != 2:
            raise ValueError(f"inputs must be (2, H, W) or (S, 2, H, W), got shape {inputs.shape}")
        if batch.shape[-2:] != (self.native, self.native):
            raise ValueError(f"inputs are {batch.shape[-2]}x{batch.shape[-1]} px but checkpoint "
                             f"{self.path!r} was trained on {self.native}x{self.native} px")
        raw = run_generator(self.model, self.scaling, batch, self.mode, batch_size, self.device)
        normalised, n_cells = normalise(raw)
        if single:
            return Prediction(raw[0], normalised[0], float(n_cells[0]))
        return Prediction(raw, normalised, n_cells)


def predict(checkpoint_path, inputs, mode: str | None = None, device=None) -> Prediction:
    """Predict fields for mould inputs (2, H, W) or (S, 2, H, W) (channels mould, tether; 0/1;
    native resolution of the training data). `mode` (a models.PREDICTION_MODES entry)
    defaults to the checkpoint's training config."""
    return Predictor(checkpoint_path, device=device, mode=mode)(inputs)


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
