"""Lab moulds: the shapes labs cast, in families, each a pure function of (seed, mould id).

The paper's generator (`generate_mould`) draws unions of random polygons at one area with 0 or
at least 4 posts; a lab casts strips and dog-bones on two posts, rings round a post, crosses
and polygons with posts at their arms or corners, frames with holes, smooth outlines, strips
anchored along their sides. Each family below is a function of a random generator and returns
an outline (a shapely Polygon, holes allowed) and posts (n, 3: x, y, radius) in box sides, the
box being [0, 1]^2; `lab_mould` draws one, scales it to a uniform area fraction in AREA_RANGE,
turns it by a uniform angle when the family has no preferred axis, centres it, checks it (the
mould contract, extent <= MAX_EXTENT, posts clear of the walls and of each other) and redraws
the geometry until it passes. Post radii are drawn in box sides from each family's range (the
paper generator's are 0.007-0.054 box sides; a ring's central post is larger).

Every family's parameters and ranges are in FAMILIES (`LabFamily.ranges`), their one home;
docs/moulds.md, "Lab families", describes each with a gallery. A lab mould is checked as a
user's drawing is (`check_mould`: no area rule, room for cells everywhere it joins) and carries
its family's name (`Mould.family`).
"""

from __future__ import annotations

import math
from dataclasses import dataclass, field
from typing import Callable

import numpy as np
import shapely
from shapely import affinity
from shapely.geometry import LineString, Point, Polygon, box as rectangle

from condor.model.scenes import Scene
from condor.moulds.mould import Mould, check_mould

AREA_RANGE = (0.20, 0.55)  # polygon area / box area, uniform
MAX_EXTENT = 0.90  # width and height at most this share of the box (the generator's)
CLEARANCE = 0.012  # box sides: post to wall and post to post, at least
MAX_ATTEMPTS = 200  # geometry redraws per mould
LAB_STREAM = 3  # default_rng([seed, mould, LAB_STREAM]): the lab geometry's own stream
ARC_SEGMENTS = 16  # buffer segments a quarter circle


@dataclass(frozen=True)
class LabFamily:
    """A family of lab moulds: `draw(rng)` -> (outline, posts) in box sides around the
    origin, before scaling; `ranges` documents every parameter it draws (name -> (low,
    high), box sides unless the name says otherwise); `turn`: whether the mould is turned by
    a uniform angle (False for shapes a lab aligns with its axes)."""

    name: str
    summary: str
    draw: Callable
    ranges: dict = field(default_factory=dict)
    turn: bool = True


def _round_rect(width: float, height: float, radius: float) -> Polygon:
    """A rectangle centred at the origin with corners rounded by `radius`."""
    radius = min(radius, 0.49 * min(width, height))
    core = rectangle(-width / 2 + radius, -height / 2 + radius, width / 2 - radius,
                     height / 2 - radius)
    return core.buffer(radius, quad_segs=ARC_SEGMENTS) if radius > 0 else core


def _stadium(length: float, width: float) -> Polygon:
    """A strip of `length` with semicircular ends of diameter `width`, along x."""
    half = max(length - width, 1e-9) / 2
    return LineString([(-half, 0), (half, 0)]).buffer(width / 2, quad_segs=ARC_SEGMENTS)


def _fillet(polygon: Polygon, radius: float) -> Polygon:
    """Concave corners rounded by `radius` (a closing), as a cast mould's are."""
    return polygon.buffer(radius, quad_segs=ARC_SEGMENTS).buffer(-radius, quad_segs=ARC_SEGMENTS)


def _radius(rng, low: float, high: float) -> float:
    return float(rng.uniform(low, high))


# --------------------------------------------------------------------------- the families


def _strip(rng):
    aspect = rng.uniform(2.5, 6.0)
    width = 1.0
    outline = _stadium(aspect * width, width) if rng.random() < 0.5 else \
        _round_rect(aspect * width, width, rng.uniform(0.05, 0.25) * width)
    inset = rng.uniform(0.45, 0.9) * width  # post centre from the strip's end
    x = aspect * width / 2 - inset
    return outline, np.array([[-x, 0.0], [x, 0.0]]), {"width": width}


