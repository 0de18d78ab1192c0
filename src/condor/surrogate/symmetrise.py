"""Test-time symmetrisation: the mean over the 16 exact symmetries g of the mould (mirrors,
transpose, z-flip) of g^-1 G(g x), and the root mean of the transformed-back spread variances.

The z-flip leaves the inputs unchanged, so each of the 8 planar transforms runs once and its
z-flipped twin is its output with SxSz, SySz negated: the mean of the two sets them to zero.
`symmetrised` is the product's one path: the network runs on the 8 planar transforms, each
output is decoded where the network wrote it (`inference.decode`: per pixel, but for the
physics head's softmax over the grid, which does not depend on the pixels' order), then moved
back and summed in one compiled pass (physics.symmetrised_sum_kernel), float64.
`symmetrised_reference` is the same mean written plainly, each transform decoded and moved
back by apply_symmetry one at a time: what the tests hold the product against
(tests/test_surrogate_predict.py).
"""

from __future__ import annotations

import numpy as np
import torch

from .inference import decode, run_network
from .physics import symmetrised_sum_kernel
from .samples import FIELD_NAMES, N_SYMMETRIES, apply_symmetry

PLANAR = N_SYMMETRIES // 2  # the planar transforms 0..7 (FLIP_Z is the highest bit)


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


def symmetrised(model, scaling, x: torch.Tensor, n_cells, input_kind: str = "mask",
                batched: bool = True) -> tuple[np.ndarray, np.ndarray | None]:
    """Mean over the 16 symmetries of the physical fields the network predicts for inputs x
    (n, C, H, H), and the spread's root mean variance (None for a tanh head): float64 (n, 8,
    H, H) each. `batched`: the 8 transforms run as one batch of the network (the same numbers
    in "eval" mode, where a sample's output does not depend on its batch; a few times faster
    on a CPU); otherwise one transform at a time (the modes whose output depends on the
    batch). `n_cells` (n,): N_c per mould, for a physics head."""
    n, side = x.shape[0], x.shape[-1]
    moved = [apply_symmetry(k, inputs=x, input_kind=input_kind)[0] for k in range(PLANAR)]
    out = run_network(model, torch.cat(moved)) if batched else \
        torch.cat([run_network(model, part) for part in moved])
    if out.shape[-2:] != (side, side):
        raise ValueError(f"symmetrisation needs a square grid, got {tuple(out.shape[-2:])}")
    cells = None if n_cells is None else \
        np.tile(np.asarray(n_cells, dtype=np.float32).reshape(n), PLANAR)
    fields, spread = decode(scaling, out.contiguous(), cells)  # NCHW: decode's slices are planes
    shape = (PLANAR, n, len(FIELD_NAMES), side * side)
    fields = fields.cpu().numpy().reshape(shape)
    spreads = np.zeros_like(fields) if spread is None else spread.cpu().numpy().reshape(shape)
    source, weight, variance_weight = _FIELD_MAPS
    mean = np.zeros((n, len(FIELD_NAMES), side * side))
    variance = np.zeros_like(mean)
    symmetrised_sum_kernel(fields, spreads, _pixel_sources(side), source.astype(np.int64),
                           weight.astype(np.float64), variance_weight.astype(np.float64),
                           mean, variance)
    shape = (n, len(FIELD_NAMES), side, side)
    return (mean / N_SYMMETRIES).reshape(shape), \
        None if spread is None else np.sqrt(variance / N_SYMMETRIES).reshape(shape)


def symmetrised_reference(model, scaling, x: torch.Tensor, n_cells,
                          input_kind: str = "mask") -> tuple[np.ndarray, np.ndarray | None]:
    """`symmetrised`, written plainly: each planar transform through the network, decoded in
    float64 and moved back with its z-flipped twin by apply_symmetry, one at a time. The
    tests hold the product's path against it; nothing else runs it."""
    total, variance = 0.0, 0.0
    for k in range(PLANAR):
        out = run_network(model, apply_symmetry(k, inputs=x, input_kind=input_kind)[0])
        y, spread = decode(scaling, out.contiguous().double(), n_cells)
        y = y.cpu().numpy()
        for z in (0, PLANAR):
            total = total + apply_symmetry(k + z, fields=y, inverse=True)[1]
            if spread is not None:  # variances move with the pixels; signs do not apply
                variance = variance + np.abs(apply_symmetry(
                    k + z, fields=spread.cpu().numpy() ** 2, inverse=True)[1])
    spread = None if np.isscalar(variance) else np.sqrt(variance / N_SYMMETRIES)
    return total / N_SYMMETRIES, spread
