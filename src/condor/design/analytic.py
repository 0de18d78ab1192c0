"""An analytic stand-in for the surrogate, with known answers: for tests, for benchmarking
the search's own cost (geometry, rasterising, scoring) without a network, and for docs.

`AnalyticPredictor(native, box)(inputs)` maps mould inputs (S, 2, H, W) 0/1 to fields:
P = the occupied pixels (mould or tether) blurred by the scene's kernel; T = 0.01 x the
blurred tethers; a fraction q of each cell's orientation lies in the plane, with the in-plane
order tensor of the whole raster's second moments: with I the second-moment tensor of the
occupied pixels about their centroid, a = (Ixx - Iyy) / (Ixx + Iyy), b = 2 Ixy / (Ixx + Iyy),
Sx2 = q P (1 + a) / 2, Sy2 = q P (1 - a) / 2, SxSy = q P b / 2, Sz2 = (1 - q) P. So
alignment:THETA of its fields is exactly a cos 2THETA + b sin 2THETA of the raster: longer
along THETA is better, and the best mould is as long along THETA as the extent rule allows.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from condor.model.scenes import SIGMA_L0
from condor.surrogate.baselines import gaussian_blur


@dataclass
class AnalyticPrediction:
    raw: np.ndarray
    normalised: np.ndarray
    n_cells: np.ndarray


def raster_order(inputs: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """(a, b) of each raster (S, 2, H, W): the in-plane order of its second moments."""
    occupied = np.clip(inputs[:, 0] + inputs[:, 1], 0, 1).astype(np.float64)
    n = occupied.shape[-1]
    centres = np.arange(n) + 0.5
    x, y = np.meshgrid(centres, centres)
    mass = occupied.sum(axis=(1, 2))
    mx = (occupied * x).sum(axis=(1, 2)) / mass
    my = (occupied * y).sum(axis=(1, 2)) / mass
    dx, dy = x[None] - mx[:, None, None], y[None] - my[:, None, None]
    ixx, iyy = (occupied * dx * dx).sum(axis=(1, 2)), (occupied * dy * dy).sum(axis=(1, 2))
    ixy = (occupied * dx * dy).sum(axis=(1, 2))
    return (ixx - iyy) / (ixx + iyy), 2 * ixy / (ixx + iyy)


class AnalyticPredictor:
    """Callable like condor.surrogate.predict.Predictor (native, box, __call__)."""

    def __init__(self, native: int, box: float, in_plane: float = 0.8):
        self.native, self.box, self.in_plane = int(native), float(box), float(in_plane)
        self.calls = 0  # how many batches it was asked to predict

    def __call__(self, inputs) -> AnalyticPrediction:
        inputs = np.asarray(inputs, dtype=np.float64)
        if inputs.ndim != 4 or inputs.shape[1:] != (2, self.native, self.native):
            raise ValueError(f"inputs must be (S, 2, {self.native}, {self.native}), got "
                             f"{inputs.shape}")
        self.calls += 1
        sigma_px = SIGMA_L0 * self.native / self.box
        a, b = (v[:, None, None] for v in raster_order(inputs))
        density = gaussian_blur(np.clip(inputs[:, 0] + inputs[:, 1], 0, 1), sigma_px)
        q = self.in_plane
        raw = np.zeros((len(inputs), 8, self.native, self.native))
        raw[:, 0] = density
        raw[:, 1] = 0.01 * gaussian_blur(inputs[:, 1], sigma_px)
        raw[:, 2] = q * density * (1 + a) / 2
        raw[:, 3] = q * density * (1 - a) / 2
        raw[:, 4] = (1 - q) * density
        raw[:, 5] = q * density * b / 2
        n_cells = density.sum(axis=(1, 2))
        normalised = raw * (self.native**2 / n_cells)[:, None, None, None]
        return AnalyticPrediction(raw, normalised, n_cells)