def _dogbone(rng):
    pad = 1.0  # pad radius
    waist = rng.uniform(0.3, 0.75) * 2 * pad  # narrowest width
    length = rng.uniform(1.5, 4.0) * pad  # between the pads' centres
    curved = rng.random() < 0.5
    round_pads = rng.random() < 0.5
    pad_half = pad if round_pads else 0.9 * pad  # the pad's half width across the axis
    x = np.linspace(-length / 2, length / 2, 41)
    if curved:  # the waist widens smoothly towards the pads: a concave profile
        half = waist / 2 + (0.8 * pad_half - waist / 2) * np.clip(2 * np.abs(x) / length, 0,
                                                                   1) ** 2
        half = np.maximum(half, waist / 2)
    else:
        half = np.full_like(x, waist / 2)
    body = Polygon(np.concatenate([np.stack([x, half], 1), np.stack([x[::-1], -half[::-1]], 1)]))
    if round_pads:
        pads = [Point(dx, 0).buffer(pad, quad_segs=ARC_SEGMENTS)
                for dx in (-length / 2, length / 2)]
    else:
        side = 2 * pad_half
        pads = [affinity.translate(_round_rect(side, side, 0.2 * pad), dx, 0)
                for dx in (-length / 2, length / 2)]
    outline = _fillet(shapely.union_all([body, *pads]), 0.15 * pad)
    return outline, np.array([[-length / 2, 0.0], [length / 2, 0.0]]), {"width": 2 * pad}


def _ring(rng):
    """A disk (or a slight oval) round one central post: the tissue forms a ring."""
    aspect = rng.uniform(1.0, 1.4)
    outline = affinity.scale(Point(0, 0).buffer(1.0, quad_segs=ARC_SEGMENTS), aspect, 1.0)
    return outline, np.array([[0.0, 0.0]]), {"central": True}


def _annulus(rng):
    """A ring-shaped mould (a disk with a concentric hole) with posts on its midline."""
    inner = rng.uniform(0.3, 0.6)
    aspect = rng.uniform(1.0, 1.3)
    disk = Point(0, 0).buffer(1.0, quad_segs=ARC_SEGMENTS)
    hole = Point(0, 0).buffer(inner, quad_segs=ARC_SEGMENTS)
    outline = affinity.scale(disk.difference(hole), aspect, 1.0)
    n = int(rng.integers(2, 7))
    phase = rng.uniform(0, 2 * np.pi / n)
    mid = (1 + inner) / 2
    angles = phase + 2 * np.pi * np.arange(n) / n
    posts = np.stack([aspect * mid * np.cos(angles), mid * np.sin(angles)], 1)
    return outline, posts, {"width": 1 - inner}


def _polygon(rng):
    """A regular polygon, corners rounded, a post inset at each corner."""
    n = int(rng.integers(3, 9))
    angles = 2 * np.pi * np.arange(n) / n + np.pi / 2
    corners = np.stack([np.cos(angles), np.sin(angles)], 1)
    outline = Polygon(corners)
    rounding = rng.uniform(0.05, 0.2)
    outline = outline.buffer(-rounding, quad_segs=ARC_SEGMENTS).buffer(rounding,
                                                                        quad_segs=ARC_SEGMENTS)
    posts = corners * rng.uniform(0.6, 0.78)
    return outline, posts, {"width": 2 * math.cos(math.pi / n) * 0.6}


def _cross(rng):
    """A cross of 3-6 arms of equal width, a post near each arm's end."""
    n = int(rng.choice([3, 4, 4, 4, 5, 6]))
    width = rng.uniform(0.3, 0.6) if n <= 4 else rng.uniform(0.25, 0.4)
    length = 1.0  # arm length from the centre
    phase = rng.uniform(0, np.pi)
    arms = []
    posts = []
    inset = rng.uniform(0.5, 0.85) * width
    cap = "round" if rng.random() < 0.5 else "flat"
    for k in range(n):
        a = phase + 2 * np.pi * k / n
        end = (length * math.cos(a), length * math.sin(a))
        arms.append(LineString([(0, 0), end]).buffer(width / 2, cap_style=cap,
                                                     quad_segs=ARC_SEGMENTS))
        posts.append(((length - inset) * math.cos(a), (length - inset) * math.sin(a)))
    outline = _fillet(shapely.union_all(arms), 0.2 * width)
    return outline, np.array(posts), {"width": width}


def _spline(rng):
    """A smooth closed outline r(phi) = 1 + sum_k a_k cos(k phi + p_k), k = 2..5, with 1-8 posts
    placed at random inside it."""
    phi = np.linspace(0, 2 * np.pi, 256, endpoint=False)
    r = np.ones_like(phi)
    for k in range(2, 6):
        r += rng.uniform(0, 0.35 / k) * np.cos(k * phi + rng.uniform(0, 2 * np.pi))
    outline = Polygon(np.stack([r * np.cos(phi), r * np.sin(phi)], 1))
    n = int(rng.integers(1, 9))
    return outline, random_posts(rng, outline, n), {"random_posts": n}


