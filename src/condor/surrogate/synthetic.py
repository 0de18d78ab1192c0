"""A small synthetic dataset with the real dataset's layout, for tests, benchmarks and docs:
random rectangular and elliptical moulds with a few disc tethers; the fields are fixed linear
maps of blurred mould and tether masks plus a smooth x-gradient term (so a network must use
position and shape, and a masked mean cannot fit them)."""

from __future__ import annotations

import numpy as np
import xarray as xr

from .baselines import gaussian_blur
from .samples import CHANNEL_NAMES, FIELD_NAMES

# Per field: weight of blurred occupancy, of blurred tethers, of occupancy * x/size.
_MIX = np.array([[0.8, 0.4, 0.0], [0.1, 2.0, 0.0], [0.2, -0.3, 0.5], [0.5, -0.1, -0.4],
                 [0.05, 0.6, 0.0], [0.0, 0.2, 0.3], [0.0, 0.1, 0.0], [0.0, -0.1, 0.05]])


def _mould(rng: np.random.Generator, size: int) -> tuple[np.ndarray, np.ndarray]:
    yy, xx = np.mgrid[0:size, 0:size] + 0.5
    cx, cy = rng.uniform(0.4, 0.6, 2) * size
    ax, ay = rng.uniform(0.2, 0.4, 2) * size
    if rng.random() < 0.5:
        mould = (np.abs(xx - cx) < ax) & (np.abs(yy - cy) < ay)
    else:
        mould = ((xx - cx) / ax) ** 2 + ((yy - cy) / ay) ** 2 < 1
    tether = np.zeros_like(mould)
    for _ in range(rng.integers(1, 4)):
        tx, ty = cx + rng.uniform(-0.6, 0.6) * ax, cy + rng.uniform(-0.6, 0.6) * ay
        tether |= (xx - tx) ** 2 + (yy - ty) ** 2 < (0.06 * size) ** 2
    return mould & ~tether, tether


def synthetic_dataset(n: int = 8, size: int = 32, seed: int = 0,
                      splits=("train", "train", "train", "train", "train", "val", "test", "test"),
                      sigma_px: float = 1.5) -> xr.Dataset:
    """n samples of size x size px; split labels cycle through `splits`."""
    rng = np.random.default_rng([seed, n, size])
    masks = np.stack([np.stack(_mould(rng, size)) for _ in range(n)]).astype(np.uint8)
    occ = np.clip(masks[:, 0] + masks[:, 1], 0, 1).astype(np.float64)
    x = (np.arange(size) + 0.5) / size
    basis = np.stack([gaussian_blur(occ, sigma_px), gaussian_blur(masks[:, 1].astype(float), sigma_px),
                      gaussian_blur(occ * x, sigma_px)], axis=1)  # (n, 3, H, W)
    fields = np.einsum("fk,skyx->sfyx", _MIX, basis).astype(np.float32)
    split = np.array([splits[i % len(splits)] for i in range(n)])
    # a stand-in for the lattice channels (condor.data.inputs): the masks at the kernel's blur
    lattice = np.stack([gaussian_blur(masks[:, c].astype(float), sigma_px) for c in range(2)],
                       axis=1).astype(np.float32)
    return xr.Dataset(
        {"inputs": (("sample", "channel", "y", "x"), masks),
         "lattice": (("sample", "cell", "y", "x"), lattice),
         "fields": (("sample", "field", "y", "x"), fields),
         "split": ("sample", split), "status": ("sample", np.array(["ok"] * n)),
         "n_cells": ("sample", np.rint(fields[:, 0].sum(axis=(1, 2))).astype(np.int64))},
        coords={"sample": np.arange(n), "channel": list(CHANNEL_NAMES), "field": list(FIELD_NAMES),
                "cell": ["mobile", "fixed"]},
        attrs={"pixel_size": 15.625 / size})
