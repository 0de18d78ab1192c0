"""The paper's random tethered moulds: its "Automated mould creation for training data".

`generate_mould(seed, mould_id, scene)` makes mould `mould_id` of dataset `seed`, a pure
function of its arguments: a `condor.moulds.mould.Mould` labelled with its regime (one of
SYMMETRIES) and the generator's record. The scene gives the box, the area fraction and the
largest extent (condor.model.scenes.Scene, their one home).

Pipeline for one mould (docs/moulds.md gives every choice the paper leaves open):

1. Categorical choices first, from ``default_rng([seed, mould_id])``: no-tether flag,
   regime, order, removal type, rounding flags, outline kind and bar layout. Rejection
   below only redraws continuous geometry, so these frequencies are exactly the table's.
2. Initial shape on the unit canvas: 3-6 random points, convex hull or star-shaped simple
   polygon, area >= 0.5; three tethers fully inside; a random symmetry origin inside.
3. Duplication by the regime's isometries and union of the copies.
4. Scaling to the unit box (area fraction), optional concave (closing) and convex
   (opening) rounding, exact rescaling, centring, extent and neck checks.
5. Tether pruning: exclusion zone (circle or bars), wall clearance, overlaps.
6. Scaling to the box side in l0.
"""

from __future__ import annotations

import math
import numbers
from dataclasses import dataclass

import numpy as np
import pandas as pd
import shapely
from shapely import affinity
from shapely.geometry import Polygon

from condor.model.scenes import Scene
from condor.moulds.mould import SYMMETRIES, Mould, overlapping_tethers, tethers_fit

REMOVALS: tuple[str, ...] = ("none", "circular", "symmetric_bars", "rotated_bars", "random_bars")
NO_TETHERS = "no_tethers"  # removal label of the tether-free subset

# The paper's Table "Probabilities of tether removal selection", raw; n/a -> 0.0.
REMOVAL_FREQUENCIES: dict[str, dict[str, float]] = {
    "random_rotation": {"none": 0.05, "circular": 0.5, "symmetric_bars": 0.0,
                        "rotated_bars": 0.0, "random_bars": 0.45},
    "single_mirror": {"none": 0.05, "circular": 0.45, "symmetric_bars": 0.45,
                      "rotated_bars": 0.05, "random_bars": 0.0},
    "double_mirror": {"none": 0.05, "circular": 0.45, "symmetric_bars": 0.45,
                      "rotated_bars": 0.05, "random_bars": 0.0},
    "cyclic": {"none": 0.05, "circular": 0.45, "symmetric_bars": 0.0,
               "rotated_bars": 0.45, "random_bars": 0.05},
    "dihedral": {"none": 0.05, "circular": 0.45, "symmetric_bars": 0.3,
                 "rotated_bars": 0.15, "random_bars": 0.05},
}
MIRROR_AXES = ("vertical", "horizontal")  # single mirror: line x = ox or y = oy
DOUBLE_BARS = ("horizontal", "vertical", "both")  # double mirror bar sub-choice
OUTLINES = ("convex_hull", "simple_polygon")


def removal_probabilities(symmetry: str) -> np.ndarray:
    """Removal-type probabilities for `symmetry`, in REMOVALS order, rows renormalised to 1."""
    if symmetry not in REMOVAL_FREQUENCIES:
        raise ValueError(f"unknown symmetry {symmetry!r}; choose one of {SYMMETRIES}")
    raw = np.array([REMOVAL_FREQUENCIES[symmetry][r] for r in REMOVALS], dtype=float)
    return raw / raw.sum()