def _frame(rng):
    """A rectangle with 1-4 holes (a frame, or a grid of windows), posts at its corners or
    the midpoints of its sides."""
    aspect = rng.uniform(1.0, 2.0)
    width, height = aspect, 1.0
    bar = rng.uniform(0.18, 0.3)  # the frame's bar width
    outline = _round_rect(width, height, rng.uniform(0.0, 0.12))
    nx, ny = (1, 1) if rng.random() < 0.5 else ((2, 1) if rng.random() < 0.6 else (2, 2))
    hole_w = (width - (nx + 1) * bar) / nx
    hole_h = (height - (ny + 1) * bar) / ny
    holes = []
    for i in range(nx):
        for j in range(ny):
            cx = -width / 2 + bar + hole_w / 2 + i * (hole_w + bar)
            cy = -height / 2 + bar + hole_h / 2 + j * (hole_h + bar)
            if rng.random() < 0.3:
                hole = affinity.scale(Point(cx, cy).buffer(0.5, quad_segs=ARC_SEGMENTS),
                                      hole_w, hole_h)
            else:
                hole = affinity.translate(_round_rect(hole_w, hole_h,
                                                      rng.uniform(0.0, 0.3) * min(hole_w, hole_h)),
                                          cx, cy)
            holes.append(hole)
    outline = outline.difference(shapely.union_all(holes))
    x, y = width / 2 - bar / 2, height / 2 - bar / 2
    if rng.random() < 0.6:
        posts = np.array([[-x, -y], [x, -y], [x, y], [-x, y]])
    else:
        posts = np.array([[0, -y], [x, 0], [0, y], [-x, 0]]) if nx == 1 else \
            np.array([[-x, 0.0], [x, 0.0]])
    return outline, posts, {"width": bar}


def _side_anchored(rng):
    """A long strip with a row of 2-4 posts along each long side."""
    aspect = rng.uniform(2.0, 4.5)
    width, height = aspect, 1.0
    outline = _round_rect(width, height, rng.uniform(0.05, 0.3))
    per_side = int(rng.integers(2, 5))
    inset = rng.uniform(0.12, 0.22)
    x = np.linspace(-width / 2 + 0.35 * height, width / 2 - 0.35 * height, per_side)
    y = height / 2 - inset
    posts = np.concatenate([np.stack([x, np.full(per_side, y)], 1),
                            np.stack([x, np.full(per_side, -y)], 1)])
    return outline, posts, {"width": 2 * inset}


def _oval(rng):
    """An ellipse with 2 posts on its long axis, or 4 (two on each axis)."""
    aspect = rng.uniform(1.3, 3.0)
    outline = affinity.scale(Point(0, 0).buffer(1.0, quad_segs=ARC_SEGMENTS), aspect, 1.0)
    inset = rng.uniform(0.45, 0.8)
    posts = [[-aspect * inset, 0.0], [aspect * inset, 0.0]]
    if rng.random() < 0.5:
        posts += [[0.0, -inset], [0.0, inset]]
    return outline, np.array(posts), {"width": 2.0}


# batches of 30 candidates that may all miss random_posts' inner region before it draws in the
# whole outline: a region that 60,000 candidates miss is a sliver (one composite band drew a
# core of 1e-8 of its bounds, 2 CPU minutes of candidates); a usual one misses a batch or two
EMPTY_BATCHES = 2000


def random_posts(rng, outline: Polygon, n: int, spread: bool = True) -> np.ndarray:
    """n points inside `outline`, at least a fifth of its inradius-ish size from the wall and
    spread out (the farthest of 30 candidates from the chosen ones, each time; with `spread`
    False, the first candidate inside). Where that inner region is a sliver that
    EMPTY_BATCHES batches of candidates in a row all miss (a band whose half-width is about
    that margin), the points are drawn anywhere inside `outline` instead; RuntimeError if
    even those miss."""
    xmin, ymin, xmax, ymax = outline.bounds
    core = outline.buffer(-0.2 * min(xmax - xmin, ymax - ymin) / 2)
    if core.is_empty:
        core = outline
    chosen: list[np.ndarray] = []
    cx0, cy0, cx1, cy1 = core.bounds
    empty = 0
    while len(chosen) < n:
        xy = rng.uniform([cx0, cy0], [cx1, cy1], size=(30, 2))
        xy = xy[shapely.contains_xy(core, xy[:, 0], xy[:, 1])]
        if not len(xy):
            empty += 1
            if empty >= EMPTY_BATCHES:
                if core is outline:
                    raise RuntimeError(f"no point inside the outline (area {outline.area:.3g}) "
                                       f"in {EMPTY_BATCHES} batches of candidates")
                core, empty = outline, 0
                cx0, cy0, cx1, cy1 = core.bounds
            continue
        empty = 0
        if chosen and spread:
            d = np.min(np.linalg.norm(xy[:, None] - np.array(chosen)[None], axis=2), axis=1)
            chosen.append(xy[int(np.argmax(d))])
        else:
            chosen.append(xy[0])
    return np.array(chosen)


