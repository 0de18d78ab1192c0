"""A mould's input channels given as a picture of them: a (2, H, W) 0/1 .npy array or a
two-channel .png (a mould itself, as JSON, SVG or DXF: condor.moulds.read.load_mould)."""

from __future__ import annotations

from pathlib import Path

import numpy as np


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
    grid."""
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