@dataclass(frozen=True)
class MouldParams:
    """Knobs of the generator. Canvas lengths are in unit-canvas widths (the initial shape
    lives in [0, 1]^2); "box" lengths are fractions of the box side."""

    # The paper: 100 tether-free moulds in 6,500 (0.01538...), as the dataset contract rounds it.
    no_tether_fraction: float = 0.0154
    min_tethers: int = 4  # tethered moulds keep at least this many
    convex_rounding: float = 0.25  # probability of rounding convex corners
    concave_rounding: float = 0.75  # probability of rounding concave corners
    hull_probability: float = 0.5  # outline is the convex hull (else star-shaped polygon)
    min_points: int = 3
    max_points: int = 6
    min_initial_area: float = 0.5  # of the canvas
    initial_tethers: int = 3
    tether_radius_min: float = 0.02  # canvas widths
    tether_radius_max: float = 0.065
    order_min: int = 2  # cyclic / dihedral rotation order
    order_max: int = 6
    copies_min: int = 2  # random rotation: copies in all, the original included
    copies_max: int = 4
    circle_min: float = 0.2  # exclusion circle diameter / max mould width
    circle_max: float = 0.8
    bar_width_min: float = 0.1  # exclusion bar width / max mould width
    bar_width_max: float = 0.4
    offset_min: float = 0.1  # rotated bars: offset / angular period of the bar pattern
    offset_max: float = 0.4
    rounding_radius_min: float = 0.02  # box sides
    rounding_radius_max: float = 0.05
    tether_clearance: float = 0.005  # box sides, tether to wall and tether to tether
    min_neck: float = 0.03  # box sides: narrowest part allowed to join the mould
    quad_segs: int = 8  # buffer arc resolution (segments per quarter circle)
    max_attempts: int = 2000  # geometry redraws per mould

    @property
    def max_copies(self) -> int:
        """The most copies of the initial shape a mould is the union of: random rotation
        `copies_max`, mirrors 2 or 4, cyclic `order_max`, dihedral 2 x `order_max`."""
        return max(self.copies_max, 4, 2 * self.order_max)

    @property
    def max_tethers(self) -> int:
        """The most tethers a generated mould can keep: every copy of the initial tethers
        (pruning only removes); 36 for the defaults (3 tethers x 12 dihedral copies)."""
        return self.initial_tethers * self.max_copies

    def validate(self) -> None:
        """Raise ValueError naming the first bad field."""
        probs = ("no_tether_fraction", "convex_rounding", "concave_rounding", "hull_probability")
        for name in probs:
            value = getattr(self, name)
            if not 0.0 <= value <= 1.0:
                raise ValueError(f"MouldParams.{name} = {value!r} must be in [0, 1]")
        positive = ("min_initial_area", "tether_radius_min", "circle_min", "bar_width_min",
                    "rounding_radius_min", "quad_segs", "max_attempts", "initial_tethers")
        for name in positive:
            value = getattr(self, name)
            if not value > 0:
                raise ValueError(f"MouldParams.{name} = {value!r} must be positive")
        for name in ("tether_clearance", "min_neck", "min_tethers", "offset_min"):
            if not getattr(self, name) >= 0:
                raise ValueError(f"MouldParams.{name} = {getattr(self, name)!r} must be >= 0")
        pairs = (("min_points", "max_points"), ("tether_radius_min", "tether_radius_max"),
                 ("order_min", "order_max"), ("copies_min", "copies_max"),
                 ("circle_min", "circle_max"), ("bar_width_min", "bar_width_max"),
                 ("offset_min", "offset_max"), ("rounding_radius_min", "rounding_radius_max"))
        for low, high in pairs:
            if getattr(self, high) < getattr(self, low):
                raise ValueError(f"MouldParams.{high} = {getattr(self, high)!r} is below "
                                 f"{low} = {getattr(self, low)!r}")
        ints = ("min_points", "max_points", "order_min", "order_max", "copies_min",
                "copies_max", "min_tethers", "initial_tethers", "quad_segs", "max_attempts")
        for name in ints:
            if not isinstance(getattr(self, name), numbers.Integral):
                raise ValueError(f"MouldParams.{name} = {getattr(self, name)!r} must be an int")
        if self.min_points < 3:
            raise ValueError(f"MouldParams.min_points = {self.min_points} must be >= 3")
        if self.order_min < 2:
            raise ValueError(f"MouldParams.order_min = {self.order_min} must be >= 2")
        if self.copies_min < 1:
            raise ValueError(f"MouldParams.copies_min = {self.copies_min} must be >= 1")
        if self.min_initial_area >= 1.0:
            raise ValueError(f"MouldParams.min_initial_area = {self.min_initial_area} "
                             "must be below 1 (the canvas area)")
        if self.tether_radius_max >= 0.25:
            raise ValueError(f"MouldParams.tether_radius_max = {self.tether_radius_max} "
                             "is too large for the unit canvas")
        if self.offset_max > 0.5:
            raise ValueError(f"MouldParams.offset_max = {self.offset_max} must be <= 0.5")


