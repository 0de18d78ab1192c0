"""Kinds of mould that no source of condor draws: neither the paper's generator, nor a lab
family (condor.moulds.lab), nor the composite source. A stand-in for the lab moulds nobody here
has seen (issue 41): T, L, Y, H and U shapes, stars, crescents, serpentine strips, triangles
with a hole, hexagons round a central post and twin-hole stadiums, each with its posts where a
lab would put them (at arm ends, corners or horns).

`unseen_mould(kind, variant, box)` -> (outline Polygon with holes, posts (n, 3): x, y, r), in
l0, centred in a box of side `box`; a pure function of (kind, variant). The area is drawn in
0.22-0.45 of the box's, the larger side at most 0.85 of the box, the post radius 0.03-0.05 of
the box. Kept out of src/: a test set, not a training source.
"""

from __future__ import annotations

import numpy as np
from shapely import affinity
from shapely.geometry import LineString, Point, Polygon, box as rect
from shapely.ops import polylabel, unary_union

SEED = 4141  # the kinds' own stream: default_rng([SEED, kind index, variant])
ARC = 16


def _bar(p, q, w):
    return LineString([p, q]).buffer(w / 2, cap_style="flat", join_style="mitre")


def _t(rng):
    w = rng.uniform(0.32, 0.45)
    stem = rng.uniform(0.7, 1.1)
    shape = unary_union([_bar((-1, 0), (1, 0), w), _bar((0, 0), (0, -stem), w)])
    return shape, [(-1 + w / 2, 0), (1 - w / 2, 0), (0, -stem + w / 2)]


def _l(rng):
    w = rng.uniform(0.25, 0.4)
    a, b = rng.uniform(0.9, 1.3), rng.uniform(0.6, 1.1)
    shape = unary_union([_bar((0, 0), (a, 0), w), _bar((0, -w / 2), (0, b), w)])
    return shape, [(a - w / 2, 0), (0, b - w / 2)]


def _y(rng):
    w = rng.uniform(0.32, 0.42)
    arms = [_bar((0, 0), (np.cos(t), np.sin(t)), w) for t in np.deg2rad([90, 210, 330])]
    ends = [((1 - w / 2) * np.cos(t), (1 - w / 2) * np.sin(t)) for t in np.deg2rad([90, 210, 330])]
    return unary_union(arms + [Point(0, 0).buffer(w * 0.6, quad_segs=ARC)]), ends


def _h(rng):
    w = rng.uniform(0.3, 0.4)
    half = rng.uniform(0.7, 1.0)
    gap = rng.uniform(0.8, 1.2)
    parts = [_bar((-gap / 2, -half), (-gap / 2, half), w), _bar((gap / 2, -half), (gap / 2, half), w),
             _bar((-gap / 2, 0), (gap / 2, 0), w * rng.uniform(0.7, 1.0))]
    posts = [(sx * gap / 2, sy * (half - w / 2)) for sx in (-1, 1) for sy in (-1, 1)]
    return unary_union(parts), posts


def _u(rng):
    w = rng.uniform(0.22, 0.32)
    r = rng.uniform(0.45, 0.65)
    arm = rng.uniform(0.5, 0.9)
    bend = Point(0, 0).buffer(r + w / 2, quad_segs=ARC).difference(
        Point(0, 0).buffer(r - w / 2, quad_segs=ARC)).intersection(rect(-2, -2, 2, 0))
    shape = unary_union([bend, _bar((-r, 0), (-r, arm), w), _bar((r, 0), (r, arm), w)])
    posts = [(-r, arm - w / 2), (r, arm - w / 2)]
    if rng.uniform() < 0.5:
        posts.append((0, -r))
    return shape, posts


def _star(rng):
    n = int(rng.integers(5, 7))
    inner = rng.uniform(0.5, 0.62)
    t = np.arange(2 * n) * np.pi / n + np.pi / 2
    rad = np.where(np.arange(2 * n) % 2 == 0, 1.0, inner)
    shape = Polygon(np.stack([rad * np.cos(t), rad * np.sin(t)], 1))
    shape = shape.buffer(0.06, quad_segs=ARC).buffer(-0.06, quad_segs=ARC)
    tips = [(0.72 * np.cos(a), 0.72 * np.sin(a)) for a in t[::2]]
    return shape, tips


