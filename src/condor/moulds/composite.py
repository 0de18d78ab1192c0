"""Composite moulds: a training source that varies what lab moulds vary, not a shape labs cast.

A composite mould is a union of 1-3 random parts (stadiums, ellipses, rounded rectangles,
convex polygons, curved bars), each joined at a point of the outline so far, concave corners
rounded, a quarter of them a band round a hole, a third of the rest with 1-3 holes, and 1-8
posts inside: along a wall, at the outline's tips, spread apart or placed at random; drawn,
scaled to an area in the lab range, turned, centred and checked as a lab mould is
(`condor.moulds.lab.family_mould`, the same stream). The paper's generator never makes one
or two posts or holes, and each lab family makes one kind of each: the hope was that a
surrogate trained on composite moulds meets fewer moulds unlike anything it saw. Measured in
experiments/generalisation/README.md: without posts along walls or bands ("Composite moulds in
training") the held-out kinds' error stayed; with them ("Composite moulds with posts along a
wall and bands round holes") annuli, frames and crosses held out gained 0.1-0.3x of their noise
ceiling, which more moulds of the families did not give; with posts at tips and curved bars
(2026-12-07) the error on kinds no source draws fell 7% (experiments/unseen_kinds). A dataset draws
`moulds.composite_fraction` of its training and validation lab moulds from here
(`condor.moulds.sources`); the test sets never hold one. The default run draws about 100
beside 200 of the families' and 200 of the generator's (that README's "the default since
9b32aad").
"""

from __future__ import annotations

import numpy as np
import shapely
from shapely import affinity
from shapely.geometry import LineString, Point, Polygon
from shapely.ops import polylabel

from condor.model.scenes import Scene
from condor.moulds.lab import (
    AREA_RANGE, ARC_SEGMENTS, LabFamily, _fillet, _round_rect, _stadium, family_mould,
    random_posts,
)
from condor.moulds.mould import Mould

COMPOSITE = "composite"  # the source's and its moulds' family name
RIM_SHARE = 0.4  # the share of composite moulds whose posts follow a wall (`_rim_posts`)
TIP_SHARE = 0.35  # the share whose posts stand at the outline's tips (`_tip_posts`)
TIP_REACH = 0.5  # a tip post centres in the mould within this of its tip, in part widths
RIM_INSET = (0.08, 0.25)  # how far inside the wall they stand, in the parts' unit width
BAND_SHARE = 0.25  # the share of composite moulds that are a band round a hole of their shape
BAND_WIDTH = (0.2, 0.4)  # that band's width, in the parts' unit width


def _primitive(rng) -> Polygon:
    """One part of a composite outline, about a unit wide: a stadium, an ellipse, a rounded
    rectangle, a random convex polygon or a curved bar (an arc of 60-240 degrees, as a U, a
    crescent's or a serpentine's arm), scaled 0.6-1.4x and turned at random."""
    kind = int(rng.integers(5))
    if kind == 0:
        part = _stadium(rng.uniform(1.2, 5.0), 1.0)
    elif kind == 1:
        part = affinity.scale(Point(0, 0).buffer(0.5, quad_segs=ARC_SEGMENTS),
                              rng.uniform(1.0, 3.0), 1.0)
    elif kind == 2:
        part = _round_rect(rng.uniform(1.0, 4.0), 1.0, rng.uniform(0.0, 0.3))
    elif kind == 4:
        radius = rng.uniform(0.8, 2.0)
        sweep = np.deg2rad(rng.uniform(60, 240))
        t = np.linspace(-sweep / 2, sweep / 2, 48)
        arc = LineString(np.stack([radius * np.cos(t), radius * np.sin(t)], 1))
        part = arc.buffer(0.5, quad_segs=ARC_SEGMENTS)
        part = affinity.translate(part, -part.centroid.x, -part.centroid.y)
    else:
        angles = np.sort(rng.uniform(0, 2 * np.pi, int(rng.integers(3, 8))))
        radii = 0.5 * rng.uniform(0.6, 1.0, len(angles))
        part = Polygon(np.stack([radii * np.cos(angles), radii * np.sin(angles)], 1)).convex_hull
        part = affinity.translate(part, -part.centroid.x, -part.centroid.y)
    size = rng.uniform(0.6, 1.4)
    return affinity.rotate(affinity.scale(part, size, size, origin=(0, 0)), rng.uniform(0, 180),
                           origin=(0, 0))