# --------------------------------------------------------------------------- choices


@dataclass(frozen=True)
class _Choices:
    no_tethers: bool
    symmetry: str
    order: int
    removal: str
    convex: bool
    concave: bool
    outline: str
    mirror_axis: str  # single mirror only
    double_bars: str  # double mirror bars only


def _draws_no_tethers(rng: np.random.Generator, params: MouldParams) -> bool:
    """The generator's first draw from a mould's rng: is it tether-free?"""
    return bool(rng.random() < params.no_tether_fraction)


def is_tether_free(seed: int, mould_id: int, params: MouldParams = MouldParams()) -> bool:
    """Whether mould `mould_id` of dataset `seed` has no tethers, without drawing its
    geometry (the first draw of `generate_mould`): the config sizes a tether-free test mould's
    replicas from it before any mould exists."""
    _check_ids(seed, mould_id)
    return _draws_no_tethers(np.random.default_rng([int(seed), int(mould_id)]), params)


def _draw_choices(rng: np.random.Generator, params: MouldParams) -> _Choices:
    """Every categorical choice, drawn once per mould in a fixed order (fixed rng use)."""
    no_tethers = _draws_no_tethers(rng, params)
    symmetry = SYMMETRIES[int(rng.integers(len(SYMMETRIES)))]
    rotation_order = int(rng.integers(params.order_min, params.order_max + 1))
    copies = int(rng.integers(params.copies_min, params.copies_max + 1))
    removal = REMOVALS[int(rng.choice(len(REMOVALS), p=removal_probabilities(symmetry)))]
    convex = bool(rng.random() < params.convex_rounding)
    concave = bool(rng.random() < params.concave_rounding)
    outline = OUTLINES[0] if rng.random() < params.hull_probability else OUTLINES[1]
    mirror_axis = MIRROR_AXES[int(rng.integers(2))]
    double_bars = DOUBLE_BARS[int(rng.integers(3))]
    order = {"random_rotation": copies, "single_mirror": 2, "double_mirror": 4}.get(
        symmetry, rotation_order)
    return _Choices(no_tethers, symmetry, order, NO_TETHERS if no_tethers else removal,
                    convex, concave, outline, mirror_axis, double_bars)


# --------------------------------------------------------------------------- initial shape


def _star_areas(points: np.ndarray) -> np.ndarray:
    """Areas of the polygons through `points` (b, n, 2) sorted by angle about their mean."""
    centre = points.mean(axis=1, keepdims=True)
    angle = np.arctan2(points[..., 1] - centre[..., 1], points[..., 0] - centre[..., 0])
    ordered = np.take_along_axis(points, np.argsort(angle, axis=1)[..., None], axis=1)
    x, y = ordered[..., 0], ordered[..., 1]
    return 0.5 * np.abs(np.sum(x * np.roll(y, -1, axis=1) - y * np.roll(x, -1, axis=1), axis=1))


def _outline_polygon(points: np.ndarray, outline: str) -> Polygon:
    if outline == "convex_hull":
        return shapely.MultiPoint(points).convex_hull
    centre = points.mean(axis=0)
    order = np.argsort(np.arctan2(points[:, 1] - centre[1], points[:, 0] - centre[0]))
    return Polygon(points[order])


