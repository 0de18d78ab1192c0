"""The surrogate's training domain: how far a mould lies from the generated moulds a
surrogate was trained on (`training_domain_check`: warnings, or a refusal beyond
AREA_REFUSE). Simulation needs no such check: the model holds for any mould."""

from __future__ import annotations

import numpy as np

from condor.model.scenes import Scene, same_length
from condor.moulds.mould import InvalidMouldError, Mould
from condor.moulds.units import listing

# Training domain of the surrogate (generated moulds): area = scene.area_fraction of the
# box exactly, extent <= scene.max_extent, 0 or >= 4 tethers, and tether radii within
# TRAINING_TETHER_RADIUS box sides: the smallest and largest over 4,300 generated moulds
# (generate_mould(s, i) in a box of side 1, s = 1, 2 with i < 2000 and s = 11 with i < 300) were
# 0.0074 and 0.0539, rounded outwards here.
AREA_WARN = 0.10  # relative deviation of the area from the training area that warns
AREA_REFUSE = 0.50  # ... that refuses a prediction
TRAINING_MIN_TETHERS = 4
TRAINING_TETHER_RADIUS = (0.007, 0.06)  # box sides


class OutsideTrainingDomainError(InvalidMouldError):
    """A mould too far from the generated moulds for a surrogate's prediction to mean much."""


def training_domain_check(mould: Mould, scene: Scene) -> list[str]:
    """Warnings for predicting `mould` with a surrogate trained on `scene`'s generated moulds.

    Generated moulds all have area exactly scene.area_fraction of the box, width and
    height at most scene.max_extent of it, 0 or at least TRAINING_MIN_TETHERS tethers, and
    tether radii within TRAINING_TETHER_RADIUS box sides. A mould whose area differs from
    the training area by more than AREA_WARN (relative) gets a warning; by more than
    AREA_REFUSE, OutsideTrainingDomainError (simulate it instead). Extent, tether count and
    radii outside the training ranges, and tethers too small to mark any pixel of the input
    grid, get warnings. Simulation needs no such check: the model holds for any mould.
    """
    box = float(scene.box)
    if not same_length(mould.box, box):
        raise OutsideTrainingDomainError(
            f"the mould is placed in a {mould.box:g} l0 box, the {scene.name!r} scene (and a "
            f"surrogate trained on it) has {box:g} l0")
    warnings = []
    fraction = mould.polygon.area / box**2
    deviation = fraction / scene.area_fraction - 1
    area = (f"its area is {fraction:.3g} of the box, the training moulds' is exactly "
            f"{scene.area_fraction:g} ({deviation:+.0%})")
    if abs(deviation) > AREA_REFUSE:
        raise OutsideTrainingDomainError(
            f"{area}, beyond the +-{AREA_REFUSE:.0%} a prediction is allowed: simulate it, or "
            "scale it with --fit")
    if abs(deviation) > AREA_WARN:
        warnings.append(f"{area}: the prediction extrapolates (more than +-{AREA_WARN:.0%})")
    xmin, ymin, xmax, ymax = mould.polygon.bounds
    extent = max(xmax - xmin, ymax - ymin) / box
    if extent > scene.max_extent * (1 + 1e-9):
        warnings.append(f"its width or height is {extent:.3g} of the box, the training moulds' "
                        f"is at most {scene.max_extent:g}")
    tethers = np.asarray(mould.tethers, dtype=float).reshape(-1, 3)
    if 0 < len(tethers) < TRAINING_MIN_TETHERS:
        warnings.append(f"it has {len(tethers)} tethers, the training moulds have none or at "
                        f"least {TRAINING_MIN_TETHERS}")
    low, high = (r * box for r in TRAINING_TETHER_RADIUS)
    odd = [i for i, r in enumerate(tethers[:, 2]) if not low <= r <= high]
    if odd:
        warnings.append(f"tether radii {listing(tethers[odd, 2])} l0 (tethers {listing(odd)}) "
                        f"are outside the training range {low:.3g}-{high:.3g} l0")
    hidden = tethers_without_pixels(tethers, box, scene.pixels)
    if hidden:
        warnings.append(f"tethers {listing(hidden)} cover no pixel centre of the "
                        f"{scene.pixels} px input grid: the surrogate cannot see them")
    return warnings


def tethers_without_pixels(tethers: np.ndarray, box: float, pixels: int) -> list[int]:
    """Tethers whose disk holds no pixel centre (the rule of condor.moulds.mould.input_channels)."""
    size = box / pixels
    hidden = []
    for i, (x, y, r) in enumerate(tethers):
        ix = np.arange(max(0, int((x - r) / size) - 1), min(pixels, int((x + r) / size) + 2))
        iy = np.arange(max(0, int((y - r) / size) - 1), min(pixels, int((y + r) / size) + 2))
        cx, cy = np.meshgrid((ix + 0.5) * size, (iy + 0.5) * size)
        if not ((cx - x) ** 2 + (cy - y) ** 2 < r * r).any():
            hidden.append(i)
    return hidden