def _crescent(rng):
    off = rng.uniform(0.35, 0.55)
    r2 = rng.uniform(0.85, 1.0)
    shape = Point(0, 0).buffer(1, quad_segs=ARC).difference(Point(off, 0).buffer(r2, quad_segs=ARC))
    shape = shape.buffer(-0.05).buffer(0.05)
    if shape.geom_type != "Polygon":
        shape = max(shape.geoms, key=lambda g: g.area)
    horns = [polylabel(shape.intersection(rect(-0.3, 0, 2, 2)), 1e-3),
             polylabel(shape.intersection(rect(-0.3, -2, 2, 0)), 1e-3)]
    posts = [(p.x, p.y) for p in horns] + [(-0.75, 0.0)]
    return shape, posts[: 2 + int(rng.integers(2))]


def _serpentine(rng):
    w = rng.uniform(0.3, 0.4)
    amp = rng.uniform(0.3, 0.5)
    x = np.linspace(-1, 1, 60)
    y = amp * np.sin(np.pi * x * rng.choice([1.0, 1.5]))
    shape = LineString(np.stack([x, y], 1)).buffer(w / 2, cap_style="round", quad_segs=ARC)
    return shape, [(x[2], y[2]), (x[-3], y[-3])]


def _triangle_frame(rng):
    t = np.deg2rad([90, 210, 330])
    outer = Polygon(np.stack([np.cos(t), np.sin(t)], 1)).buffer(0.15, quad_segs=ARC).buffer(-0.15)
    hole = rng.uniform(0.3, 0.45)
    inner = Polygon(np.stack([hole * np.cos(t), hole * np.sin(t)], 1))
    shape = outer.difference(inner.buffer(0.05, quad_segs=ARC))
    return shape, [(0.62 * np.cos(a), 0.62 * np.sin(a)) for a in t]


def _hexagon_post(rng):
    t = np.arange(6) * np.pi / 3
    shape = Polygon(np.stack([np.cos(t), np.sin(t)], 1))
    posts = [(0.0, 0.0)]
    if rng.uniform() < 0.5:
        posts += [(0.7 * np.cos(a), 0.7 * np.sin(a)) for a in t[::2]]
    return shape, posts


def _twin_holes(rng):
    length = rng.uniform(1.6, 2.2)
    shape = LineString([(-length / 2, 0), (length / 2, 0)]).buffer(0.5, quad_segs=ARC)
    hr = rng.uniform(0.18, 0.26)
    holes = [Point(sx * length / 4, 0).buffer(hr, quad_segs=ARC) for sx in (-1, 1)]
    shape = shape.difference(unary_union(holes))
    return shape, [(-length / 2 - 0.15, 0), (length / 2 + 0.15, 0)]


KINDS = {"tee": _t, "ell": _l, "wye": _y, "aitch": _h, "you": _u, "star": _star,
         "crescent": _crescent, "serpentine": _serpentine, "triangle_frame": _triangle_frame,
         "hexagon_post": _hexagon_post, "twin_holes": _twin_holes}


def unseen_mould(kind: str, variant: int, box: float):
    """(outline, posts) of one mould of `kind` in a box of side `box` (l0)."""
    rng = np.random.default_rng([SEED, list(KINDS).index(kind), variant])
    shape, anchors = KINDS[kind](rng)
    angle = rng.uniform(0, 360)
    anchors = np.asarray(anchors, dtype=float)
    area_share = rng.uniform(0.22, 0.45)
    scale = np.sqrt(area_share * box * box / shape.area)
    minx, miny, maxx, maxy = affinity.rotate(shape, angle, origin=(0, 0)).bounds
    scale = min(scale, 0.85 * box / max(maxx - minx, maxy - miny))
    shape = affinity.rotate(affinity.scale(shape, scale, scale, origin=(0, 0)), angle, origin=(0, 0))
    c = np.deg2rad(angle)
    rot = np.array([[np.cos(c), -np.sin(c)], [np.sin(c), np.cos(c)]])
    pts = (anchors * scale) @ rot.T
    cx, cy = (shape.bounds[0] + shape.bounds[2]) / 2, (shape.bounds[1] + shape.bounds[3]) / 2
    shape = affinity.translate(shape, box / 2 - cx, box / 2 - cy)
    pts = pts + [box / 2 - cx, box / 2 - cy]
    radius = rng.uniform(0.03, 0.05) * box
    posts = []
    for x, y in pts:  # shrink a post until it sits inside with a margin
        r = radius
        while r > 0.3 and not shape.buffer(-0.2).contains(Point(x, y).buffer(r)):
            r *= 0.9
        posts.append((x, y, r))
    return shape, np.asarray(posts)