def _draw_outline(rng, outline: str, params: MouldParams, batch: int = 128,
                  max_batches: int = 400) -> Polygon:
    """Initial shape in the unit canvas: 3-6 uniform points (count redrawn with every
    candidate), convex hull or star-shaped polygon, area >= min_initial_area. Candidates
    are drawn in batches (vectorised); the first accepted one in batch order wins."""
    n_max = params.max_points
    for _ in range(max_batches):
        counts = rng.integers(params.min_points, n_max + 1, size=batch)
        points = rng.random((batch, n_max, 2))
        areas = np.zeros(batch)
        for n in np.unique(counts):
            rows = np.flatnonzero(counts == n)
            subset = points[rows, :n]
            if outline == "convex_hull":
                areas[rows] = shapely.area(shapely.convex_hull(shapely.multipoints(subset)))
            else:
                areas[rows] = _star_areas(subset)
        accepted = np.flatnonzero(areas >= params.min_initial_area)
        for row in accepted:
            polygon = _outline_polygon(points[row, : counts[row]], outline)
            if polygon.is_valid and polygon.area >= params.min_initial_area:
                return polygon
    raise RuntimeError(f"no initial outline with area >= {params.min_initial_area} "
                       f"in {batch * max_batches} candidates")


def _random_points_inside(rng, polygon: Polygon, count: int, batch: int = 64) -> np.ndarray:
    """`count` uniform points inside `polygon` (rejection from its bounding box)."""
    xmin, ymin, xmax, ymax = polygon.bounds
    found: list[np.ndarray] = []
    total = 0
    for _ in range(1000):
        xy = rng.random((batch, 2)) * [xmax - xmin, ymax - ymin] + [xmin, ymin]
        inside = xy[shapely.contains_xy(polygon, xy[:, 0], xy[:, 1])]
        found.append(inside)
        total += len(inside)
        if total >= count:
            return np.concatenate(found)[:count]
    raise RuntimeError("could not sample points inside the polygon")


def _place_tethers(rng, polygon: Polygon, params: MouldParams) -> np.ndarray | None:
    """Initial tethers: uniform centres, uniform radii, disks fully inside `polygon` and
    not overlapping each other. None if the shape has no room (the attempt is redrawn)."""
    boundary = polygon.exterior
    tethers: list[tuple[float, float, float]] = []
    for _ in range(200):
        xy = _random_points_inside(rng, polygon, 1)[0]
        radius = rng.uniform(params.tether_radius_min, params.tether_radius_max)
        if boundary.distance(shapely.Point(xy)) < radius:
            continue
        if any(math.hypot(xy[0] - x, xy[1] - y) < radius + r for x, y, r in tethers):
            continue
        tethers.append((xy[0], xy[1], radius))
        if len(tethers) == params.initial_tethers:
            return np.array(tethers)
    return None


# --------------------------------------------------------------------------- isometries


def _rotation(theta: float, about: np.ndarray) -> np.ndarray:
    """3x3 homogeneous matrix: rotation by `theta` (rad) about the point `about`."""
    c, s = math.cos(theta), math.sin(theta)
    ox, oy = about
    return np.array([[c, -s, ox - c * ox + s * oy], [s, c, oy - s * ox - c * oy], [0, 0, 1.0]])


def _reflection(axis: str, about: np.ndarray) -> np.ndarray:
    """Reflection across the vertical (x = ox) or horizontal (y = oy) line through `about`."""
    ox, oy = about
    if axis == "vertical":
        return np.array([[-1.0, 0, 2 * ox], [0, 1.0, 0], [0, 0, 1.0]])
    return np.array([[1.0, 0, 0], [0, -1.0, 2 * oy], [0, 0, 1.0]])


def _copy_maps(rng, choices: _Choices, polygon: Polygon, origin: np.ndarray) -> list[np.ndarray]:
    """Isometries whose images of the initial shape make up the mould (identity first)."""
    identity = np.eye(3)
    k = choices.order
    if choices.symmetry == "random_rotation":
        centres = _random_points_inside(rng, polygon, k - 1)
        angles = rng.uniform(0.0, 2 * math.pi, size=k - 1)
        return [identity] + [_rotation(a, c) for a, c in zip(angles, centres)]
    if choices.symmetry == "single_mirror":
        return [identity, _reflection(choices.mirror_axis, origin)]
    if choices.symmetry == "double_mirror":
        mx, my = _reflection("vertical", origin), _reflection("horizontal", origin)
        return [identity, mx, my, mx @ my]
    rotations = [_rotation(2 * math.pi * j / k, origin) for j in range(k)]
    if choices.symmetry == "cyclic":
        return rotations
    mirror = _reflection("vertical", origin)  # dihedral: reflect first, then rotate
    return [r @ m for r in rotations for m in (identity, mirror)]


