"""The surrogate's training domain: how far a mould lies from the generated moulds a
surrogate was trained on (`training_domain_check`: warnings, or a refusal beyond
AREA_REFUSE). Simulation needs no such check: the model holds for any mould."""

from __future__ import annotations

from dataclasses import dataclass

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
EXTENT_WARN = 0.01  # relative excess of the width or height over the training moulds' largest
# that warns: --fit puts a long mould at the window's scene.max_extent, a hair past the largest
# training mould's (0.8997 of the box against 0.9 for the default run's)
TRAINING_MIN_TETHERS = 4
TRAINING_TETHER_RADIUS = (0.007, 0.06)  # box sides


class OutsideTrainingDomainError(InvalidMouldError):
    """A mould too far from the generated moulds for a surrogate's prediction to mean much."""


@dataclass(frozen=True)
class TrainingRanges:
    """The ranges of a surrogate's training moulds, in box sides: area (a fraction of the box),
    the larger side, the posts (counts) and their radii; `source` names whose they are."""

    area: tuple[float, float]
    extent: float
    posts: tuple[int, int]
    post_radius: tuple[float, float]
    source: str


def generated_ranges(scene: Scene) -> TrainingRanges:
    """The paper generator's moulds: area exactly scene.area_fraction, at most scene.max_extent
    wide, 0 or at least TRAINING_MIN_TETHERS tethers of radii TRAINING_TETHER_RADIUS."""
    return TrainingRanges((scene.area_fraction, scene.area_fraction), scene.max_extent,
                          (TRAINING_MIN_TETHERS, 10**6), TRAINING_TETHER_RADIUS,
                          "the generated moulds")


def training_domain_check(mould: Mould, scene: Scene,
                          ranges: TrainingRanges | None = None) -> list[str]:
    """Warnings for predicting `mould` with a surrogate trained on moulds of `ranges` in
    `scene` (None: the paper generator's, `generated_ranges`).

    A mould whose area lies outside the training areas by more than AREA_WARN (relative) gets
    a warning; by more than AREA_REFUSE, OutsideTrainingDomainError (simulate it instead). A
    larger extent, a tether count or radii outside the training ranges, and tethers too small
    to mark any pixel of the input grid, get warnings. Simulation needs no such check: the
    model holds for any mould. The generated moulds' count rule is "0 or at least
    TRAINING_MIN_TETHERS"; a checkpoint's own ranges count its training moulds' posts.
    """
    box = float(scene.box)
    if not same_length(mould.box, box):
        raise OutsideTrainingDomainError(
            f"the mould is placed in a {mould.box:g} l0 box, the {scene.name!r} scene (and a "
            f"surrogate trained on it) has {box:g} l0")
    generated = ranges is None
    ranges = generated_ranges(scene) if generated else ranges
    warnings = []
    fraction = mould.polygon.area / box**2
    low, high = ranges.area
    nearest = min(max(fraction, low), high)
    deviation = fraction / nearest - 1
    training = (f"exactly {low:g}" if low == high else f"{low:.3g}-{high:.3g}")
    area = (f"its area is {fraction:.3g} of the box, {ranges.source}' is {training} "
            f"({deviation:+.0%})")
    if abs(deviation) > AREA_REFUSE:
        raise OutsideTrainingDomainError(
            f"{area}, beyond the +-{AREA_REFUSE:.0%} a prediction is allowed: simulate it, or "
            "scale it with --fit")
    if abs(deviation) > (AREA_WARN if generated else 1e-9):
        warnings.append(f"{area}: the prediction extrapolates" +
                        (f" (more than +-{AREA_WARN:.0%})" if generated else ""))
    xmin, ymin, xmax, ymax = mould.polygon.bounds
    extent = max(xmax - xmin, ymax - ymin) / box
    if extent > ranges.extent * (1 + EXTENT_WARN):
        warnings.append(f"its width or height is {extent:.3g} of the box, {ranges.source}' "
                        f"is at most {ranges.extent:.3g}")
    tethers = np.asarray(mould.tethers, dtype=float).reshape(-1, 3)
    if generated and 0 < len(tethers) < TRAINING_MIN_TETHERS:
        warnings.append(f"it has {len(tethers)} tethers, the training moulds have none or at "
                        f"least {TRAINING_MIN_TETHERS}")
    elif not generated and not ranges.posts[0] <= len(tethers) <= ranges.posts[1]:
        warnings.append(f"it has {len(tethers)} tethers, {ranges.source} have "
                        f"{ranges.posts[0]}-{ranges.posts[1]}")
    low, high = (r * box for r in ranges.post_radius)
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
