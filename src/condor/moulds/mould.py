"""The mould contract: what every source of moulds (the paper's generator, a user's drawing)
makes and every consumer reads.

A mould is a shapely ``Polygon`` (the footprint, tethers not subtracted) in l0 box
coordinates, plus ``tethers``: a float64 array (n, 3) of x, y, radius in l0 (`Mould`).
`check_mould` holds a mould to the contract, `input_channels` rasterises it into the
surrogate's two masks, `save_json` / `load_json` write and read it exactly. A source imports
from this module only (docs/architecture.md): `condor.moulds.paper` (the paper's generator),
`condor.moulds.read` (a user's JSON, SVG or DXF drawing).
"""

from __future__ import annotations

import json
import math
import numbers
from dataclasses import dataclass, fields
from pathlib import Path

import numpy as np
import shapely
from shapely.geometry import MultiPolygon, Polygon, mapping, shape

from condor.files import write_text
from condor.model.lattice import HALF

# The regimes of the paper's generator (condor.moulds.paper): a mould labelled with one of them
# is a *generated* mould and obeys the generator's exact area rule (check_mould).
SYMMETRIES: tuple[str, ...] = (
    "random_rotation",
    "single_mirror",
    "double_mirror",
    "cyclic",
    "dihedral",
)
USER = "user"  # symmetry, removal and family label of a mould no source of condor made
PAPER = "paper"  # the family of the paper's generated moulds (condor.moulds.paper)
MIN_WIDTH_L0 = 1.0  # a user mould must be at least one cell (l0) wide everywhere it joins


class InvalidMouldError(ValueError):
    """A mould (or a mould file) that breaks the mould contract."""


class DrawingError(InvalidMouldError):
    """A mould file that cannot be read as a mould: format, units, which shape is what."""


@dataclass(kw_only=True)
class Mould:
    """One mould design. Lengths in l0, box coordinates [0, box]^2, y up.

    A *generated* mould (symmetry in SYMMETRIES) carries the generator's record (seed,
    order, removal, origin, unpruned tethers, rounding, outline kind) and obeys its exact
    area rule. Any other mould is a *user* mould (symmetry USER unless a caller labels it
    otherwise): it needs only box, polygon and tethers, and check_mould checks its
    geometry alone (docs/user_moulds.md).
    """

    mould_id: int = 0
    seed: int | None = None  # dataset seed of a generated mould; None for a user mould
    symmetry: str = USER  # one of SYMMETRIES, or USER (any other label: a user mould)
    order: int = 1  # rotation order (cyclic/dihedral), copies (random_rotation), 2 or 4
    # (mirrors); 1 for a user mould (no symmetry assumed)
    removal: str = USER  # one of the generator's REMOVALS (condor.moulds.paper), "no_tethers" for the tether-free subset, or USER
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
    family: str | None = None  # its source's family: PAPER (the generator), a lab family
    # (condor.moulds.lab.FAMILY_NAMES), "composite" (condor.moulds.composite) or USER; None:
    # PAPER for a generated mould, else USER

    def __post_init__(self):
        if self.family is None:
            self.family = PAPER if self.symmetry in SYMMETRIES else USER

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
            "family": self.family,
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


# --------------------------------------------------------------------------- checks


def check_mould(mould: Mould, rtol: float = 1e-6) -> None:
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
    outside = ~tethers_fit(polygon, tethers, -slack)
    if outside.any():
        i = int(np.flatnonzero(outside)[0])
        raise InvalidMouldError(f"{name}: tether {i} at {tethers[i].tolist()} is not fully "
                                "inside the mould")
    overlap = overlapping_tethers(tethers, -slack)
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


def overlapping_tethers(tethers: np.ndarray, gap: float) -> np.ndarray:
    """Mask of tethers closer than `gap` to any other tether (every member of a pair)."""
    xy, radius = tethers[:, :2], tethers[:, 2]
    distance = np.hypot(*(xy[:, None, :] - xy[None, :, :]).transpose(2, 0, 1))
    clash = distance < radius[:, None] + radius[None, :] + gap
    np.fill_diagonal(clash, False)
    return clash.any(axis=1)


def tethers_fit(polygon: Polygon, tethers: np.ndarray, clearance: float) -> np.ndarray:
    """Mask of tether disks inside `polygon` with at least `clearance` to its boundary."""
    if len(tethers) == 0:
        return np.zeros(0, dtype=bool)
    xy = tethers[:, :2]
    inside = shapely.contains_xy(polygon, xy[:, 0], xy[:, 1])
    wall = shapely.distance(polygon.boundary, shapely.points(xy))
    return inside & (wall >= tethers[:, 2] + clearance)


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
    """Write `mould` as JSON (exact float round trip), whole or not at all (condor.files)."""
    write_text(path, json.dumps(mould.to_dict()))


def load_json(path) -> Mould:
    """Read and validate a mould file; errors (InvalidMouldError) name the file."""
    text = Path(path).read_text()  # OSError (missing, unreadable) names the file itself
    try:
        mould = Mould.from_dict(json.loads(text))
        check_mould(mould)
    except Exception as error:  # any malformed content: JSON, keys, types, geometry
        raise InvalidMouldError(f"{path} is not a valid mould file: {type(error).__name__}: {error}") from error
    return mould
