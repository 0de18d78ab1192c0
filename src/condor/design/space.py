"""A parametric mould family for the search: a real vector -> a mould the simulator accepts.

The footprint is star-shaped about the symmetry origin: its radius is r(theta) =
exp(sum_k c_k b_k(theta)), where the b_k are the Fourier modes cos(m theta), sin(m theta),
m = 1..n_modes, symmetrised over the design's symmetry group and orthonormalised (so every
vector gives a footprint with that symmetry, and no coordinate is wasted on a mode the group
forbids). It is sampled at `vertices` angles: a smooth outline (the generator's rounding)
that is always a simple polygon. Mode m is damped by 2 / max(m, 2) so high modes make gentle
waves. Then, exactly as the generator does, it is scaled to `area_fraction` of the box and
its bounding box is centred in the box.

Each of `n_tethers` tether genes (angle, radial position, radius, presence) places one tether
and its copies under the group: angle phi from the origin (phi = pi/2 * gene + the gene's
evenly spaced base angle), radius r = min + (max - min) * sigmoid(gene), at the fraction
sigmoid(gene) of the way from the origin to the outermost point of that ray where the disk
fits (at least `min_gap` from the wall). The gene is present when its presence gene is > 0.

Fabrication limits and how an infeasible vector is handled (`Decoded.repair` measures how far
the repair went; the search subtracts `repair_weight * repair` from the score, so it learns
to stay feasible, while every returned mould is valid):

  * area = area_fraction of the box: exact by construction (similarity scaling);
  * extent (width and height) <= max_extent of the box, and no neck narrower than `min_neck`
    (the generator's rule): the log-radius wave is shrunk towards a circle, log r -> t log r
    with the largest t in [0, 1] found by bisection (a circle always passes);
    repair += (1 - t)^2 |c|^2;
  * tethers: radius >= min_tether_radius (the lattice's half spacing by default, below which
    the simulator widens a post anyway), disks inside the footprint with >= min_gap to the
    wall, >= min_gap between tethers. A disk that does not fit where its genes put it moves
    inwards along its ray to the nearest place it fits (repair += the moved fraction^2); one
    that fits nowhere on its ray is dropped (repair += 1). Copies of one tether that overlap
    (a tether near a mirror axis or the rotation centre) merge into one at their mean, which
    the group leaves in place; a tether whose copies overlap an earlier tether is dropped
    with all its copies, keeping the symmetry (repair += 1);
  * at least `min_tethers` tethers: fewer is allowed (still a valid mould) but each missing
    tether adds 1 to repair.

Every mould `decode` returns passes condor.moulds.mould.check_mould (checked on each decode).
"""

from __future__ import annotations

import math
import re
from dataclasses import dataclass, field, replace

import numpy as np
import shapely
from shapely.geometry import Polygon

from condor.model.lattice import HALF
from condor.moulds.mould import InvalidMouldError, Mould, check_mould

SYMMETRY_KINDS = ("none", "single_mirror", "double_mirror", "cyclic", "dihedral")
_GENES_PER_TETHER = 4


def symmetry_group(symmetry: str, angle: float = 0.0) -> tuple[str, int, np.ndarray]:
    """(kind, order, matrices (n, 2, 2)) of a symmetry spec about the origin: "none",
    "single_mirror" (mirror line along y, as the generator's vertical mirror),
    "double_mirror", "cyclic:K" or "dihedral:K" (K >= 2), all rotated by `angle` (rad)."""
    match = re.fullmatch(r"\s*([a-z_]+)\s*(?::\s*(\d+))?\s*", str(symmetry))
    kind = match.group(1) if match else None
    if kind not in SYMMETRY_KINDS:
        raise ValueError(f"unknown symmetry {symmetry!r}; choose one of none, single_mirror, "
                         "double_mirror, cyclic:K, dihedral:K")
    rotational = kind in ("cyclic", "dihedral")
    if rotational != (match.group(2) is not None):
        raise ValueError(f"symmetry {symmetry!r}: cyclic and dihedral need an order (e.g. "
                         f"{kind}:4); the others take none")
    k = int(match.group(2)) if rotational else 1
    if rotational and k < 2:
        raise ValueError(f"symmetry {symmetry!r}: the order must be at least 2")
    mirror = np.array([[-1.0, 0.0], [0.0, 1.0]])  # x -> -x: mirror line along y

    def rotation(a):
        return np.array([[math.cos(a), -math.sin(a)], [math.sin(a), math.cos(a)]])

    if kind == "none":
        maps = [np.eye(2)]
    elif kind == "single_mirror":
        maps = [np.eye(2), mirror]
    elif kind == "double_mirror":
        maps = [np.eye(2), mirror, -mirror, -np.eye(2)]
    else:
        rotations = [rotation(2 * math.pi * j / k) for j in range(k)]
        maps = rotations if kind == "cyclic" else rotations + [r @ mirror for r in rotations]
    turn = rotation(angle)
    maps = np.array([turn @ m @ turn.T for m in maps])
    order = {"none": 1, "single_mirror": 2, "double_mirror": 4}.get(kind, k)
    return kind, order, maps