def _draw(rng):
    """A union of 1-3 random parts (each joined at a point of the outline so far), concave
    corners rounded; a quarter of them a band round a hole of the outline's own shape (a frame
    or an annulus of any outline), a third of the rest with 1-3 small holes; 1-8 posts inside:
    RIM_SHARE of the time along one wall (`_rim_posts`; a band's on its midline), TIP_SHARE at
    the outline's tips (`_tip_posts`), else (or where those find no place) spread apart or
    placed at random. Not a shape labs cast, but one that varies what they vary (the number and
    placement of posts, holes, narrow bands, elongation, joints) so that a surrogate trained on
    it meets fewer moulds unlike anything it saw."""
    parts = [_primitive(rng)]  # each part holds its centre: a joint joins the union
    for _ in range(int(rng.integers(0, 3))):
        joint = parts[int(rng.integers(len(parts)))].exterior.interpolate(rng.uniform(0, 1),
                                                                          normalized=True)
        parts.append(affinity.translate(_primitive(rng), joint.x, joint.y))
    outline = _fillet(shapely.union_all(parts), 0.1)
    if outline.geom_type != "Polygon":
        return outline, np.zeros((0, 2)), {}  # refused by _attempt: drawn again
    band = None
    if rng.random() < BAND_SHARE:
        band = rng.uniform(*BAND_WIDTH)
        hole = outline.buffer(-band).buffer(-0.05).buffer(0.05)
        ring = outline.difference(hole) if hole.geom_type == "Polygon" else None
        # a band whose every neck is near its width: no pinch where the parts join
        if ring is not None and hole.area > 0.05 * outline.area and \
                ring.buffer(-0.45 * band).geom_type == "Polygon":
            outline = ring
        else:
            band = None
    elif rng.random() < 1 / 3:
        for _ in range(int(rng.integers(1, 4))):
            inner = outline.buffer(-0.3)
            if inner.is_empty:
                break
            centre = random_posts(rng, inner, 1, spread=False)[0]
            size = rng.uniform(0.15, 0.6)
            hole = affinity.rotate(affinity.translate(
                _round_rect(size * rng.uniform(1.0, 2.0), size, rng.uniform(0, 0.5) * size)
                if rng.random() < 0.5 else
                affinity.scale(Point(0, 0).buffer(size / 2, quad_segs=ARC_SEGMENTS),
                               rng.uniform(1.0, 2.0), 1.0), *centre), rng.uniform(0, 180))
            if outline.buffer(-0.08).contains(hole):
                outline = outline.difference(hole)
    n = int(rng.integers(1, 9))
    placement = rng.random()
    if placement < RIM_SHARE:
        posts = _rim_posts(rng, outline, n, None if band is None else band / 2)
        if posts is not None:
            return outline, posts, {"posts": n, "rim": 1}
    elif placement < RIM_SHARE + TIP_SHARE:
        posts = _tip_posts(outline, n)
        if posts is not None:
            return outline, posts, {"posts": len(posts), "tips": 1}
    return outline, random_posts(rng, outline, n, spread=rng.random() < 0.5), {"posts": n}