def _apply_geometry(matrix: np.ndarray, geometry):
    a, b, xoff = matrix[0]
    d, e, yoff = matrix[1]
    return affinity.affine_transform(geometry, [a, b, d, e, xoff, yoff])


def _apply_points(matrix: np.ndarray, xy: np.ndarray) -> np.ndarray:
    return xy @ matrix[:2, :2].T + matrix[:2, 2]


# --------------------------------------------------------------------------- exclusion


def _bar_pattern(choices: _Choices, origin, copy_centroids: np.ndarray):
    """Symmetric bar layout: ("line" | "ray", axis angles in rad, angular period)."""
    k = choices.order
    if choices.symmetry == "single_mirror":
        axis = math.pi / 2 if choices.mirror_axis == "vertical" else 0.0
        return "line", np.array([axis]), math.pi
    if choices.symmetry == "double_mirror":
        angles = {"horizontal": [0.0], "vertical": [math.pi / 2], "both": [0.0, math.pi / 2]}
        chosen = np.array(angles[choices.double_bars])
        return "line", chosen, math.pi / len(chosen)
    if choices.symmetry == "dihedral":  # the k mirror axes
        return "line", math.pi / 2 + math.pi * np.arange(k) / k, math.pi / k
    # cyclic: rays from the origin towards each copy's centroid; random rotation: the same
    # (only its random bars are in the paper's table)
    vectors = np.asarray(copy_centroids) - np.asarray(origin)
    angles = np.arctan2(vectors[:, 1], vectors[:, 0])
    return "ray", angles, 2 * math.pi / k


def _distance_to_bars(xy: np.ndarray, centre, angles: np.ndarray, kind: str) -> np.ndarray:
    """Distance of each point to the nearest bar axis (lines through, or rays from, centre)."""
    rel = xy[:, None, :] - np.asarray(centre)[None, None, :]
    ux, uy = np.cos(angles)[None, :], np.sin(angles)[None, :]
    along = rel[..., 0] * ux + rel[..., 1] * uy
    if kind == "ray":
        along = np.maximum(along, 0.0)
    dx, dy = rel[..., 0] - along * ux, rel[..., 1] - along * uy
    return np.hypot(dx, dy).min(axis=1)


def _excluded(rng, removal: str, tethers: np.ndarray, centre, width: float, params,
              pattern) -> np.ndarray:
    """Mask of tethers touching the exclusion zone (all lengths in the same units)."""
    xy, radius = tethers[:, :2], tethers[:, 2]
    if removal == "none":
        return np.zeros(len(tethers), dtype=bool)
    if removal == "circular":
        diameter = rng.uniform(params.circle_min, params.circle_max) * width
        return np.hypot(*(xy - np.asarray(centre)).T) <= radius + diameter / 2
    kind, angles, period = pattern
    half_width = 0.5 * rng.uniform(params.bar_width_min, params.bar_width_max) * width
    if removal == "rotated_bars":
        offset = period * rng.uniform(params.offset_min, params.offset_max)
        angles = angles + offset * rng.choice([-1.0, 1.0])
    elif removal == "random_bars":
        angles = rng.uniform(0.0, 2 * math.pi, size=len(angles))
    return _distance_to_bars(xy, centre, angles, kind) <= radius + half_width


# --------------------------------------------------------------------------- generation


def _check_ids(seed, mould_id) -> None:
    for name, value in (("seed", seed), ("mould_id", mould_id)):
        if isinstance(value, bool) or not isinstance(value, numbers.Integral):
            raise ValueError(f"{name} = {value!r} must be a non-negative integer")
        if value < 0:
            raise ValueError(f"{name} = {value!r} must be a non-negative integer")


def _fit_to_unit_box(polygon: Polygon, area_fraction: float):
    """Similarity (3x3) that scales `polygon` to `area_fraction` of the unit box and centres
    its bounding box at (0.5, 0.5)."""
    scale = math.sqrt(area_fraction / polygon.area)
    xmin, ymin, xmax, ymax = polygon.bounds
    cx, cy = 0.5 * (xmin + xmax), 0.5 * (ymin + ymax)
    return np.array([[scale, 0, 0.5 - scale * cx], [0, scale, 0.5 - scale * cy], [0, 0, 1.0]])


