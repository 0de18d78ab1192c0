"""Reading an SVG drawing (svgelements): its rings and circles, and the units its root
states (data-units, or an absolute width and height over the viewBox)."""

from __future__ import annotations

import io
import math
import re
from pathlib import Path
from xml.etree import ElementTree

import numpy as np
import svgelements

from condor.moulds.mould import DrawingError, InvalidMouldError
from condor.moulds.shapes import (FLATTEN_TOLERANCE_L0, HOLE_CLASS, Circle, Drawing, Ring,
                                  Shapes, drop_closing_point, finish_drawing, flatten_curve,
                                  sort_rings)
from condor.moulds.units import l0_per_unit, resolve_units

SVG_MM_PER_PX = 25.4 / 96  # CSS: 96 px per inch


_CSS_MM = {"mm": 1.0, "cm": 10.0, "q": 0.25, "in": 25.4, "pt": 25.4 / 72, "pc": 25.4 / 6,
           "px": SVG_MM_PER_PX}  # CSS absolute units in mm


_CSS_LENGTH = re.compile(r"^\s*([-+]?(?:\d+\.?\d*|\.\d+)(?:[eE][-+]?\d+)?)\s*([a-zA-Z%]*)\s*$")


def _css_length(value: str | None) -> tuple[float, str] | None:
    """(number, unit) of a CSS length ("" for a bare number); None if absent or unparsable."""
    match = _CSS_LENGTH.match(value) if isinstance(value, str) else None
    return (float(match.group(1)), match.group(2).lower()) if match else None


def _svg_root(path: Path):
    """The SVG's root attributes that fix its units, and the document without width, height
    and viewBox, so that svgelements returns root user units exactly (it converts to px with
    a rounded mm constant otherwise)."""
    try:
        tree = ElementTree.parse(path)
    except ElementTree.ParseError as error:
        raise DrawingError(f"{path} is not a readable SVG (XML): {error}") from error
    root = tree.getroot()
    if not root.tag.endswith("svg"):
        raise DrawingError(f"{path}: the root element is <{root.tag}>, not <svg>")
    attrs = {key: root.attrib.pop(key, None) for key in ("width", "height", "viewBox")}
    attrs["data-units"] = root.attrib.get("data-units")
    attrs["preserveAspectRatio"] = root.attrib.get("preserveAspectRatio", "")
    buffer = io.BytesIO()
    tree.write(buffer)
    buffer.seek(0)
    return attrs, buffer


def _svg_mm_per_user_unit(attrs: dict, source: str) -> tuple[float, bool]:
    """(mm per root user unit, whether width/height state an absolute CSS unit).

    The viewBox maps onto width x height ("meet": the smaller scale, "slice": the larger);
    lengths without a unit are CSS px, percentages say nothing. Without a viewBox, or
    without a usable width and height, a user unit is a CSS px (1/96 in)."""
    sizes = {key: _css_length(attrs[key]) for key in ("width", "height")}
    stated = any(size is not None and size[1] in _CSS_MM for size in sizes.values())
    sizes_mm = {key: size[0] * _CSS_MM.get(size[1] or "px", 0.0)
                for key, size in sizes.items() if size is not None and size[1] != "%"}
    box = None
    if attrs["viewBox"]:
        try:
            box = [float(v) for v in attrs["viewBox"].replace(",", " ").split()]
        except ValueError:
            box = None
        if box is None or len(box) != 4 or box[2] <= 0 or box[3] <= 0:
            raise DrawingError(f"{source}: viewBox {attrs['viewBox']!r} is not four numbers "
                               "with positive width and height")
    if box is None or not sizes_mm:
        return SVG_MM_PER_PX, stated
    scales = [sizes_mm[key] / box[k] for key, k in (("width", 2), ("height", 3))
              if key in sizes_mm and sizes_mm[key] > 0]
    if not scales:
        return SVG_MM_PER_PX, stated
    aspect = attrs["preserveAspectRatio"].split()
    if aspect and aspect[0] == "none" and not math.isclose(min(scales), max(scales),
                                                           rel_tol=1e-9):
        raise DrawingError(f"{source}: preserveAspectRatio=\"none\" stretches the drawing "
                           "unequally in x and y; draw it at a uniform scale")
    return (max(scales) if "slice" in aspect else min(scales)), stated