FAMILIES: dict[str, LabFamily] = {f.name: f for f in (
    LabFamily("strip", "a strip (straight or stadium) on two posts near its ends", _strip,
              {"aspect (length / width)": (2.5, 6.0), "post inset / width": (0.45, 0.9),
               "post radius": (0.02, 0.055)}),
    LabFamily("dogbone", "two pads (round or square) joined by a straight or curved waist, a "
              "post in each pad", _dogbone,
              {"waist / pad diameter": (0.3, 0.75), "pad distance / pad radius": (1.5, 4.0),
               "post radius": (0.025, 0.06)}),
    LabFamily("ring", "a disk or slight oval round one large central post", _ring,
              {"aspect": (1.0, 1.4), "post radius": (0.04, 0.13)}, turn=True),
    LabFamily("annulus", "a ring-shaped mould (a concentric hole) with 2-6 posts on its midline",
              _annulus, {"hole radius / outer radius": (0.3, 0.6), "aspect": (1.0, 1.3),
                         "posts": (2, 6), "post radius": (0.02, 0.045)}),
    LabFamily("polygon", "a regular polygon of 3-8 sides, corners rounded, a post at each "
              "corner", _polygon, {"sides (= posts)": (3, 8), "post inset": (0.6, 0.78),
                                   "post radius": (0.02, 0.045)}),
    LabFamily("cross", "3-6 arms of equal width from a centre, a post near each arm's end",
              _cross, {"arms (= posts)": (3, 6), "arm width / arm length": (0.3, 0.6),
                       "post radius": (0.02, 0.045)}),
    LabFamily("spline", "a smooth random outline (harmonics 2-5) with 1-8 posts inside",
              _spline, {"posts": (1, 8), "post radius": (0.02, 0.05)}),
    LabFamily("frame", "a rectangle with 1-4 holes, posts at its corners or its sides' "
              "midpoints", _frame, {"aspect": (1.0, 2.0), "bar / height": (0.18, 0.3),
                                    "post radius": (0.02, 0.04)}, turn=False),
    LabFamily("side_anchored", "a long strip anchored by 2-4 posts along each long side",
              _side_anchored, {"aspect": (2.0, 4.5), "posts a side": (2, 4),
                               "post radius": (0.015, 0.035)}),
    LabFamily("oval", "an ellipse with 2 posts on its long axis, or 4 (two on each axis)", _oval,
              {"aspect": (1.3, 3.0), "post inset": (0.45, 0.8), "post radius": (0.02, 0.05)}),
)}
FAMILY_NAMES: tuple[str, ...] = tuple(FAMILIES)


def _post_radius_range(family: LabFamily) -> tuple[float, float]:
    return family.ranges["post radius"]


def _attempt(rng, family: LabFamily, max_extent: float, area_range: tuple[float, float]):
    """One draw of the family's geometry, scaled, turned and centred in the unit box; None
    when it breaks a rule (too wide, posts too close to a wall or each other)."""
    outline, posts, _ = family.draw(rng)
    area = rng.uniform(*area_range)
    scale = math.sqrt(area / outline.area)
    angle = rng.uniform(0, 180) if family.turn else float(rng.choice([0.0, 90.0]))
    low, high = _post_radius_range(family)
    radii = rng.uniform(low, high, size=len(posts))
    outline = affinity.rotate(affinity.scale(outline, scale, scale, origin=(0, 0)), angle,
                              origin=(0, 0))
    if len(posts):
        c, s = math.cos(math.radians(angle)), math.sin(math.radians(angle))
        posts = (posts * scale) @ np.array([[c, s], [-s, c]])
    xmin, ymin, xmax, ymax = outline.bounds
    if max(xmax - xmin, ymax - ymin) > max_extent:
        return None
    shift = np.array([0.5 - (xmin + xmax) / 2, 0.5 - (ymin + ymax) / 2])
    outline = affinity.translate(outline, *shift)
    tethers = np.column_stack([posts + shift, radii]) if len(posts) else np.zeros((0, 3))
    if not outline.is_valid or outline.geom_type != "Polygon":
        return None
    for x, y, r in tethers:
        if outline.exterior.distance(Point(x, y)) < r + CLEARANCE or \
                not outline.contains(Point(x, y)) or \
                any(ring.distance(Point(x, y)) < r + CLEARANCE for ring in outline.interiors):
            return None
    if len(tethers) > 1:
        d = np.linalg.norm(tethers[:, None, :2] - tethers[None, :, :2], axis=2)
        gap = d - tethers[:, None, 2] - tethers[None, :, 2]
        np.fill_diagonal(gap, np.inf)
        if gap.min() < CLEARANCE:
            return None
    return outline, tethers


