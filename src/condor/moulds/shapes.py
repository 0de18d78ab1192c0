"""A drawing's shapes as its readers find them (rings, circles, in the file's own units and
axes) and what every reader shares to make them a `Drawing`: the outline, its holes and its
tethers in l0, y up, checked in the file's own coordinates (`finish_drawing`), and which
closed shape is the outline (`sort_rings`)."""

from __future__ import annotations

import math
import re
from dataclasses import dataclass

import numpy as np
import shapely
from shapely import affinity
from shapely.geometry import Polygon
from shapely.geometry.polygon import orient

from condor.moulds.mould import DrawingError, InvalidMouldError
from condor.moulds.units import l0_per_unit

FLATTEN_TOLERANCE_L0 = 0.01  # curves become chords with sagitta at most this (l0)


@dataclass(frozen=True)
class Drawing:
    """A drawing's outline and tethers in l0, y up, not yet placed in a box."""

    source: str
    polygon: Polygon
    tethers: np.ndarray  # (n, 3): x, y, radius, l0
    units: str  # what the file was drawn in: "l0" or "mm"
    reading: str = ""  # how its units were read, for the user: "CSS px (it states no ...)"


@dataclass
class Ring:
    name: str  # how the file names it, for messages
    points: np.ndarray  # (k, 2) drawing units, the file's axes


@dataclass
class Circle:
    name: str
    x: float
    y: float
    r: float
    hole: bool = False  # drawn as a hole by the file's convention (HOLE_LAYERS, HOLE_CLASS)


# A circle is a hole, not a post, on a DXF layer of one of these names (any case), or, in an
# SVG, with class "hole" (among its classes), data-condor="hole" or an id starting "hole".
HOLE_LAYERS = ("hole", "holes")
HOLE_CLASS = "hole"
HOW_TO_DRAW_A_HOLE = ("draw a hole as a closed polyline (a DXF LWPOLYLINE, an SVG path, "
                      "polygon or rect), or as a circle on a DXF layer named HOLES or an SVG "
                      "circle with class=\"hole\"")


@dataclass
class Shapes:
    """What a file holds, in drawing units ("l0" or "mm" after a factor), the file's axes."""

    source: str
    unit: str  # "l0" or "mm": what the coordinates become after the reader's factor
    label: str  # the file's own coordinate unit, for messages ("l0", "um", "user units")
    shell: Ring
    holes: list
    circles: list


def drop_closing_point(points: np.ndarray, tol: float) -> np.ndarray:
    if len(points) > 1 and np.hypot(*(points[-1] - points[0])) <= tol:
        return points[:-1]
    return points


def _ring_polygon(ring: Ring, source: str, label: str) -> Polygon:
    polygon = Polygon(ring.points)
    if not polygon.is_valid:
        raise InvalidMouldError(f"{source}: {ring.name} is {_invalid(polygon, label)}")
    if polygon.area <= 0:
        raise InvalidMouldError(f"{source}: {ring.name} encloses no area")
    return polygon


def _invalid(polygon: Polygon, label: str) -> str:
    """Why shapely finds `polygon` invalid, located in the file's coordinates."""
    reason = shapely.is_valid_reason(polygon)
    match = re.match(r"(.*)\[(\S+) (\S+)\]$", reason)
    if not match:
        return f"invalid ({reason})"
    what = "self-intersecting" if match.group(1) == "Self-intersection" else \
        f"invalid ({match.group(1)})"
    x, y = float(match.group(2)), float(match.group(3))
    return f"{what} at ({x:.4g}, {y:.4g}) {label} in the file's coordinates"


def finish_drawing(shapes: Shapes, mm_per_unit: float, l0_um, flip_y: bool, how: str) -> Drawing:
    """Outline, holes and tethers checked in the file's own coordinates, then in l0, y up."""
    source, unit, label = shapes.source, shapes.unit, shapes.label
    shell = _ring_polygon(shapes.shell, source, label)
    holes = [_ring_polygon(h, source, label) for h in shapes.holes]
    for hole, ring in zip(holes, shapes.holes):
        if not shell.contains(hole):
            raise InvalidMouldError(f"{source}: {ring.name} is not inside {shapes.shell.name}")
    polygon = Polygon(shell.exterior.coords, [h.exterior.coords for h in holes])
    if not polygon.is_valid:
        raise InvalidMouldError(f"{source}: the outline with its holes is "
                                f"{_invalid(polygon, label)}")
    tethers = np.array([[c.x, c.y, c.r] for c in shapes.circles]).reshape(-1, 3)
    names = [c.name for c in shapes.circles]
    slack = 1e-9 * max(np.ptp(np.asarray(shell.exterior.coords), axis=0))
    for (x, y, r), name in zip(tethers, names):
        if not r > 0:
            raise InvalidMouldError(f"{source}: {name} has radius {r:g}; a tether needs a "
                                    "positive radius")
        inside = polygon.contains(shapely.Point(x, y))
        wall = polygon.boundary.distance(shapely.Point(x, y))
        if not inside or wall < r - slack:
            where = "outside the outline" if not inside else \
                f"crossing the outline ({wall:.4g} {label} from the wall, radius {r:.4g})"
            raise InvalidMouldError(f"{source}: {name} at ({x:.4g}, {y:.4g}) {label} is "
                                    f"{where}: a tether must lie fully inside the mould")
    for i in range(len(tethers)):
        for j in range(i + 1, len(tethers)):
            gap = np.hypot(*(tethers[i, :2] - tethers[j, :2])) - tethers[i, 2] - tethers[j, 2]
            if gap < -slack:
                raise InvalidMouldError(f"{source}: {names[i]} and {names[j]} overlap "
                                        f"(by {-gap:.4g} {label}); tethers must be apart")
    scale = mm_per_unit * l0_per_unit(unit, l0_um, source, label, how)
    sign = -1.0 if flip_y else 1.0
    polygon = orient(affinity.scale(polygon, scale, sign * scale, origin=(0, 0)))
    tethers = tethers * [scale, sign * scale, scale]
    return Drawing(source=source, polygon=polygon, tethers=tethers, units=unit,
                   reading=f"{label} ({how})")