def _shape_basis(maps: np.ndarray, n_modes: int, theta: np.ndarray) -> np.ndarray:
    """(V, d) symmetrised Fourier modes at angles theta: per mode m, the group average of
    cos m theta and sin m theta, orthonormalised (RMS 1 over theta) and damped by
    2 / max(m, 2). A group maps each mode's span onto itself, so modes are treated apart."""
    u = np.stack([np.cos(theta), np.sin(theta)])  # (2, V)
    images = np.einsum("gij,jv->giv", np.linalg.inv(maps), u)  # g^-1 applied to directions
    angles = np.arctan2(images[:, 1], images[:, 0])  # (G, V)
    columns = []
    for m in range(1, n_modes + 1):
        pair = np.stack([np.cos(m * angles).mean(axis=0), np.sin(m * angles).mean(axis=0)], 1)
        left, singular, _ = np.linalg.svd(pair, full_matrices=False)
        rank = int(np.sum(singular > 1e-8 * math.sqrt(len(theta))))
        for j in range(rank):
            column = left[:, j] * math.sqrt(len(theta))
            column *= np.sign(column[np.argmax(np.abs(column))])  # a fixed sign
            columns.append(column * 2.0 / max(m, 2))
    if not columns:
        return np.zeros((len(theta), 0))
    return np.stack(columns, axis=1)


def _sigmoid(x):
    return 1.0 / (1.0 + np.exp(-np.asarray(x, dtype=np.float64)))


@dataclass
class Decoded:
    """A decoded vector: the mould and how much repair it needed (0 = none)."""

    mould: Mould
    repair: float
    shrink: float  # t: 1 = the shape as encoded, < 1 shrunk towards a circle
    n_dropped: int  # tether genes present but dropped (no room, or overlapping)