def _extent(polygon) -> float:
    xmin, ymin, xmax, ymax = polygon.bounds
    return max(xmax - xmin, ymax - ymin)


def _round(polygon, choices: _Choices, rng, params: MouldParams):
    """Concave rounding = closing, then convex rounding = opening, radii in box sides."""
    segs = params.quad_segs
    radius = rng.uniform(params.rounding_radius_min, params.rounding_radius_max, size=2)
    if choices.concave:
        polygon = polygon.buffer(radius[0], quad_segs=segs).buffer(-radius[0], quad_segs=segs)
    if choices.convex:
        polygon = polygon.buffer(-radius[1], quad_segs=segs).buffer(radius[1], quad_segs=segs)
    return polygon


def _single_valid_polygon(geometry) -> bool:
    return (isinstance(geometry, Polygon) and not geometry.is_empty and geometry.is_valid
            and geometry.area > 0)


def _attempt_footprint(rng, choices: _Choices, params: MouldParams, area_fraction: float,
                       max_extent: float):
    """Initial shape, copies, rounding and scaling to the unit box (box side 1).

    Returns (initial shape, symmetry origin in the canvas, copy maps, canvas-to-unit-box
    similarity, footprint in the unit box), or None if rejected."""
    initial = _draw_outline(rng, choices.outline, params)
    origin0 = _random_points_inside(rng, initial, 1)[0]
    maps = _copy_maps(rng, choices, initial, origin0)
    union = shapely.union_all([_apply_geometry(m, initial) for m in maps])
    if not _single_valid_polygon(union):
        return None
    to_unit = _fit_to_unit_box(union, area_fraction)
    # Early reject: rounding changes the area by a few percent at most.
    if to_unit[0, 0] * _extent(union) > 1.15 * max_extent:
        return None
    polygon = _round(_apply_geometry(to_unit, union), choices, rng, params)
    if not _single_valid_polygon(polygon):
        return None
    exact = _fit_to_unit_box(polygon, area_fraction)
    polygon = _apply_geometry(exact, polygon)
    if not _single_valid_polygon(polygon) or _extent(polygon) > max_extent:
        return None
    if params.min_neck > 0 and not _single_valid_polygon(polygon.buffer(-params.min_neck / 2)):
        return None
    return initial, origin0, maps, exact @ to_unit, polygon


def _attempt_tethers(rng, choices: _Choices, params: MouldParams, footprint):
    """Initial tethers, their copies and pruning, in the unit box.

    Returns (kept tethers, all copies before pruning, exclusion centre) or None if fewer
    than `min_tethers` survive."""
    initial, origin0, maps, similarity, polygon = footprint
    tethers0 = _place_tethers(rng, initial, params)
    if tethers0 is None:
        return None
    scale = similarity[0, 0]
    unpruned = np.concatenate([
        np.column_stack([_apply_points(similarity @ m, tethers0[:, :2]), tethers0[:, 2] * scale])
        for m in maps
    ])
    centre = _exclusion_centre(choices, polygon, _apply_points(similarity, origin0[None])[0])
    centroid0 = np.array([[initial.centroid.x, initial.centroid.y]])
    copy_centroids = np.concatenate([_apply_points(similarity @ m, centroid0) for m in maps])
    pattern = _bar_pattern(choices, centre, copy_centroids)
    keep = ~_excluded(rng, choices.removal, unpruned, centre, _extent(polygon), params, pattern)
    keep &= tethers_fit(polygon, unpruned, params.tether_clearance)
    tethers = unpruned[keep]
    tethers = tethers[~overlapping_tethers(tethers, params.tether_clearance)]
    if len(tethers) < params.min_tethers:
        return None
    return tethers, unpruned


def _exclusion_centre(choices: _Choices, polygon: Polygon, origin: np.ndarray) -> np.ndarray:
    """The symmetry origin; for random rotation (no symmetry) the footprint's centre of area."""
    if choices.symmetry == "random_rotation":
        return np.array(polygon.centroid.coords[0])
    return origin