def lab_geometry(seed: int, mould_id: int, family: str, box: float,
                 max_extent: float = MAX_EXTENT,
                 area_range: tuple[float, float] = AREA_RANGE) -> tuple[Polygon, np.ndarray]:
    """The outline (l0) and posts (n, 3, l0) of lab mould `mould_id` of `family` in a box of
    side `box`: a pure function of its arguments (`family_geometry`)."""
    if family not in FAMILIES:
        raise ValueError(f"unknown lab family {family!r}; choose one of {FAMILY_NAMES}")
    return family_geometry(seed, mould_id, FAMILIES[family], box, max_extent, area_range)


def family_geometry(seed: int, mould_id: int, fam: LabFamily, box: float,
                    max_extent: float = MAX_EXTENT,
                    area_range: tuple[float, float] = AREA_RANGE) -> tuple[Polygon, np.ndarray]:
    """The outline (l0) and posts (n, 3, l0) of mould `mould_id` of family `fam` (a LabFamily,
    here or condor.moulds.composite's) in a box of side `box` (rng = default_rng([seed,
    mould_id, LAB_STREAM])). RuntimeError when no draw passes in MAX_ATTEMPTS."""
    rng = np.random.default_rng([int(seed), int(mould_id), LAB_STREAM])
    for _ in range(MAX_ATTEMPTS):
        found = _attempt(rng, fam, max_extent, area_range)
        if found is not None:
            outline, tethers = found
            to_box = float(box)
            return (affinity.scale(outline, to_box, to_box, origin=(0, 0)),
                    tethers * np.array([to_box, to_box, to_box]))
    raise RuntimeError(f"lab mould {mould_id} (seed {seed}, family {fam.name}): no geometry "
                       f"passed in {MAX_ATTEMPTS} draws")


def lab_mould(seed: int, mould_id: int, family: str, scene: Scene,
              area_range: tuple[float, float] = AREA_RANGE) -> Mould:
    """Lab mould `mould_id` of dataset `seed`, of `family`, in `scene`'s box (at most
    scene.max_extent of it wide), checked against the mould contract."""
    if family not in FAMILIES:
        raise ValueError(f"unknown lab family {family!r}; choose one of {FAMILY_NAMES}")
    return family_mould(seed, mould_id, FAMILIES[family], scene, area_range)


def family_mould(seed: int, mould_id: int, fam: LabFamily, scene: Scene,
                 area_range: tuple[float, float] = AREA_RANGE) -> Mould:
    """Mould `mould_id` of family `fam` (`family_geometry`) in `scene`'s box, carrying the
    family's name, checked against the mould contract."""
    polygon, tethers = family_geometry(seed, mould_id, fam, scene.box, scene.max_extent,
                                       area_range)
    mould = Mould(mould_id=int(mould_id), seed=int(seed), box=float(scene.box), polygon=polygon,
                  tethers=tethers, family=fam.name)
    check_mould(mould)
    return mould


def check_area_range(area_range, families, max_extent: float = MAX_EXTENT) -> None:
    """ValueError unless `area_range` is (low, high) with 0 < low < high < 1 and every family
    of `families` can draw a mould in it within `max_extent` (tried on a few moulds when the
    range or the extent is not the default, which is known to work)."""
    low, high = (float(v) for v in area_range)
    if not 0 < low < high < 1:
        raise ValueError(f"the area range [{low:g}, {high:g}] must rise within (0, 1)")
    if (low, high) == AREA_RANGE and max_extent >= MAX_EXTENT:
        return
    for family in families:
        for mould_id in range(3):
            try:
                lab_geometry(0, mould_id, family, 1.0, max_extent, (low, high))
            except RuntimeError:
                raise ValueError(f"the {family} family cannot make a mould of area "
                                 f"{low:g}-{high:g} of the box within an extent of "
                                 f"{max_extent:g} of it (its elongated shapes stay smaller): "
                                 "lower the range or leave the family out") from None