@dataclass(frozen=True)
class DesignSpace:
    """Mould family of a scene. Lengths in l0 unless named *_box (box sides)."""

    box: float
    area_fraction: float = 0.40
    max_extent: float = 0.90
    symmetry: str = "double_mirror"
    symmetry_angle: float = 0.0  # radians: rotates the mirror axes / rotation frame
    n_modes: int = 6
    n_tethers: int = 4  # tether genes; each places a tether and its symmetric copies
    min_tether_radius: float = HALF  # the lattice resolves no smaller post
    max_tether_radius_box: float = 0.05  # the generator's largest (box sides)
    min_gap: float = 1.0  # tether to tether and tether to wall: one cell spacing
    min_neck_box: float = 0.03  # the generator's min_neck (box sides)
    min_tethers: int = 0
    shape_scale: float = 0.2  # log-radius amplitude per unit gene (before mode damping)
    vertices: int = 128
    # A fixed footprint (shapely Polygon in box coordinates): the search then places the
    # posts alone, inside it (from its centroid), and n_modes should be 0 (see constrained_space)
    footprint: object = None
    all_present: bool = False  # every tether gene places its post (presence genes ignored)
    _cache: dict = field(default_factory=dict, compare=False, repr=False, hash=False)

    def __post_init__(self):
        if not (math.isfinite(self.box) and self.box > 0):
            raise ValueError(f"DesignSpace.box = {self.box!r} must be a positive length (l0)")
        if not 0 < self.area_fraction < 1:
            raise ValueError(f"DesignSpace.area_fraction = {self.area_fraction!r} must be in (0, 1)")
        circle_extent = 2 * math.sqrt(self.area_fraction / math.pi)
        if not circle_extent < self.max_extent <= 1:
            raise ValueError(f"DesignSpace.max_extent = {self.max_extent!r} must be in "
                             f"({circle_extent:.3f}, 1]: a circle of area fraction "
                             f"{self.area_fraction} is {circle_extent:.3f} wide")
        kind, order, maps = symmetry_group(self.symmetry, self.symmetry_angle)
        for name in ("n_modes", "n_tethers", "min_tethers", "vertices"):
            value = getattr(self, name)
            if isinstance(value, bool) or not isinstance(value, (int, np.integer)) or value < 0:
                raise ValueError(f"DesignSpace.{name} = {value!r} must be a non-negative int")
        if self.vertices < 16:
            raise ValueError(f"DesignSpace.vertices = {self.vertices} must be at least 16")
        if not self.min_tether_radius > 0:
            raise ValueError(f"DesignSpace.min_tether_radius = {self.min_tether_radius!r} "
                             "must be positive (l0)")
        if self.max_tether_radius < self.min_tether_radius:
            raise ValueError(f"DesignSpace.max_tether_radius_box = {self.max_tether_radius_box} "
                             f"({self.max_tether_radius:.3g} l0) is below min_tether_radius = "
                             f"{self.min_tether_radius:.3g} l0")
        for name in ("min_gap", "min_neck_box", "shape_scale"):
            if not getattr(self, name) >= 0:
                raise ValueError(f"DesignSpace.{name} = {getattr(self, name)!r} must be >= 0")
        # Vertex angles the group maps onto each other (so the sampled outline is exactly
        # symmetric): a multiple of 2 x the rotation order, starting on the frame's axis.
        step = 2 * (order if kind in ("cyclic", "dihedral") else 2)
        n_vertices = step * math.ceil(self.vertices / step)
        theta = self.symmetry_angle + 2 * math.pi * np.arange(n_vertices) / n_vertices
        self._cache.update(kind=kind, order=order, maps=maps, theta=theta,
                           directions=np.stack([np.cos(theta), np.sin(theta)], axis=1),
                           basis=_shape_basis(maps, self.n_modes, theta) * self.shape_scale)

    @classmethod
    def from_scene(cls, scene, **overrides) -> "DesignSpace":
        """The space for a condor.model.scenes.Scene (box, area fraction and extent of its dataset)."""
        settings = {"box": scene.box, "area_fraction": scene.area_fraction,
                    "max_extent": scene.max_extent, **overrides}
        return cls(**settings)

    def with_(self, **changes) -> "DesignSpace":
        return replace(self, _cache={}, **changes)

    # ------------------------------------------------------------------ layout

    @property
    def max_tether_radius(self) -> float:
        return self.max_tether_radius_box * self.box

    @property
    def n_shape(self) -> int:
        return self._cache["basis"].shape[1]

    @property
    def dim(self) -> int:
        """Length of a design vector: shape coefficients, then 4 genes per tether."""
        return self.n_shape + _GENES_PER_TETHER * self.n_tethers

    @property
    def group(self) -> np.ndarray:
        return self._cache["maps"]

    def random_vectors(self, rng: np.random.Generator, n: int) -> np.ndarray:
        """n standard normal vectors (the search's initial probe)."""
        return rng.standard_normal((n, self.dim))

    # ------------------------------------------------------------------ decoding

    def decode(self, vector, mould_id: int = 0, seed: int = 0) -> Decoded:
        """The mould of `vector` (see the module docstring) and its repair measure."""
        x = np.asarray(vector, dtype=np.float64)
        if x.shape != (self.dim,):
            raise ValueError(f"design vector has shape {x.shape}, this space needs ({self.dim},)")
        if not np.all(np.isfinite(x)):
            raise ValueError("design vector holds NaN or infinite values")
        coefficients = x[: self.n_shape]
        polygon, origin, shrink = self._footprint(coefficients)
        repair = (1.0 - shrink) ** 2 * float(coefficients @ coefficients)
        genes = x[self.n_shape:].reshape(self.n_tethers, _GENES_PER_TETHER)
        tethers, moved, dropped = self._tethers(polygon, origin, genes)
        repair += moved + dropped + max(0, self.min_tethers - len(tethers))
        kind, order = self._cache["kind"], self._cache["order"]
        mould = Mould(
            mould_id=int(mould_id), seed=int(seed), symmetry=kind, order=order,
            removal="none" if len(tethers) else "no_tethers", box=float(self.box),
            polygon=polygon, tethers=tethers, origin=(float(origin[0]), float(origin[1])),
            unpruned_tethers=tethers.copy(), area_fraction=float(self.area_fraction),
            outline="simple_polygon")
        try:
            check_mould(mould)
        except InvalidMouldError as error:  # a bug in the repair, never a user error
            raise RuntimeError(f"design space produced an invalid mould from {x.tolist()}: "
                               f"{error}") from error
        return Decoded(mould, float(repair), float(shrink), int(dropped))

    def mould(self, vector, mould_id: int = 0, seed: int = 0) -> Mould:
        return self.decode(vector, mould_id, seed).mould

    def _outline(self, log_radius: np.ndarray, shrink: float):
        """Footprint vertices (V, 2) in l0 for the log-radius wave shrunk by t = `shrink`,
        symmetry origin at (0, 0), area exactly area_fraction of the box."""
        scaled = shrink * log_radius
        radius = np.exp(scaled - scaled.max())  # scale is fixed below; avoid overflow
        xy = radius[:, None] * self._cache["directions"]
        x, y = xy[:, 0], xy[:, 1]
        area = 0.5 * abs(np.dot(x, np.roll(y, -1)) - np.dot(y, np.roll(x, -1)))
        return xy * math.sqrt(self.area_fraction * self.box**2 / area)

    def _extent_ok(self, xy: np.ndarray) -> bool:
        return float(np.max(xy.max(axis=0) - xy.min(axis=0))) <= self.max_extent * self.box

    def _neck_ok(self, xy: np.ndarray) -> bool:
        if self.min_neck_box <= 0:
            return True
        core = Polygon(xy).buffer(-self.min_neck_box * self.box / 2, quad_segs=4)
        return isinstance(core, Polygon) and not core.is_empty

    def _footprint(self, coefficients: np.ndarray):
        """(polygon in box coordinates, origin, shrink t). The extent is cheap to test
        (numpy), the neck is not (a shapely buffer): bisect on the extent first, then, only
        if the neck fails there, on both. A fixed `footprint` is returned as it is, its origin
        the centroid."""
        if self.footprint is not None:
            centre = self.footprint.centroid
            return self.footprint, np.array([centre.x, centre.y]), 1.0
        def largest(t_high, ok):
            if ok(t_high):
                return t_high
            low, high = 0.0, t_high  # a circle (t = 0) always passes
            for _ in range(14):
                mid = 0.5 * (low + high)
                low, high = (mid, high) if ok(mid) else (low, mid)
            return low

        log_radius = self._cache["basis"] @ coefficients

        def extent_ok(t):
            return self._extent_ok(self._outline(log_radius, t))

        def both_ok(t):
            xy = self._outline(log_radius, t)
            return self._extent_ok(xy) and self._neck_ok(xy)

        shrink = largest(largest(1.0, extent_ok), both_ok)
        xy = self._outline(log_radius, shrink)
        shift = self.box / 2 - 0.5 * (xy.min(axis=0) + xy.max(axis=0))
        return Polygon(xy + shift), shift, shrink

    def _fits(self, polygon: Polygon, xy: np.ndarray, radius) -> np.ndarray:
        """Mask of disks (centres xy (n, 2), radius) inside `polygon` with min_gap to the wall."""
        inside = shapely.contains_xy(polygon, xy[:, 0], xy[:, 1])
        wall = shapely.distance(polygon.exterior, shapely.points(xy))
        return inside & (wall >= np.asarray(radius) + self.min_gap)

    def _tethers(self, polygon: Polygon, origin: np.ndarray, genes: np.ndarray):
        """Tethers (n, 3) in box coordinates, the repair for moved tethers, dropped genes."""
        maps = self._cache["maps"]
        kept: list[np.ndarray] = []
        moved = 0.0
        dropped = 0
        steps = np.linspace(1.0, 0.0, 41)  # candidate fractions along the ray, outside in
        reach = self.max_extent * self.box  # longer than any ray inside the footprint
        for j, (g_angle, g_radial, g_radius, g_present) in enumerate(genes):
            if g_present <= 0 and not self.all_present:
                continue
            phi = math.pi / 2 * g_angle + 2 * math.pi * j / max(self.n_tethers, 1)
            radius = self.min_tether_radius + (self.max_tether_radius - self.min_tether_radius) \
                * float(_sigmoid(g_radius))
            direction = np.array([math.cos(phi), math.sin(phi)])
            ray = origin + np.outer(steps * reach, direction)
            fits = self._fits(polygon, ray, radius)
            if not fits.any():
                dropped += 1
                continue
            outermost = steps[np.argmax(fits)]  # first fitting candidate from outside
            want = float(_sigmoid(g_radial)) * outermost
            if not self._fits(polygon, (origin + want * reach * direction)[None], radius)[0]:
                candidates = np.flatnonzero(fits)  # the ray leaves and re-enters the room
                nearest = steps[candidates[np.argmin(np.abs(steps[candidates] - want))]]
                moved += (nearest - want) ** 2
                want = nearest
            centre = origin + want * reach * direction
            orbit = self._merge_orbit(origin + (centre - origin) @ maps.transpose(0, 2, 1),
                                      radius)
            orbit_disks = np.column_stack([orbit, np.full(len(orbit), radius)])
            if not self._fits(polygon, orbit, radius).all() or \
                    _overlaps(orbit_disks, kept, self.min_gap):
                dropped += 1
                continue
            kept.extend(orbit_disks)
        tethers = np.array(kept, dtype=np.float64).reshape(-1, 3)
        return tethers, moved, dropped

    def _merge_orbit(self, copies: np.ndarray, radius: float) -> np.ndarray:
        """Copies (G, 2) of one tether; overlapping ones (closer than 2 r + min_gap) merged
        into their mean (single linkage)."""
        n = len(copies)
        label = np.arange(n)
        distance = np.hypot(*(copies[:, None, :] - copies[None, :, :]).transpose(2, 0, 1))
        close = distance < 2 * radius + self.min_gap
        for _ in range(n):  # propagate the smallest label through the close pairs
            new = np.array([label[close[i]].min() for i in range(n)])
            if np.array_equal(new, label):
                break
            label = new
        return np.array([copies[label == c].mean(axis=0) for c in np.unique(label)])


