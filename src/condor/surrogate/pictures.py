"""A mould's input channels given as masks: a (2, H, W) 0/1 .npy array (mould, tether) on the
checkpoint's grid. A picture of a mould (PNG, TIFF, JPEG) is a mould, read as one:
condor.moulds.read_picture (and a mould file: condor.moulds.read.load_mould)."""

from __future__ import annotations

from pathlib import Path

import numpy as np


def _binary(mask: np.ndarray, what: str) -> np.ndarray:
    values = np.unique(mask)
    if not np.isin(values, (0, 1)).all():
        raise ValueError(f"{what} must hold 0/1 values, found {values[:6].tolist()}")
    return mask.astype(np.uint8)


def read_mould_inputs(path, pixels: int, box: float | None = None) -> np.ndarray:
    """Input channels (2, pixels, pixels) uint8 given as a (2, H, W) 0/1 .npy array (mould,
    tether) at the checkpoint's grid."""
    path = Path(path)
    if path.suffix.lower() != ".npy":
        raise ValueError(f"input channels {str(path)!r} must end in .npy (a mould: .json, .svg, "
                         ".dxf, or a picture of it: .png, .tif, .jpg)")
    array = np.load(path, allow_pickle=False)
    if array.ndim != 3 or array.shape[0] != 2 or array.shape[1] != array.shape[2]:
        raise ValueError(f"{path}: inputs must have shape (2, H, H), got {array.shape}")
    array = _binary(array, str(path))
    if array.shape[-1] != pixels:
        raise ValueError(f"{path}: masks are {array.shape[-1]} x {array.shape[-1]} px, the "
                         f"checkpoint was trained on {pixels} x {pixels} px (a picture of the "
                         "mould, .png, .tif or .jpg, is read at any size)")
    return array
