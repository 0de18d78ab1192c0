"""Random tethered moulds: the paper's "Automated mould creation for training data".

A mould is a shapely ``Polygon`` (the footprint, tethers not subtracted) in l0 box
coordinates, plus ``tethers``: a float64 array (n, 3) of x, y, radius in l0.

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

import json
import math
import numbers
from dataclasses import dataclass, fields
from pathlib import Path

import numpy as np
import pandas as pd
import shapely
from shapely import affinity
from shapely.geometry import MultiPolygon, Polygon, mapping, shape

from condor.model.lattice import HALF

SYMMETRIES: tuple[str, ...] = (
    "random_rotation",
    "single_mirror",
    "double_mirror",
    "cyclic",
    "dihedral",
)
REMOVALS: tuple[str, ...] = ("none", "circular", "symmetric_bars", "rotated_bars", "random_bars")
NO_TETHERS = "no_tethers"  # removal label of the tether-free subset
USER = "user"  # symmetry and removal label of a mould the generator did not make
MIN_WIDTH_L0 = 1.0  # a user mould must be at least one cell (l0) wide everywhere it joins

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


class InvalidMouldError(ValueError):
    """A mould (or a mould file) that breaks the mould contract."""


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


@dataclass(kw_only=True)
class Mould:
    """One mould design. Lengths in l0, box coordinates [0, box]^2, y up.

    A *generated* mould (symmetry in SYMMETRIES) carries the generator's record (seed,
    order, removal, origin, unpruned tethers, rounding, outline kind) and obeys its exact
    area rule. Any other mould is a *user* mould (symmetry USER unless a caller labels it
    otherwise): it needs only box, polygon and tethers, and validate_mould checks its
    geometry alone (docs/user_moulds.md).
    """

    mould_id: int = 0
    seed: int | None = None  # dataset seed of a generated mould; None for a user mould
    symmetry: str = USER  # one of SYMMETRIES, or USER (any other label: a user mould)
    order: int = 1  # rotation order (cyclic/dihedral), copies (random_rotation), 2 or 4
    # (mirrors); 1 for a user mould (no symmetry assumed)
    removal: str = USER  # one of REMOVALS, "no_tethers" for the tether-free subset, or USER
    box: float  # box side, l0
    polygon: Polygon  # footprint, tethers not subtracted
    tethers: np.ndarray  # (n, 3): x, y, radius
    origin: tuple[float, float] | None = None  # symmetry origin (random rotation: centre of
    # area); None for a user mould
    unpruned_tethers: np.ndarray | None = None  # (m, 3) all duplicated tethers before any
    # pruning; None for a user mould (nothing was pruned)
    area_fraction: float | None = None  # the generator's target polygon area / box area;
    # None for a user mould (it has no area rule)
    convex_rounded: bool = False
    concave_rounded: bool = False
    outline: str | None = None  # initial shape: "convex_hull" or "simple_polygon"; None
    # for a user mould

    @property
    def n_tethers(self) -> int:
        return int(len(self.tethers))

    @property
    def is_generated(self) -> bool:
        """True for a mould of the generator (its symmetry is one of SYMMETRIES)."""
        return self.symmetry in SYMMETRIES

    def tether_disks(self, quad_segs: int = 16):
        """Tether disks as one (multi)polygon (a polygonal approximation), l0."""
        if self.n_tethers == 0:
            return Polygon()
        centres = shapely.points(self.tethers[:, :2])
        return shapely.union_all(shapely.buffer(centres, self.tethers[:, 2], quad_segs=quad_segs))

    def cell_region(self):
        """Where mobile cells may sit: the footprint minus the tether disks (l0)."""
        return self.polygon.difference(self.tether_disks()) if self.n_tethers else self.polygon

    def to_dict(self) -> dict:
        """JSON-safe dict (plain floats, lists, None); `from_dict` inverts it exactly."""
        return {
            "mould_id": int(self.mould_id),
            "seed": None if self.seed is None else int(self.seed),
            "symmetry": self.symmetry,
            "order": int(self.order),
            "removal": self.removal,
            "box": float(self.box),
            "polygon": _polygon_to_lists(self.polygon),
            "tethers": np.asarray(self.tethers, dtype=float).reshape(-1, 3).tolist(),
            "origin": None if self.origin is None else [float(self.origin[0]),
                                                        float(self.origin[1])],
            "unpruned_tethers": None if self.unpruned_tethers is None else
            np.asarray(self.unpruned_tethers, float).reshape(-1, 3).tolist(),
            "area_fraction": None if self.area_fraction is None else float(self.area_fraction),
            "convex_rounded": bool(self.convex_rounded),
            "concave_rounded": bool(self.concave_rounded),
            "outline": self.outline,
        }

    @classmethod
    def from_dict(cls, d: dict) -> "Mould":
        """Inverse of `to_dict`. Only box, polygon and tethers are required; every other
        field takes its default (a user mould) when absent or null."""
        if not isinstance(d, dict):
            raise InvalidMouldError(f"a mould is a JSON object, got {type(d).__name__}")
        known = {f.name for f in fields(cls)}
        unknown = set(d) - known
        if unknown:
            raise InvalidMouldError(f"unknown mould field(s) {sorted(unknown)}")
        missing = [name for name in _REQUIRED_FIELDS if d.get(name) is None]
        if missing:
            raise InvalidMouldError(f"missing mould field(s) {missing}")
        values = {k: v for k, v in d.items() if v is not None}
        values["polygon"] = _polygon_from_lists(d["polygon"])
        values["tethers"] = np.asarray(d["tethers"], dtype=np.float64).reshape(-1, 3)
        if "unpruned_tethers" in values:
            values["unpruned_tethers"] = np.asarray(values["unpruned_tethers"],
                                                    np.float64).reshape(-1, 3)
        if "origin" in values:
            values["origin"] = (float(d["origin"][0]), float(d["origin"][1]))
        return cls(**values)


_REQUIRED_FIELDS = ("box", "polygon", "tethers")


def _polygon_to_lists(polygon) -> dict:
    geo = mapping(polygon)
    return {"type": geo["type"],
            "coordinates": json.loads(json.dumps(geo["coordinates"]))}


def _polygon_from_lists(d: dict):
    return shape(d)


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


def _overlapping(tethers: np.ndarray, gap: float) -> np.ndarray:
    """Mask of tethers closer than `gap` to any other tether (every member of a pair)."""
    xy, radius = tethers[:, :2], tethers[:, 2]
    distance = np.hypot(*(xy[:, None, :] - xy[None, :, :]).transpose(2, 0, 1))
    clash = distance < radius[:, None] + radius[None, :] + gap
    np.fill_diagonal(clash, False)
    return clash.any(axis=1)


def _fits(polygon: Polygon, tethers: np.ndarray, clearance: float) -> np.ndarray:
    """Mask of tether disks inside `polygon` with at least `clearance` to its boundary."""
    if len(tethers) == 0:
        return np.zeros(0, dtype=bool)
    xy = tethers[:, :2]
    inside = shapely.contains_xy(polygon, xy[:, 0], xy[:, 1])
    wall = shapely.distance(polygon.boundary, shapely.points(xy))
    return inside & (wall >= tethers[:, 2] + clearance)


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
    keep &= _fits(polygon, unpruned, params.tether_clearance)
    tethers = unpruned[keep]
    tethers = tethers[~_overlapping(tethers, params.tether_clearance)]
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


def generate_mould(seed: int, mould_id: int, box: float = 62.5,
                   params: MouldParams = MouldParams(), area_fraction: float = 0.40,
                   max_extent: float = 0.90) -> Mould:
    """Generate mould `mould_id` of dataset `seed` in a square box of side `box` (l0).

    The mould is a pure function of its arguments (rng = default_rng([seed, mould_id])).
    Its area is exactly `area_fraction` of the box; geometry whose width or height would
    exceed `max_extent` of the box is redrawn. Raises RuntimeError if no geometry is
    accepted within `params.max_attempts` draws.
    """
    _check_ids(seed, mould_id)
    params.validate()
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


# --------------------------------------------------------------------------- validation


def validate_mould(mould: Mould, rtol: float = 1e-6) -> None:
    """Raise InvalidMouldError naming the first broken rule of the mould contract.

    Every mould: a single valid Polygon inside the box, finite numbers, tethers of shape
    (n, 3) with positive radii, fully inside the polygon and the box, no two overlapping.
    A generated mould (`is_generated`): area = area_fraction * box^2 (to `rtol`), exactly
    as the generator makes it. A user mould has no area rule (an area_fraction it states
    must match its polygon, to `rtol`) and is checked by geometry instead: every part is at
    least MIN_WIDTH_L0 (one cell) wide where it joins the rest, and the tether posts leave
    room for mobile cells, so that condor.model.simulate.simulate accepts it (docs/user_moulds.md).
    """
    name = f"mould {mould.mould_id}" if mould.is_generated or mould.mould_id else "the mould"
    polygon, box = mould.polygon, float(mould.box)
    if not (math.isfinite(box) and box > 0):
        raise InvalidMouldError(f"{name}: box = {box!r} must be positive and finite")
    if isinstance(polygon, MultiPolygon):
        raise InvalidMouldError(f"{name}: polygon is a MultiPolygon, not a single Polygon")
    if not isinstance(polygon, Polygon) or polygon.is_empty:
        raise InvalidMouldError(f"{name}: polygon is {polygon.geom_type}, not a Polygon")
    coords = shapely.get_coordinates(polygon)
    if not np.isfinite(coords).all():
        raise InvalidMouldError(f"{name}: polygon has NaN or infinite coordinates")
    if not polygon.is_valid:
        reason = shapely.is_valid_reason(polygon)
        raise InvalidMouldError(f"{name}: invalid polygon ({reason})")
    xmin, ymin, xmax, ymax = polygon.bounds
    slack = 1e-9 * box
    if xmin < -slack or ymin < -slack or xmax > box + slack or ymax > box + slack:
        raise InvalidMouldError(f"{name}: polygon bounds {polygon.bounds} leave the box "
                                f"[0, {box}]^2")
    fraction = polygon.area / box**2
    if mould.is_generated and mould.area_fraction is None:
        raise InvalidMouldError(f"{name}: a generated ({mould.symmetry}) mould needs its "
                                "area_fraction")
    if mould.area_fraction is not None and not math.isclose(fraction, mould.area_fraction,
                                                            rel_tol=rtol):
        hint = (f" (the generator's rule for a {mould.symmetry} mould; a mould of your own "
                "leaves out symmetry and area_fraction)" if mould.is_generated else
                " (area_fraction is the generator's target: leave it out)")
        raise InvalidMouldError(f"{name}: area fraction {fraction:.6f} is not "
                                f"{mould.area_fraction}{hint}")
    tethers = np.asarray(mould.tethers, dtype=float)
    if tethers.ndim != 2 or tethers.shape[1] != 3:
        raise InvalidMouldError(f"{name}: tethers have shape {tethers.shape}, expected (n, 3)")
    if not np.isfinite(tethers).all():
        raise InvalidMouldError(f"{name}: tethers hold NaN or infinite values")
    if len(tethers):
        _check_tethers(name, polygon, tethers, box, slack)
    if not mould.is_generated:
        _check_room(name, polygon, tethers)


def _check_tethers(name: str, polygon: Polygon, tethers: np.ndarray, box: float,
                   slack: float) -> None:
    x, y, radius = tethers.T
    if (radius <= 0).any():
        raise InvalidMouldError(f"{name}: tether radius {radius.min()} is not positive")
    outside_box = (x - radius < -slack) | (y - radius < -slack) | \
        (x + radius > box + slack) | (y + radius > box + slack)
    if outside_box.any():
        i = int(np.flatnonzero(outside_box)[0])
        raise InvalidMouldError(f"{name}: tether {i} at {tethers[i].tolist()} leaves the box")
    outside = ~_fits(polygon, tethers, -slack)
    if outside.any():
        i = int(np.flatnonzero(outside)[0])
        raise InvalidMouldError(f"{name}: tether {i} at {tethers[i].tolist()} is not fully "
                                "inside the mould")
    overlap = _overlapping(tethers, -slack)
    if overlap.any():
        i = int(np.flatnonzero(overlap)[0])
        raise InvalidMouldError(f"{name}: tether {i} at {tethers[i].tolist()} overlaps "
                                "another tether")


# Margin (l0) added to half a cell in _check_room: covers the polygonal approximation of
# buffers (below 0.01 l0 at quad_segs=64 for radii up to 30 l0) so that the check errs on
# the side of refusing.
_ROOM_MARGIN = 0.02


def _check_room(name: str, polygon: Polygon, tethers: np.ndarray) -> None:
    """A user mould's geometry checks beyond the contract, so that the lattice has cells.

    Lattice sites, projected on the plane, form a square grid of side HALF (two or more
    layers, i.e. depth >= HALF: every scene), so every disk of radius HALF / sqrt(2) = l0/2
    holds a site. A region that contains such a disk somewhere therefore holds a cell."""
    half_cell = MIN_WIDTH_L0 / 2 + _ROOM_MARGIN
    core = polygon.buffer(-half_cell, quad_segs=64)
    parts = list(getattr(core, "geoms", [core])) if not core.is_empty else []
    if not parts:
        raise InvalidMouldError(f"{name}: the polygon is narrower than a cell "
                                f"({MIN_WIDTH_L0:g} l0) everywhere")
    if len(parts) > 1:
        raise InvalidMouldError(f"{name}: a neck narrower than a cell ({MIN_WIDTH_L0:g} l0) "
                                f"splits the polygon into {len(parts)} parts")
    if len(tethers):
        # posts fix every site within max(radius, HALF) of a tether centre (condor.model.lattice)
        posts = shapely.buffer(shapely.points(tethers[:, :2]),
                               np.maximum(tethers[:, 2], HALF) + half_cell, quad_segs=64)
        if core.difference(shapely.union_all(posts)).is_empty:
            raise InvalidMouldError(f"{name}: the tethers leave no room for a mobile cell")


# --------------------------------------------------------------------------- rasters, files


def input_channels(mould: Mould, pixels: int, supersample: int = 1) -> np.ndarray:
    """(2, pixels, pixels) indexed [channel, y, x]: channel 0 "mould" (in the polygon and in
    no tether disk), channel 1 "tether" (in a tether disk, exact circles). Pixel centres at
    (i + 0.5) * box / pixels.

    supersample 1: uint8 0/1, each pixel judged at its centre (the dataset's `inputs`).
    supersample k > 1: float32 coverage, the fraction of a k x k grid of sub-pixel centres in
    each region, so that an outline or a post is placed to 1/k of a pixel (a post of radius
    1.3 px is a few whole pixels at k = 1, whatever its true size)."""
    for name, value in (("pixels", pixels), ("supersample", supersample)):
        if isinstance(value, bool) or not isinstance(value, numbers.Integral) or value < 1:
            raise ValueError(f"{name} = {value!r} must be a positive integer")
    k = int(supersample)
    centres = (np.arange(pixels * k) + 0.5) * (mould.box / (pixels * k))
    x, y = np.meshgrid(centres, centres)  # [y, x]
    tether = np.zeros(x.shape, dtype=bool)
    for cx, cy, r in np.asarray(mould.tethers).reshape(-1, 3):
        tether |= (x - cx) ** 2 + (y - cy) ** 2 < r * r
    inside = shapely.contains_xy(mould.polygon, x, y)
    channels = np.stack([inside & ~tether, tether])
    if k == 1:
        return channels.astype(np.uint8)
    return channels.reshape(2, pixels, k, pixels, k).mean(axis=(2, 4), dtype=np.float64).astype(np.float32)


def save_json(mould: Mould, path) -> None:
    """Write `mould` as JSON (exact float round trip)."""
    Path(path).write_text(json.dumps(mould.to_dict()))


def load_json(path) -> Mould:
    """Read and validate a mould file; errors (InvalidMouldError) name the file."""
    text = Path(path).read_text()  # OSError (missing, unreadable) names the file itself
    try:
        mould = Mould.from_dict(json.loads(text))
        validate_mould(mould)
    except Exception as error:  # any malformed content: JSON, keys, types, geometry
        raise InvalidMouldError(f"{path} is not a valid mould file: {type(error).__name__}: {error}") from error
    return mould


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