def _overlaps(disks: np.ndarray, kept: list[np.ndarray], gap: float) -> bool:
    if not kept:
        return False
    other = np.asarray(kept)
    distance = np.hypot(*(disks[:, None, :2] - other[None, :, :2]).transpose(2, 0, 1))
    return bool((distance < disks[:, None, 2] + other[None, :, 2] + gap).any())


def default_space(scene, objective=None, **overrides) -> DesignSpace:
    """The space the search uses unless told otherwise: double mirror symmetry with its axes
    along the objective's alignment direction when all alignment terms share one (a
    mirror-symmetric tissue has no net alignment off its axes); none otherwise."""
    settings = {"symmetry": "double_mirror", "symmetry_angle": 0.0}
    if objective is not None:
        angles = {round(q.angle % (math.pi / 2), 12) for q in objective.quantities
                  if q.name == "alignment"}
        if len(angles) == 1:
            settings["symmetry_angle"] = angles.pop()
        elif len(angles) > 1:
            settings["symmetry"] = "none"
    settings.update(overrides)
    return DesignSpace.from_scene(scene, **settings)


def constrained_space(scene, mould, keep, objective=None) -> DesignSpace:
    """The search's space constrained to a user's `mould` (condor.moulds.mould.Mould, placed in the
    scene's box): `keep` holds "footprint" (its outline, fixed: the search places the posts
    alone, from the outline's centroid, and the symmetry is none) and/or "posts" (its number
    of posts: that many tether genes, each placing one post, symmetry none; a post with no
    room is dropped and penalised as the search's repair). Without "footprint" the outline is searched as usual."""
    keep = set(keep)
    unknown = keep - {"footprint", "posts"}
    if unknown:
        raise ValueError(f"--keep {sorted(unknown)}: choose footprint and/or posts")
    if not keep:
        return default_space(scene, objective)
    settings = {}
    tethers = np.asarray(mould.tethers, dtype=float).reshape(-1, 3)
    if "posts" in keep:
        settings.update(symmetry="none", n_tethers=len(tethers), min_tethers=len(tethers),
                        all_present=True)
        if len(tethers):  # the user's posts fit the space's radius range
            settings["max_tether_radius_box"] = max(0.05, float(tethers[:, 2].max()) / scene.box)
    if "footprint" in keep:
        polygon = mould.polygon
        xmin, ymin, xmax, ymax = polygon.bounds
        settings.update(symmetry="none", n_modes=0, footprint=polygon,
                        area_fraction=float(polygon.area) / scene.box**2,
                        max_extent=max(scene.max_extent,
                                       max(xmax - xmin, ymax - ymin) / scene.box))
        settings.setdefault("n_tethers", max(len(tethers), 4))
    return default_space(scene, objective, **settings)