def read_svg(path: Path, units: str | None, l0_um: float | None) -> Drawing:
    """Rings and circles of an SVG drawing (svgelements resolves transforms, <use>, nested
    <svg> and styles; display:none elements are skipped).

    Units: a root attribute data-units="l0" | "mm" | "um" says what one user unit is;
    otherwise a root width or height with an absolute CSS unit (mm, cm, q, in, pt, pc, px)
    makes the drawing physical, the viewBox mapping user units onto that size; otherwise
    `units` says what one user unit is, and without it the CSS default applies (a user unit
    is a px, 1/96 in, and a bare width is in px)."""
    source = str(path)
    attrs, document = _svg_root(path)
    try:
        svg = svgelements.SVG.parse(document, reify=True, ppi=96.0)
    except Exception as error:  # svgelements raises bare parser errors of several kinds
        raise DrawingError(f"{path} is not a readable SVG: {type(error).__name__}: {error}") \
            from error
    mm_per_user, stated = _svg_mm_per_user_unit(attrs, source)
    declared = attrs["data-units"]
    if declared is not None or (units is not None and not stated):
        unit = resolve_units(declared.strip() if declared is not None else None, units,
                              source, "data-units on <svg>")
        per_user = 1e-3 if unit == "um" else 1.0  # drawing units (l0 or mm) per user unit
        label = unit
        how = f"data-units = {unit!r}" if declared is not None else f"--units {unit}"
    else:
        if units == "l0":
            raise DrawingError(f"{path} states a physical size (width {attrs['width']!r}, "
                               f"height {attrs['height']!r}); --units l0 contradicts it "
                               "(to draw in l0, set data-units=\"l0\" on <svg>)")
        unit, per_user = "mm", mm_per_user
        label = ("mm" if per_user == 1.0 else "user units") if stated else "CSS px"
        how = ("its width/height are physical lengths" if stated else
               f"it states no units, so it is read as CSS px, 96 px an inch, "
               f"{per_user:.4g} mm a user unit; if its numbers are mm or l0, set "
               "data-units=\"mm\" or \"l0\" on <svg> or pass --units mm or --units l0")
    unit = "l0" if unit == "l0" else "mm"
    tol = FLATTEN_TOLERANCE_L0 / (per_user * l0_per_unit(unit, l0_um, source, label, how))

    rings, circles, ignored, counts = [], [], 0, {}
    for element in svg.elements():
        if not isinstance(element, svgelements.Shape):
            ignored += isinstance(element, svgelements.Text)
            continue
        tag = type(element).__name__.lower()
        counts[tag] = counts.get(tag, 0) + 1
        name = (f'<{tag} id="{element.id}">' if element.id else
                f"<{tag}> number {counts[tag]} in document order")
        outline = abs(svgelements.Path(element))
        if isinstance(element, (svgelements.Circle, svgelements.Ellipse)):
            circle = _svg_circle(outline, name, source)
            circle.hole = _marked_hole(element)
            circles.append(circle)
            continue
        subpaths = list(outline.as_subpaths())
        for k, subpath in enumerate(subpaths):
            points, closed = _flatten_subpath(subpath, tol)
            ring = name if len(subpaths) == 1 else f"{name} subpath {k + 1}"
            if closed and len(points) >= 3:
                rings.append(Ring(ring, points))
            elif len(points):
                ignored += 1
    shell, holes, tethers = sort_rings(source, rings, circles, ignored, tol)
    shapes = Shapes(source, unit, label, shell=shell, holes=holes, circles=tethers)
    return finish_drawing(shapes, per_user, l0_um, flip_y=True, how=how)


def _marked_hole(element) -> bool:
    """Whether an SVG circle is drawn as a hole: class "hole" among its classes,
    data-condor="hole", or an id starting with "hole"."""
    values = getattr(element, "values", {}) or {}
    classes = str(values.get("class") or "").split()
    return (HOLE_CLASS in classes or str(values.get("data-condor") or "") == HOLE_CLASS
            or str(element.id or "").lower().startswith(HOLE_CLASS))


def _flatten_subpath(subpath, tol: float) -> tuple[np.ndarray, bool]:
    """Vertices (px) of one SVG subpath and whether it is closed (Z, or ends at its start)."""
    points, closed = [], False
    for segment in subpath:
        if isinstance(segment, svgelements.Move):
            points.append((segment.end.x, segment.end.y))
        elif isinstance(segment, svgelements.Close):
            closed = True
        elif isinstance(segment, svgelements.Line):
            points.append((segment.end.x, segment.end.y))
        elif segment.start is not None:  # Arc, QuadraticBezier, CubicBezier
            points.extend(map(tuple, flatten_curve(segment.npoint, tol)[1:]))
    points = np.asarray(points, dtype=np.float64).reshape(-1, 2)
    if len(points) > 2 and np.hypot(*(points[-1] - points[0])) <= tol:
        closed = True
    if closed:
        points = drop_closing_point(points, tol)
    return points, closed


def _svg_circle(outline, name: str, source: str) -> Circle:
    """A <circle> or <ellipse> after its transforms (user units); it must be round."""
    samples = [segment.npoint(np.linspace(0, 1, 16, endpoint=False)) for segment in outline
               if isinstance(segment, (svgelements.Arc, svgelements.CubicBezier,
                                       svgelements.QuadraticBezier, svgelements.Line))]
    if not samples:
        raise InvalidMouldError(f"{source}: {name} has zero size; a tether needs a positive "
                                "radius")
    points = np.concatenate(samples)
    centre = points.mean(axis=0)  # the sample set is symmetric about the centre
    radii = np.hypot(*(points - centre).T)
    radius = float(radii.mean())
    if radii.max() - radii.min() > max(1e-6 * radius, 1e-12):
        raise InvalidMouldError(f"{source}: {name} is an ellipse (radii {radii.min():.4g} to "
                                f"{radii.max():.4g}), not a circle: tethers are circles")
    return Circle(name, float(centre[0]), float(centre[1]), radius)