def _attempt(rng, choices: _Choices, params: MouldParams, area_fraction: float,
             max_extent: float):
    """One draw of all continuous geometry in the unit box: (footprint, tethers, unpruned
    tethers, origin), or None if rejected. Tether-free moulds draw no tethers."""
    footprint = _attempt_footprint(rng, choices, params, area_fraction, max_extent)
    if footprint is None:
        return None
    initial, origin0, maps, similarity, polygon = footprint
    origin = _exclusion_centre(choices, polygon, _apply_points(similarity, origin0[None])[0])
    if choices.no_tethers:
        return polygon, np.zeros((0, 3)), np.zeros((0, 3)), origin
    tethers = _attempt_tethers(rng, choices, params, footprint)
    if tethers is None:
        return None
    return polygon, *tethers, origin


def generate_mould(seed: int, mould_id: int, scene: Scene,
                   params: MouldParams = MouldParams()) -> Mould:
    """Generate mould `mould_id` of dataset `seed` in `scene`'s square box (side scene.box, l0).

    The mould is a pure function of its arguments (rng = default_rng([seed, mould_id])).
    Its area is exactly scene.area_fraction of the box; geometry whose width or height would
    exceed scene.max_extent of the box is redrawn. Raises RuntimeError if no geometry is
    accepted within `params.max_attempts` draws.
    """
    _check_ids(seed, mould_id)
    params.validate()
    box, area_fraction, max_extent = scene.box, scene.area_fraction, scene.max_extent
    if not (isinstance(box, numbers.Real) and math.isfinite(box) and box > 0):
        raise ValueError(f"box = {box!r} must be a positive finite length (l0)")
    if not 0 < area_fraction < 1:
        raise ValueError(f"area_fraction = {area_fraction!r} must be in (0, 1)")
    if not 0 < max_extent <= 1:
        raise ValueError(f"max_extent = {max_extent!r} must be in (0, 1]")
    rng = np.random.default_rng([int(seed), int(mould_id)])
    choices = _draw_choices(rng, params)
    for _ in range(params.max_attempts):
        result = _attempt(rng, choices, params, area_fraction, max_extent)
        if result is not None:
            break
    else:
        raise RuntimeError(
            f"mould {mould_id} (seed {seed}): no {choices.symmetry}/{choices.removal} geometry "
            f"accepted in {params.max_attempts} attempts")
    polygon, tethers, unpruned, origin = result
    to_box = np.diag([float(box), float(box), 1.0])
    return Mould(
        mould_id=int(mould_id), seed=int(seed), symmetry=choices.symmetry, order=choices.order,
        removal=choices.removal, box=float(box), polygon=_apply_geometry(to_box, polygon),
        tethers=tethers * box, origin=(float(origin[0] * box), float(origin[1] * box)),
        unpruned_tethers=unpruned * box, area_fraction=float(area_fraction),
        convex_rounded=choices.convex, concave_rounded=choices.concave,
        outline=choices.outline)


# --------------------------------------------------------------------------- tables


def regime_table(moulds) -> pd.DataFrame:
    """Observed regime shares and removal frequencies (among tethered moulds) per regime,
    next to the paper's table (rows renormalised). One row per regime."""
    moulds = list(moulds)
    rows = []
    for symmetry in SYMMETRIES:
        chosen = [m for m in moulds if m.symmetry == symmetry]
        tethered = [m.removal for m in chosen if m.removal != NO_TETHERS]
        row = {"regime": symmetry, "n": len(chosen),
               "share": len(chosen) / len(moulds) if moulds else float("nan"),
               "paper_share": 1 / len(SYMMETRIES),
               "no_tethers": len(chosen) - len(tethered)}
        paper = removal_probabilities(symmetry)
        for removal, expected in zip(REMOVALS, paper):
            observed = tethered.count(removal) / len(tethered) if tethered else float("nan")
            row[removal] = observed
            row[f"{removal}_paper"] = float(expected)
        rows.append(row)
    return pd.DataFrame(rows).set_index("regime")