def _rim_posts(rng, outline: Polygon, n: int, inset: float | None = None):
    """n posts at equal arc spacing (a random phase) along one wall, `inset` inside it: the
    outer wall's inward offset or a hole's outward one, as labs anchor a strip along its sides,
    a frame in its bars, an annulus on its midline or a cross near its arms' ends. None when
    that offset leaves the mould (a hole's past the next wall): the caller places them
    elsewhere. `inset` None: drawn from RIM_INSET."""
    walls = [outline.exterior, *outline.interiors]
    k = int(rng.integers(len(walls)))
    inset = rng.uniform(*RIM_INSET) if inset is None else inset
    offset = Polygon(walls[k]).buffer(-inset if k == 0 else inset, quad_segs=ARC_SEGMENTS)
    if offset.geom_type != "Polygon" or offset.is_empty:
        return None
    phase = rng.uniform(0, 1)
    xy = shapely.get_coordinates(shapely.line_interpolate_point(
        offset.exterior, (phase + np.arange(n) / n) % 1.0, normalized=True))
    if not np.all(shapely.contains_xy(outline.buffer(-0.5 * inset), xy[:, 0], xy[:, 1])):
        return None
    return xy


def _tip_posts(outline: Polygon, n: int):
    """Up to n posts at the outline's tips, as labs anchor a strip, a dog-bone, a cross or a T
    at its arms' ends: the local maxima of the outer wall's distance from the outline's pole
    of inaccessibility (at least 1/8 of the wall apart, the farthest first), each post at the
    pole of the mould within TIP_REACH of the tip's middle (the middle of the arm's end). None when the
    outline has no tip (a disk) or a post would leave it: the caller places them elsewhere."""
    pole = polylabel(outline, 1e-3)
    ring = outline.exterior
    xy = shapely.get_coordinates(shapely.line_interpolate_point(
        ring, np.arange(256) / 256, normalized=True))
    d = np.hypot(xy[:, 0] - pole.x, xy[:, 1] - pole.y)
    window = 16  # a tip is the farthest point within 1/16 of the wall either side
    near = np.stack([np.roll(d, k) for k in range(-window, window + 1)])
    tips = np.flatnonzero((d >= near.max(axis=0)) & (d > 1.2 * d.min()))
    if not len(tips):
        return None
    chosen: list[int] = []
    for i in tips[np.argsort(-d[tips])]:
        if all(min(abs(i - j), 256 - abs(i - j)) >= 32 for j in chosen):
            chosen.append(int(i))
    posts = []
    for i in chosen[:n]:
        # the tip's middle: the mean of the wall's points near it that reach almost as far (a
        # flat end's whole edge, a round end's apex), so that a post centres across its arm
        near_tip = (i + np.arange(-window, window + 1)) % len(d)
        middle = xy[near_tip[d[near_tip] >= d[i] - 0.25 * TIP_REACH]].mean(axis=0)
        end = outline.intersection(Point(middle).buffer(TIP_REACH, quad_segs=ARC_SEGMENTS))
        if end.geom_type != "Polygon" or end.is_empty:
            return None
        p = polylabel(end, 1e-3)
        posts.append((p.x, p.y))
    posts = np.array(posts)
    if not np.all(shapely.contains_xy(outline.buffer(-0.1), posts[:, 0], posts[:, 1])):
        return None
    return posts


COMPOSITE_FAMILY = LabFamily(
    COMPOSITE, "a union of 1-3 random parts (stadiums, ellipses, rounded rectangles, convex "
    "polygons), a quarter a band round a hole of its shape, a quarter with 1-3 small holes, "
    "1-8 posts along a wall, at its tips, spread or at random",
    _draw,
    {"parts": (1, 3), "part aspect": (1.0, 5.0), "part size": (0.6, 1.4), "holes": (0, 3),
     "hole size / part width": (0.15, 0.6), "posts": (1, 8), "post radius": (0.015, 0.07),
     "rim post inset / part width": RIM_INSET, "band / part width": BAND_WIDTH,
     "tip post reach / part width": (0, TIP_REACH)})


def composite_mould(seed: int, mould_id: int, scene: Scene,
                    area_range: tuple[float, float] = AREA_RANGE) -> Mould:
    """Composite mould `mould_id` of dataset `seed` in `scene`'s box, checked against the mould
    contract."""
    return family_mould(seed, mould_id, COMPOSITE_FAMILY, scene, area_range)
