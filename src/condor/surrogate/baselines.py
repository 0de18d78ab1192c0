"""Baselines the surrogate must beat, evaluated with the same metrics:

- MaskedMeanBaseline: per pixel, the training-set mean of each field over the samples where
  that pixel is inside the mould, and the mean over samples where it is outside; a new mould
  selects one or the other per pixel.
- MouldBlurBaseline: the mould (tethers included) convolved with a Gaussian, mapped to each
  field by least squares (field ~ a_f * blur + b_f) on the training set.

Inputs are (S, 2, H, W) 0/1 (mould, tether), fields (S, 8, H, W), all at one resolution.
"""

from __future__ import annotations

import numpy as np

from ..model.scenes import SIGMA_L0


def gaussian_matrix(n: int, sigma_px: float) -> np.ndarray:
    """(n, n) matrix K with (K @ v)[i] = sum_j g(i - j) v[j], g a unit-sum-on-the-infinite-line
    sampled Gaussian of `sigma_px` pixels; zero outside the grid."""
    if sigma_px <= 0:
        raise ValueError(f"sigma_px must be positive, got {sigma_px}")
    d = np.arange(n)[:, None] - np.arange(n)[None, :]
    radius = int(np.ceil(4 * sigma_px))
    g = np.exp(-0.5 * (d / sigma_px) ** 2) * (np.abs(d) <= radius)
    norm = np.exp(-0.5 * (np.arange(-radius, radius + 1) / sigma_px) ** 2).sum()
    return g / norm


def gaussian_blur(images: np.ndarray, sigma_px: float) -> np.ndarray:
    """Separable Gaussian blur of (..., H, W) images with zero padding."""
    ky = gaussian_matrix(images.shape[-2], sigma_px)
    kx = gaussian_matrix(images.shape[-1], sigma_px)
    return ky @ images @ kx.T


def occupied(inputs: np.ndarray) -> np.ndarray:
    """Mould or tether (tether pixels are not mould pixels, but cells sit on them): (S, H, W)."""
    return np.clip(inputs[:, 0] + inputs[:, 1], 0, 1).astype(np.float64)


class MaskedMeanBaseline:
    name = "masked_mean"

    def fit(self, inputs: np.ndarray, fields: np.ndarray) -> "MaskedMeanBaseline":
        m = occupied(inputs)[:, None]  # (S, 1, H, W)
        inside = m.sum(axis=0)
        outside = (1 - m).sum(axis=0)
        with np.errstate(invalid="ignore", divide="ignore"):
            self.mean_in = np.nan_to_num((fields * m).sum(axis=0) / inside)
            self.mean_out = np.nan_to_num((fields * (1 - m)).sum(axis=0) / outside)
        return self

    def predict(self, inputs: np.ndarray) -> np.ndarray:
        m = occupied(inputs)[:, None]
        return (m * self.mean_in + (1 - m) * self.mean_out).astype(np.float32)


class MouldBlurBaseline:
    """sigma_px defaults to the fields' kernel width (SIGMA_L0 / pixel_size) widened by a fit
    over a few multiples, chosen by training-set squared error."""

    name = "mould_blur"

    def __init__(self, pixel_size: float, sigma_multiples=(1.0, 1.5, 2.0, 3.0)):
        self.pixel_size = pixel_size
        self.sigma_multiples = tuple(sigma_multiples)

    def _design(self, inputs: np.ndarray, sigma_px: float) -> np.ndarray:
        return gaussian_blur(occupied(inputs), sigma_px)

    def _lstsq(self, blur: np.ndarray, fields: np.ndarray):
        # field_f ~ a_f * blur + b_f over every pixel of every training sample.
        A = np.stack([blur.ravel(), np.ones(blur.size)], axis=1)
        B = fields.transpose(1, 0, 2, 3).reshape(fields.shape[1], -1).T
        coef, *_ = np.linalg.lstsq(A, B, rcond=None)
        residual = ((A @ coef - B) ** 2).sum()
        return coef, residual

    def fit(self, inputs: np.ndarray, fields: np.ndarray) -> "MouldBlurBaseline":
        best = None
        for mult in self.sigma_multiples:
            sigma_px = mult * SIGMA_L0 / self.pixel_size
            coef, residual = self._lstsq(self._design(inputs, sigma_px), fields.astype(np.float64))
            if best is None or residual < best[2]:
                best = (sigma_px, coef, residual)
        self.sigma_px, self.coef, _ = best
        return self

    def predict(self, inputs: np.ndarray) -> np.ndarray:
        blur = self._design(inputs, self.sigma_px)[:, None]  # (S, 1, H, W)
        a, b = self.coef[0][:, None, None], self.coef[1][:, None, None]
        return (a * blur + b).astype(np.float32)


def fit_baselines(train_inputs: np.ndarray, train_fields: np.ndarray, pixel_size: float) -> list:
    """Every baseline, fitted on training inputs (S, 2, H, W) and fields (S, 8, H, W)."""
    return [MaskedMeanBaseline().fit(train_inputs, train_fields),
            MouldBlurBaseline(pixel_size).fit(train_inputs, train_fields)]