def sort_rings(source: str, rings: list, circles: list, ignored: int, tol: float) -> tuple:
    """(outline ring, hole rings, tether circles) of a drawing's closed shapes.

    The outline is the one closed shape that lies inside no other; closed shapes inside it
    are holes; circles are tethers, except those marked as holes (`Circle.hole`: a DXF layer
    HOLES, an SVG class "hole"), which are holes. With no closed shape but circles, a circle
    enclosing every other circle is the outline (a round mould)."""
    hole_rings = [_circle_ring(c, tol) for c in circles if c.hole]
    circles = [c for c in circles if not c.hole]
    if not rings:
        enclosing = [c for c in circles if all(
            c is d or math.hypot(c.x - d.x, c.y - d.y) + d.r < c.r for d in circles)]
        if len(enclosing) == 1:
            outer = enclosing[0]
            return _circle_ring(outer, tol), hole_rings, [c for c in circles if c is not outer]
        raise DrawingError(f"{source} has no closed outline (a closed path, polygon or rect); "
                           f"found {len(circles)} circle(s) (tethers) and {ignored} open or "
                           "other element(s), which are ignored")
    rings = rings + hole_rings
    polygons = [Polygon(r.points).buffer(0) for r in rings]  # containment of a repaired copy
    inside = [[i != j and polygons[j].contains(polygons[i]) for j in range(len(rings))]
              for i in range(len(rings))]
    top = [i for i in range(len(rings)) if not any(inside[i])]
    if not top:  # every ring inside another: coincident duplicates
        raise DrawingError(f"{source}: the closed shapes {', '.join(r.name for r in rings)} "
                           "coincide; keep exactly one outline")
    if len(top) > 1:
        names = ", ".join(rings[i].name for i in top)
        raise DrawingError(f"{source} has {len(top)} closed shapes that could each be the "
                           f"outline: {names}; keep exactly one (closed shapes inside it are "
                           "holes; annotations belong in open paths, lines or text)")
    holes = []
    for i, ring in enumerate(rings):
        if i != top[0]:
            if sum(inside[i]) > 1:
                raise DrawingError(f"{source}: {ring.name} lies inside a hole of the outline; "
                                   "islands inside holes are not supported")
            holes.append(ring)
    return rings[top[0]], holes, circles


def _circle_ring(circle: Circle, tol: float) -> Ring:
    """A circle as a polygon whose chords have sagitta at most `tol` (vertices on it)."""
    r = circle.r
    n = max(16, math.ceil(math.pi / math.acos(max(-1.0, 1 - tol / r))))
    n = 4 * math.ceil(n / 4)  # symmetric about both axes: its bounding box is the circle's
    angle = np.linspace(0, 2 * math.pi, n, endpoint=False)
    return Ring(circle.name, np.column_stack([circle.x + r * np.cos(angle),
                                               circle.y + r * np.sin(angle)]))


def flatten_curve(npoint, tol: float, max_pieces: int = 4096) -> np.ndarray:
    """Points along a curve (npoint: array of t in [0, 1] -> (k, 2)), ends included, such
    that each chord's sagitta, measured at the piece's parametric midpoint, is <= tol."""
    pieces = 4
    while True:
        t = np.linspace(0.0, 1.0, 2 * pieces + 1)
        points = np.asarray(npoint(t), dtype=np.float64)
        chord_mid = 0.5 * (points[0:-2:2] + points[2::2])
        sagitta = np.hypot(*(points[1::2] - chord_mid).T).max()
        if sagitta <= tol or pieces >= max_pieces:
            return points[::2]
        pieces *= 2
