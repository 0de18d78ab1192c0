"""A user's own mould: read it from a file, place it in a scene, check it against the
training domain, and write it back as a drawing (SVG, DXF) with dimensions.

`load_mould(path, scene, l0_um=None, fit=False, units=None)` accepts

- the generator's mould JSON (`condor.data.moulds.save_json`; validated as before);
- a minimal JSON: {"outline": [[x, y], ...], "holes": [[[x, y], ...], ...],
  "tethers": [[x, y, r], ...], "units": "l0" | "mm" | "um"} (holes and tethers optional);
- an SVG drawing (read with svgelements) or a DXF drawing (read with ezdxf): exactly one
  closed shape is the outline, closed shapes inside it are holes, circles are tethers.

Drawings in mm (or um) need the cell spacing `l0_um` (micrometres) to become l0. The
drawing keeps its size and is centred in the scene's box; `fit="extent"` scales it to the
window, `fit="area"` (or True) to the training moulds' area instead (`load_placement`
returns the scale factor). docs/user_moulds.md states every rule; the module's
constants are their one home.
"""

from __future__ import annotations

import io
import json
import math
import numbers
import re
from dataclasses import dataclass, replace
from pathlib import Path
from xml.etree import ElementTree
from xml.sax.saxutils import escape

import ezdxf
import numpy as np
import shapely
import svgelements
from ezdxf import edgeminer, edgesmith
from ezdxf import path as dxfpath
from ezdxf import units as dxfunits
from shapely import affinity
from shapely.geometry import Polygon
from shapely.geometry.polygon import orient

from condor.data.moulds import InvalidMouldError, Mould, load_json, validate_mould
from condor.model.scenes import Scene, same_length

UNITS = ("l0", "mm", "um")  # units a drawing may be in (um is read as mm / 1000)
FLATTEN_TOLERANCE_L0 = 0.01  # curves become chords with sagitta at most this (l0)
SVG_MM_PER_PX = 25.4 / 96  # CSS: 96 px per inch
DXF_UNITS_PROPERTY = "condor_units"  # DXF custom header property naming a drawing's units

# Training domain of the surrogate (generated moulds): area = scene.area_fraction of the
# box exactly, extent <= scene.max_extent, 0 or >= 4 tethers, and tether radii within
# TRAINING_TETHER_RADIUS box sides: the smallest and largest over 4,300 generated moulds
# (generate_mould(s, i, box=1.0), s = 1, 2 with i < 2000 and s = 11 with i < 300) were
# 0.0074 and 0.0539, rounded outwards here.
AREA_WARN = 0.10  # relative deviation of the area from the training area that warns
AREA_REFUSE = 0.50  # ... that refuses a prediction
TRAINING_MIN_TETHERS = 4
TRAINING_TETHER_RADIUS = (0.007, 0.06)  # box sides


class DrawingError(InvalidMouldError):
    """A mould file that cannot be read as a mould: format, units, which shape is what."""


class OutsideTrainingDomainError(InvalidMouldError):
    """A mould too far from the generated moulds for a surrogate's prediction to mean much."""


# --------------------------------------------------------------------------- the entry point


def load_mould(path, scene: Scene, l0_um: float | None = None, fit=False,
               units: str | None = None) -> Mould:
    """The mould in `path` (.json, .svg or .dxf), placed in `scene`'s box (lengths in l0).

    l0_um: the cell spacing l0 in micrometres; required for a drawing in mm or um.
    fit: False keeps the drawn size; "extent" scales the drawing, keeping its aspect
        ratio, so that its larger side is scene.max_extent of the box; "area" (or True)
        so that its area is the training moulds' (scene.area_fraction of the box), capped
        by the extent fit. `load_placement` also returns the scale factor.
    units: "l0", "mm" or "um", for a file that does not state its units (a minimal JSON
        without "units", a DXF with $INSUNITS = 0, an SVG whose root has neither
        data-units nor an absolute width/height); a file that states other units is an
        error.

    Raises DrawingError (unreadable file, no or several outlines, missing units or l0_um)
    or InvalidMouldError (a mould that does not fit: too large, tether outside the
    outline, overlapping tethers, self-intersecting outline, narrower than a cell, ...),
    both ValueErrors whose message names the file and the bad value. OSError if the file
    cannot be read.
    """
    return load_placement(path, scene, l0_um=l0_um, fit=fit, units=units).mould


def load_placement(path, scene: Scene, l0_um: float | None = None, fit=False,
                   units: str | None = None, data=None) -> Placement:
    """As load_mould, with how the mould was placed: its scale factor (`Placement.scale`),
    the fit mode and the drawn size (for printing and recording)."""
    path = Path(path)
    _check_arguments(l0_um, units)
    if data is None and path.suffix.lower() == ".json":
        data = _read_json(path)
    if isinstance(data, dict) and "polygon" in data:
        return _mould_json(path, scene, fit, units, l0_um)
    drawing = _read_drawing(path, l0_um, units, data)
    placement = place(drawing.polygon, drawing.tethers, scene, fit=fit, l0_um=l0_um,
                      source=str(path))
    return replace(placement, reading=drawing.reading)


@dataclass(frozen=True)
class Drawing:
    """A drawing's outline and tethers in l0, y up, not yet placed in a box."""

    source: str
    polygon: Polygon
    tethers: np.ndarray  # (n, 3): x, y, radius, l0
    units: str  # what the file was drawn in: "l0" or "mm"
    reading: str = ""  # how its units were read, for the user: "CSS px (it states no ...)"


def read_drawing(path, l0_um: float | None = None, units: str | None = None) -> Drawing:
    """The outline and tethers of a minimal JSON, SVG or DXF file, in l0 (not placed);
    arguments and errors as load_mould's."""
    _check_arguments(l0_um, units)
    return _read_drawing(Path(path), l0_um, units)


def _read_drawing(path: Path, l0_um, units, data=None) -> Drawing:
    suffix = path.suffix.lower()
    if suffix == ".json":
        return _outline_json(path, _read_json(path) if data is None else data, units, l0_um)
    if suffix == ".svg":
        return _read_svg(path, units, l0_um)
    if suffix == ".dxf":
        return _read_dxf(path, units, l0_um)
    raise DrawingError(f"{path}: unknown mould file type {suffix!r}; use .json (a mould or "
                       "an outline), .svg or .dxf")


def _check_arguments(l0_um, units) -> None:
    _check_l0_um(l0_um)
    if units is not None and units not in UNITS:
        raise DrawingError(f"--units {units!r}: choose one of {UNITS}")


# --------------------------------------------------------------------------- placement


FIT_MODES = ("area", "extent")  # --fit: the training moulds' area (capped by the window), or the window


@dataclass(frozen=True)
class Placement:
    """A drawing placed in a scene: the mould, and how it got there.

    scale: the factor the drawing was scaled by (1.0 when it keeps its size); fit: None,
    "area" or "extent"; drawn_l0: (width, height) of the drawing before scaling, l0;
    l0_um: the cell spacing used, if any (for lengths in mm)."""

    mould: Mould
    scale: float = 1.0
    fit: str | None = None
    drawn_l0: tuple[float, float] = (float("nan"), float("nan"))
    l0_um: float | None = None
    reading: str = "l0 (a mould file)"  # how the file's units were read

    def describe(self) -> str:
        """One line: how the units were read, the drawn and placed size, the scale factor."""
        return f"read in {self.reading}; {self._size_text()}"

    def _size_text(self) -> str:
        width, height = self.drawn_l0
        placed = f"{_both(width * self.scale, self.l0_um)} x {_both(height * self.scale, self.l0_um)}"
        if self.fit is None:
            return f"placed at its drawn size, {placed}"
        return (f"scaled by {self.scale:.4g} (--fit {self.fit}): drawn "
                f"{_both(width, self.l0_um)} x {_both(height, self.l0_um)}, placed {placed}")

    def record(self) -> dict:
        """JSON-safe attributes for an output's metadata."""
        return {"fit": self.fit or "none", "fit_scale": float(self.scale),
                "drawn_width_l0": float(self.drawn_l0[0]),
                "drawn_height_l0": float(self.drawn_l0[1]),
                "l0_um": None if self.l0_um is None else float(self.l0_um),
                "units_read": self.reading}


def window_text(scene: Scene, l0_um: float | None) -> str:
    """The scene's window: its box, and the training moulds' largest extent, in l0 and mm."""
    at = f" at l0 = {l0_um:g} um" if l0_um is not None else ""
    return (f"the {scene.name!r} scene's window is {_both(scene.box, l0_um)} square{at} "
            f"(training moulds span at most {_both(scene.max_extent * scene.box, l0_um)})")


def _fit_factor(polygon: Polygon, scene: Scene, fit: str) -> float:
    """The scale factor of a fit: "extent" makes the larger of width and height
    scene.max_extent of the box (the training moulds' largest); "area" makes the area
    scene.area_fraction of the box, capped by the extent fit so that it always fits."""
    xmin, ymin, xmax, ymax = polygon.bounds
    extent = scene.max_extent * float(scene.box) / max(xmax - xmin, ymax - ymin)
    if fit == "extent":
        return extent
    return min(math.sqrt(scene.area_fraction * float(scene.box) ** 2 / polygon.area), extent)


def _fit_mode(fit) -> str | None:
    if fit is False or fit is None:
        return None
    if fit is True:
        return "area"
    if fit not in FIT_MODES:
        raise DrawingError(f"fit = {fit!r}: choose one of {FIT_MODES} (--fit area, --fit extent)")
    return fit


def place_mould(polygon: Polygon, tethers, scene: Scene, fit=False,
                l0_um: float | None = None, source: str = "mould") -> Mould:
    """A user mould in `scene`'s box from an outline and tethers in l0 (anywhere); see
    `place` (this returns its mould)."""
    return place(polygon, tethers, scene, fit=fit, l0_um=l0_um, source=source).mould


def place(polygon: Polygon, tethers, scene: Scene, fit=False, l0_um: float | None = None,
          source: str = "mould") -> Placement:
    """A user mould in `scene`'s box from an outline and tethers in l0 (anywhere).

    The placement rule: the drawing keeps its size (cells have size l0) and its bounding
    box is centred in the box, as the generator centres its moulds. `fit` scales it first,
    about that centre, keeping its aspect ratio: "extent" (the CLI's --fit extent) so that
    its larger side is scene.max_extent of the box; "area" or True (--fit) so that its
    area is scene.area_fraction of the box, the training moulds', but never beyond the
    extent fit. Without a fit it is refused (InvalidMouldError naming `source`, the
    window in l0 and mm, the scale it would need and the flags that give it) when its width
    or height exceeds the box; with one or without, when validate_mould refuses the placed
    mould. `l0_um` only adds mm to the messages."""
    mode = _fit_mode(fit)
    tethers = np.asarray(tethers, dtype=np.float64).reshape(-1, 3)
    box = float(scene.box)
    if not isinstance(polygon, Polygon) or polygon.is_empty or not polygon.area > 0:
        raise InvalidMouldError(f"{source}: the outline must be a Polygon with positive area, "
                                f"got {getattr(polygon, 'geom_type', type(polygon).__name__)}")
    xmin, ymin, xmax, ymax = polygon.bounds
    drawn = (xmax - xmin, ymax - ymin)
    factor = 1.0
    if mode is not None:
        factor = _fit_factor(polygon, scene, mode)
        centre = _bbox_centre(polygon)
        polygon = affinity.scale(polygon, factor, factor, origin=tuple(centre))
        tethers = np.column_stack([centre + (tethers[:, :2] - centre) * factor,
                                   tethers[:, 2] * factor])
    width, height = drawn[0] * factor, drawn[1] * factor
    if max(width, height) > box * (1 + 1e-9):
        raise InvalidMouldError(
            f"{source}: it is {_both(width, l0_um)} wide and {_both(height, l0_um)} high; "
            f"{window_text(scene, l0_um)}. {_way_forward(drawn, scene, l0_um)}")
    shift = np.array([box / 2, box / 2]) - _bbox_centre(polygon)
    polygon = affinity.translate(polygon, *shift)
    tethers = np.column_stack([tethers[:, :2] + shift, tethers[:, 2]])
    mould = Mould(box=box, polygon=polygon, tethers=tethers)
    try:
        validate_mould(mould)
    except InvalidMouldError as error:
        note = f" (l0 = {l0_um:g} um)" if l0_um is not None else ""
        scaled = f" (scaled by {factor:.4g}, --fit {mode})" if mode is not None else ""
        raise InvalidMouldError(f"{source}{note}{scaled}: {error}") from error
    return Placement(mould=mould, scale=float(factor), fit=mode,
                     drawn_l0=(float(drawn[0]), float(drawn[1])), l0_um=l0_um)


def _way_forward(drawn, scene: Scene, l0_um: float | None) -> str:
    """What to do about a drawing larger than the scene's window: the scale that --fit
    extent would apply, the cell spacing at which it would fit, and a larger scene."""
    from condor.model.scenes import PRESETS

    side = max(drawn)
    scale = scene.max_extent * scene.box / side
    ways = [f"Way forward: --fit extent scales it by {scale:.4g} to {scene.max_extent:g} of "
            "the window (--fit: to the training moulds' area)"]
    if l0_um is not None:
        ways.append(f"or a cell spacing --l0-um {l0_um * side / (scene.max_extent * scene.box):.3g} "
                    "(or more) keeps its shape at fewer, larger cells")
    larger = [s for s in PRESETS.values() if s.box * scene.max_extent >= side and s.box > scene.box]
    if larger:
        best = min(larger, key=lambda s: s.box)
        ways.append(f"or --scene {best.name} (window {_both(best.box, l0_um)}) to simulate it "
                    "at its drawn size")
    else:
        biggest = max(PRESETS.values(), key=lambda s: s.box)
        ways.append(f"no scene holds it at its drawn size (the largest window, --scene "
                    f"{biggest.name}'s, is {_both(biggest.box, l0_um)})")
    return "; ".join(ways)


def _both(value_l0: float, l0_um: float | None) -> str:
    """A length in l0 and, given l0_um, in mm."""
    text = f"{value_l0:.4g} l0"
    return text + f" = {value_l0 * l0_um / 1000:.4g} mm" if l0_um is not None else text


def _bbox_centre(polygon) -> np.ndarray:
    xmin, ymin, xmax, ymax = polygon.bounds
    return np.array([0.5 * (xmin + xmax), 0.5 * (ymin + ymax)])


# --------------------------------------------------------------------------- training domain


def training_domain_check(mould: Mould, scene: Scene) -> list[str]:
    """Warnings for predicting `mould` with a surrogate trained on `scene`'s generated moulds.

    Generated moulds all have area exactly scene.area_fraction of the box, width and
    height at most scene.max_extent of it, 0 or at least TRAINING_MIN_TETHERS tethers, and
    tether radii within TRAINING_TETHER_RADIUS box sides. A mould whose area differs from
    the training area by more than AREA_WARN (relative) gets a warning; by more than
    AREA_REFUSE, OutsideTrainingDomainError (simulate it instead). Extent, tether count and
    radii outside the training ranges, and tethers too small to mark any pixel of the input
    grid, get warnings. Simulation needs no such check: the model holds for any mould.
    """
    box = float(scene.box)
    if not same_length(mould.box, box):
        raise OutsideTrainingDomainError(
            f"the mould is placed in a {mould.box:g} l0 box, the {scene.name!r} scene (and a "
            f"surrogate trained on it) has {box:g} l0")
    warnings = []
    fraction = mould.polygon.area / box**2
    deviation = fraction / scene.area_fraction - 1
    area = (f"its area is {fraction:.3g} of the box, the training moulds' is exactly "
            f"{scene.area_fraction:g} ({deviation:+.0%})")
    if abs(deviation) > AREA_REFUSE:
        raise OutsideTrainingDomainError(
            f"{area}, beyond the +-{AREA_REFUSE:.0%} a prediction is allowed: simulate it, or "
            "scale it with --fit")
    if abs(deviation) > AREA_WARN:
        warnings.append(f"{area}: the prediction extrapolates (more than +-{AREA_WARN:.0%})")
    xmin, ymin, xmax, ymax = mould.polygon.bounds
    extent = max(xmax - xmin, ymax - ymin) / box
    if extent > scene.max_extent * (1 + 1e-9):
        warnings.append(f"its width or height is {extent:.3g} of the box, the training moulds' "
                        f"is at most {scene.max_extent:g}")
    tethers = np.asarray(mould.tethers, dtype=float).reshape(-1, 3)
    if 0 < len(tethers) < TRAINING_MIN_TETHERS:
        warnings.append(f"it has {len(tethers)} tethers, the training moulds have none or at "
                        f"least {TRAINING_MIN_TETHERS}")
    low, high = (r * box for r in TRAINING_TETHER_RADIUS)
    odd = [i for i, r in enumerate(tethers[:, 2]) if not low <= r <= high]
    if odd:
        warnings.append(f"tether radii {_listing(tethers[odd, 2])} l0 (tethers {_listing(odd)}) "
                        f"are outside the training range {low:.3g}-{high:.3g} l0")
    hidden = _tethers_without_pixels(tethers, box, scene.pixels)
    if hidden:
        warnings.append(f"tethers {_listing(hidden)} cover no pixel centre of the "
                        f"{scene.pixels} px input grid: the surrogate cannot see them")
    return warnings


def _tethers_without_pixels(tethers: np.ndarray, box: float, pixels: int) -> list[int]:
    """Tethers whose disk holds no pixel centre (the rule of condor.data.moulds.input_channels)."""
    size = box / pixels
    hidden = []
    for i, (x, y, r) in enumerate(tethers):
        ix = np.arange(max(0, int((x - r) / size) - 1), min(pixels, int((x + r) / size) + 2))
        iy = np.arange(max(0, int((y - r) / size) - 1), min(pixels, int((y + r) / size) + 2))
        cx, cy = np.meshgrid((ix + 0.5) * size, (iy + 0.5) * size)
        if not ((cx - x) ** 2 + (cy - y) ** 2 < r * r).any():
            hidden.append(i)
    return hidden


def _listing(values, limit: int = 6) -> str:
    items = [f"{v:.3g}" if isinstance(v, float) else str(v) for v in list(values)[:limit]]
    return ", ".join(items) + (", ..." if len(values) > limit else "")


# --------------------------------------------------------------------------- units


def _check_l0_um(l0_um) -> None:
    if l0_um is None:
        return
    if isinstance(l0_um, bool) or not isinstance(l0_um, numbers.Real) \
            or not math.isfinite(l0_um) or l0_um <= 0:
        raise DrawingError(f"--l0-um {l0_um!r} must be a positive number of micrometres "
                           "(the cell spacing l0)")


def _l0_per_unit(unit: str, l0_um: float | None, source: str, label: str, how: str) -> float:
    """Length in l0 of one drawing unit ("l0" or "mm"); `label` is the file's own unit
    (meters, um, user units, ...) and `how` says where it came from, for the message."""
    if unit == "l0":
        return 1.0
    if l0_um is None:
        raise DrawingError(f"{source} is drawn in {label} ({how}): give the cell spacing l0 "
                           "in micrometres with --l0-um (e.g. --l0-um 16) to convert it to l0 "
                           "(or --units l0 if it is drawn in l0)")
    return 1000.0 / float(l0_um)


def _resolve_units(stated: str | None, given: str | None, source: str, where: str) -> str:
    """The drawing's unit: what the file states, else what the caller gives."""
    if stated is not None:
        if stated not in UNITS:
            raise DrawingError(f"{source}: {where} is {stated!r}; use one of {UNITS}")
        if given is not None and given != stated:
            raise DrawingError(f"{source} states its units ({where} = {stated!r}); "
                               f"--units {given!r} contradicts it")
        return stated
    if given is None:
        raise DrawingError(f"{source} does not state its units ({where}): state them in the "
                           f"file, or pass --units (one of {UNITS})")
    return given


# --------------------------------------------------------------------------- JSON


def _read_json(path: Path):
    text = path.read_text()
    try:
        return json.loads(text)
    except json.JSONDecodeError as error:
        raise DrawingError(f"{path} is not valid JSON: {error}") from error


def _mould_json(path: Path, scene: Scene, fit, units: str | None,
                l0_um: float | None = None) -> Placement:
    """A mould in the generator's format: already in l0 and in box coordinates (refitted
    only when a fit is asked for and would change it)."""
    if units not in (None, "l0"):
        raise DrawingError(f"{path} is a mould file, always in l0; --units {units!r} "
                           "contradicts it")
    mould = load_json(path)
    if not same_length(mould.box, scene.box):
        raise InvalidMouldError(
            f"{path} is a mould for a {mould.box:g} l0 box, the {scene.name!r} scene has "
            f"{scene.box:g} l0: pass the matching scene (--scene; a checkpoint trained on "
            "it for predict), or give its outline and tethers "
            "alone (a minimal JSON) to be placed")
    mode = _fit_mode(fit)
    if mode is not None and not math.isclose(_fit_factor(mould.polygon, scene, mode), 1.0,
                                             rel_tol=1e-6):
        return place(mould.polygon, mould.tethers, scene, fit=mode, l0_um=l0_um,
                     source=str(path))
    xmin, ymin, xmax, ymax = mould.polygon.bounds
    return Placement(mould=mould, drawn_l0=(xmax - xmin, ymax - ymin), l0_um=l0_um)


_OUTLINE_KEYS = ("outline", "holes", "tethers", "units", "comment")


def _outline_json(path: Path, data, units: str | None, l0_um: float | None) -> Drawing:
    """{"outline": [[x, y], ...], "holes": [...], "tethers": [[x, y, r], ...], "units": ...}"""
    source = str(path)
    if not isinstance(data, dict) or "outline" not in data:
        raise DrawingError(f"{path}: expected a mould (with 'polygon') or an outline (with "
                           "'outline', 'tethers', 'units'), got "
                           f"{sorted(data) if isinstance(data, dict) else type(data).__name__}")
    unknown = sorted(set(data) - set(_OUTLINE_KEYS))
    if unknown:
        raise DrawingError(f"{path}: unknown key(s) {unknown}; an outline file has "
                           f"{list(_OUTLINE_KEYS)}")
    unit = _resolve_units(data.get("units"), units, source, "'units'")
    shell = _points(data["outline"], 2, f"{path}: 'outline'")
    holes = [_points(h, 2, f"{path}: 'holes'[{i}]") for i, h in enumerate(data.get("holes", []))]
    tethers = _points(data.get("tethers", []), 3, f"{path}: 'tethers'", minimum=0)
    mm_per_unit = 1e-3 if unit == "um" else 1.0
    unit, label = ("l0" if unit == "l0" else "mm"), unit
    for ring, name in [(shell, "outline")] + [(h, f"holes[{i}]") for i, h in enumerate(holes)]:
        if len(_drop_closing_point(ring, 0.0)) < 3:
            raise DrawingError(f"{path}: the {name} needs at least 3 distinct points")
    circles = [_Circle(f"tethers[{i}]", *t) for i, t in enumerate(tethers)]
    shapes = _Shapes(source, unit, label, shell=_Ring("the outline", shell),
                     holes=[_Ring(f"holes[{i}]", h) for i, h in enumerate(holes)],
                     circles=circles)
    return _finish(shapes, mm_per_unit, l0_um, flip_y=False, how="'units' in the file")


def _points(value, width: int, where: str, minimum: int = 3) -> np.ndarray:
    try:
        array = np.asarray(value, dtype=np.float64)
    except (TypeError, ValueError) as error:
        raise DrawingError(f"{where} must be a list of [{_columns(width)}] numbers: {error}") \
            from error
    if array.size == 0 and minimum == 0:
        return np.zeros((0, width))
    if array.ndim != 2 or array.shape[1] != width:
        raise DrawingError(f"{where} must be a list of [{_columns(width)}], got shape "
                           f"{array.shape}")
    if not np.isfinite(array).all():
        raise DrawingError(f"{where} holds NaN or infinite numbers")
    if len(array) < minimum:
        raise DrawingError(f"{where} needs at least {minimum} points, got {len(array)}")
    return array


def _columns(width: int) -> str:
    return "x, y" if width == 2 else "x, y, r"


# --------------------------------------------------------------------------- shapes -> mould


@dataclass
class _Ring:
    name: str  # how the file names it, for messages
    points: np.ndarray  # (k, 2) drawing units, the file's axes


@dataclass
class _Circle:
    name: str
    x: float
    y: float
    r: float


@dataclass
class _Shapes:
    """What a file holds, in drawing units ("l0" or "mm" after a factor), the file's axes."""

    source: str
    unit: str  # "l0" or "mm": what the coordinates become after the reader's factor
    label: str  # the file's own coordinate unit, for messages ("l0", "um", "user units")
    shell: _Ring
    holes: list
    circles: list


def _drop_closing_point(points: np.ndarray, tol: float) -> np.ndarray:
    if len(points) > 1 and np.hypot(*(points[-1] - points[0])) <= tol:
        return points[:-1]
    return points


def _ring_polygon(ring: _Ring, source: str, label: str) -> Polygon:
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


def _finish(shapes: _Shapes, mm_per_unit: float, l0_um, flip_y: bool, how: str) -> Drawing:
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
    scale = mm_per_unit * _l0_per_unit(unit, l0_um, source, label, how)
    sign = -1.0 if flip_y else 1.0
    polygon = orient(affinity.scale(polygon, scale, sign * scale, origin=(0, 0)))
    tethers = tethers * [scale, sign * scale, scale]
    return Drawing(source=source, polygon=polygon, tethers=tethers, units=unit,
                   reading=f"{label} ({how})")


def _sort_rings(source: str, rings: list, circles: list, ignored: int, tol: float) -> tuple:
    """(outline ring, hole rings, tether circles) of a drawing's closed shapes.

    The outline is the one closed shape that lies inside no other; closed shapes inside it
    are holes; circles are tethers. With no closed shape but circles, a circle enclosing
    every other circle is the outline (a round mould)."""
    if not rings:
        enclosing = [c for c in circles if all(
            c is d or math.hypot(c.x - d.x, c.y - d.y) + d.r < c.r for d in circles)]
        if len(enclosing) == 1:
            outer = enclosing[0]
            return _circle_ring(outer, tol), [], [c for c in circles if c is not outer]
        raise DrawingError(f"{source} has no closed outline (a closed path, polygon or rect); "
                           f"found {len(circles)} circle(s) (tethers) and {ignored} open or "
                           "other element(s), which are ignored")
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


def _circle_ring(circle: _Circle, tol: float) -> _Ring:
    """A circle as a polygon whose chords have sagitta at most `tol` (vertices on it)."""
    r = circle.r
    n = max(16, math.ceil(math.pi / math.acos(max(-1.0, 1 - tol / r))))
    n = 4 * math.ceil(n / 4)  # symmetric about both axes: its bounding box is the circle's
    angle = np.linspace(0, 2 * math.pi, n, endpoint=False)
    return _Ring(circle.name, np.column_stack([circle.x + r * np.cos(angle),
                                               circle.y + r * np.sin(angle)]))


def _flatten_curve(npoint, tol: float, max_pieces: int = 4096) -> np.ndarray:
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


# --------------------------------------------------------------------------- SVG


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


def _read_svg(path: Path, units: str | None, l0_um: float | None) -> Drawing:
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
        unit = _resolve_units(declared.strip() if declared is not None else None, units,
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
    tol = FLATTEN_TOLERANCE_L0 / (per_user * _l0_per_unit(unit, l0_um, source, label, how))

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
            circles.append(_svg_circle(outline, name, source))
            continue
        subpaths = list(outline.as_subpaths())
        for k, subpath in enumerate(subpaths):
            points, closed = _flatten_subpath(subpath, tol)
            ring = name if len(subpaths) == 1 else f"{name} subpath {k + 1}"
            if closed and len(points) >= 3:
                rings.append(_Ring(ring, points))
            elif len(points):
                ignored += 1
    shell, holes, tethers = _sort_rings(source, rings, circles, ignored, tol)
    shapes = _Shapes(source, unit, label, shell=shell, holes=holes, circles=tethers)
    return _finish(shapes, per_user, l0_um, flip_y=True, how=how)


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
            points.extend(map(tuple, _flatten_curve(segment.npoint, tol)[1:]))
    points = np.asarray(points, dtype=np.float64).reshape(-1, 2)
    if len(points) > 2 and np.hypot(*(points[-1] - points[0])) <= tol:
        closed = True
    if closed:
        points = _drop_closing_point(points, tol)
    return points, closed


def _svg_circle(outline, name: str, source: str) -> _Circle:
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
    return _Circle(name, float(centre[0]), float(centre[1]), radius)


# --------------------------------------------------------------------------- DXF


_DXF_OPEN_EDGES = ("LINE", "ARC", "LWPOLYLINE", "POLYLINE", "SPLINE", "ELLIPSE")


def _read_dxf(path: Path, units: str | None, l0_um: float | None) -> Drawing:
    """Rings and circles of a DXF drawing's modelspace (read with ezdxf).

    CIRCLE entities are tethers; closed LWPOLYLINE, POLYLINE, SPLINE and ELLIPSE are closed
    shapes (curves and bulges flattened); LINE, ARC and open polylines or splines joined end
    to end into a loop (ezdxf.edgeminer) form one closed shape. Block references (INSERT)
    are expanded; entities on layers that are off or frozen, and everything else (TEXT,
    DIMENSION, HATCH, ...), are ignored.
    Units: the custom header property condor_units ("l0", "mm" or "um") if present, else
    $INSUNITS (inches, feet, mm, cm, m, um, ... converted to mm), else `units`."""
    source = str(path)
    path.stat()  # a missing file is an OSError naming it, not a drawing error
    try:
        doc = ezdxf.readfile(source)
    except (OSError, ezdxf.DXFError) as error:  # ezdxf: IOError for "not a DXF file"
        raise DrawingError(f"{path} is not a readable DXF: {type(error).__name__}: {error}") \
            from error
    declared = doc.header.custom_vars.get(DXF_UNITS_PROPERTY)
    insunits = int(doc.header.get("$INSUNITS", 0) or 0)
    if declared is None and insunits != 0:
        if units == "l0":
            raise DrawingError(f"{path} states $INSUNITS = {insunits} (a physical unit); "
                               f"--units l0 contradicts it")
        try:
            mm_per_unit = dxfunits.conversion_factor(insunits, dxfunits.MM)
        except (KeyError, ValueError, IndexError) as error:
            raise DrawingError(f"{path}: $INSUNITS = {insunits} is not a length unit") from error
        unit, label = "mm", dxfunits.unit_name(insunits).lower()
        how = f"$INSUNITS = {insunits}, read as {mm_per_unit:g} mm a unit"
    else:
        where = (f"header property {DXF_UNITS_PROPERTY}" if declared is not None
                 else "$INSUNITS = 0, unitless")
        unit = _resolve_units(declared, units, source, where)
        mm_per_unit = 1e-3 if unit == "um" else 1.0
        unit, label = ("l0" if unit == "l0" else "mm"), unit
        how = (f"{where} = {label!r}" if declared is not None
               else f"{where}: --units {label} says so")
    tol = FLATTEN_TOLERANCE_L0 / (mm_per_unit * _l0_per_unit(unit, l0_um, source, label, how))

    hidden = {layer.dxf.name.lower() for layer in doc.layers
              if layer.is_off() or layer.is_frozen()}
    rings, circles, edges_entities, ignored = [], [], [], 0
    for entity, name in _dxf_entities(doc.modelspace(), hidden):
        kind = entity.dxftype()
        if kind == "CIRCLE":
            centre = entity.ocs().to_wcs(entity.dxf.center)
            circles.append(_Circle(name, float(centre.x), float(centre.y),
                                   float(entity.dxf.radius)))
        elif kind in _DXF_OPEN_EDGES and edgesmith.is_closed_entity(entity):
            points = np.array([(v.x, v.y) for v in dxfpath.make_path(entity).flattening(tol)])
            rings.append(_Ring(name, _drop_closing_point(points, tol)))
        elif kind in _DXF_OPEN_EDGES:
            edges_entities.append((entity, name))
        else:
            ignored += 1
    loops, loose = _dxf_loops([e for e, _ in edges_entities], tol)
    names = {id(e): n for e, n in edges_entities}
    for chain in loops:
        parts = [names[id(edge.payload)] for edge in chain]
        loop = f"a loop of {len(parts)} joined edges ({_listing(parts, 3)})"
        points = np.array([(v.x, v.y) for v in edgesmith.path2d_from_chain(chain).flattening(tol)])
        rings.append(_Ring(loop, _drop_closing_point(points, tol)))
    ignored += loose
    shell, holes, tethers = _sort_rings(source, rings, circles, ignored, tol)
    shapes = _Shapes(source, unit, label, shell=shell, holes=holes, circles=tethers)
    return _finish(shapes, mm_per_unit, l0_um, flip_y=False, how=how)


def _dxf_entities(entities, hidden: set, owner: str | None = None):
    """(entity, name) of visible entities, block references expanded (named by the INSERT)."""
    for entity in entities:
        if entity.dxf.get("layer", "0").lower() in hidden or entity.dxf.get("invisible", 0):
            continue
        handle, layer = entity.dxf.get("handle"), entity.dxf.get("layer", "0")
        name = owner or f"{entity.dxftype()} (handle {handle}, layer {layer})"
        if entity.dxftype() == "INSERT":
            yield from _dxf_entities(entity.virtual_entities(), hidden,
                                     owner or f"block {entity.dxf.name!r} ({name})")
        else:
            yield entity, name


def _dxf_loops(entities: list, tol: float) -> tuple[list, int]:
    """Closed loops of open edges joined end to end, and how many edges are left over."""
    edges = list(edgesmith.edges_from_entities_2d(entities, gap_tol=tol))
    if not edges:
        return [], len(entities)
    deposit = edgeminer.Deposit(edges, gap_tol=tol)
    loops, used = [], 0
    for chain in edgeminer.find_all_simple_chains(deposit):
        if len(chain) > 1 and edgeminer.is_loop(chain, gap_tol=tol):
            loops.append(chain)
            used += len(chain)
    return loops, len(entities) - used


# --------------------------------------------------------------------------- writers


def _drawing_scale(l0_um: float | None) -> tuple[str, float]:
    """(unit, drawing units per l0) of a written drawing: mm given l0_um, else l0."""
    _check_l0_um(l0_um)
    return ("mm", float(l0_um) / 1000.0) if l0_um is not None else ("l0", 1.0)


def _tether_rows(mould: Mould, l0_um: float | None) -> list[tuple[str, ...]]:
    """(label, x, y, diameter) per tether: centre from the outline's lower-left bounding-box
    corner (x right, y up) and diameter, each "l0" or "l0 / mm"."""
    xmin, ymin = mould.polygon.bounds[:2]

    def pair(value):
        return f"{value:.4g}" + (f" / {value * l0_um / 1000:.4g}" if l0_um is not None else "")

    return [(f"T{i}", pair(x - xmin), pair(y - ymin), pair(2 * r))
            for i, (x, y, r) in enumerate(np.asarray(mould.tethers).reshape(-1, 3), start=1)]


def _svg_text(x: float, y: float, text: str, size: float, scale: float, extra: str = "",
              rotate: float = 0.0) -> str:
    """A <text> drawn at font size `size` * `scale` user units. Its own coordinates are
    scaled by `scale`, so the font size it states is of order 1 whatever the drawing's
    units: renderers mishandle tiny font sizes (mm drawings of sub-mm moulds)."""
    turn = f" rotate({rotate:g})" if rotate else ""
    return (f'<text transform="translate({x:.10g} {y:.10g}){turn} scale({scale:.10g})" '
            f'font-size="{size:g}"{extra}>{escape(text)}</text>')


def write_svg(mould: Mould, path, l0_um: float | None = None) -> None:
    """Write `mould` as an SVG drawing that opens in a browser: the outline (holes
    included) and tethers, the simulation box (dashed), the overall width and height, and a
    table of tether centres and diameters, in l0 and, given `l0_um`, in mm.

    The geometry is in one unit, stated by data-units on <svg>: mm given l0_um (one user
    unit = 1 mm), else l0. load_mould reads it back (annotations are lines and text, which
    it ignores); y points up in the mould and down in SVG, so the drawing is mirrored into
    SVG's axes and back."""
    unit, f = _drawing_scale(l0_um)
    box = float(mould.box)
    side = box * f
    font = side / 36  # user units per font unit
    rows = _tether_rows(mould, l0_um)
    left, top, right = 4.0 * font, 4.2 * font, 1.0 * font
    table_top = side + 4.4 * font
    bottom = 4.4 * font + (len(rows) + 1.8) * 1.3 * font
    view = (-left, -top, side + left + right, side + top + bottom)
    width_px = 760

    def xy(x, y):  # mould l0 (y up) -> SVG user units (y down)
        return x * f, (box - y) * f

    def num(v):
        return f"{v:.10g}"

    rings = [mould.polygon.exterior, *mould.polygon.interiors]
    d = " ".join("M " + " L ".join(f"{num(a)} {num(b)}" for a, b in
                                   (xy(*p) for p in np.asarray(ring.coords)[:-1])) + " Z"
                 for ring in rings)
    xmin, ymin, xmax, ymax = mould.polygon.bounds
    (x0, y0), (x1, y1) = xy(xmin, ymin), xy(xmax, ymax)  # y0 is the bottom in SVG
    stroke = side / 400
    title, subtitle = _title_lines(mould, l0_um)
    out = [
        '<?xml version="1.0" encoding="UTF-8"?>',
        f'<svg xmlns="http://www.w3.org/2000/svg" width="{width_px}" '
        f'height="{width_px * view[3] / view[2]:.0f}" '
        f'viewBox="{" ".join(num(v) for v in view)}" data-units="{unit}">',
        f"<title>{escape(title)}</title>",
        f'<g stroke="#999999" stroke-width="{num(stroke)}" fill="none" '
        f'stroke-dasharray="{num(4 * stroke)} {num(4 * stroke)}">',
    ]
    corners = [(0, 0), (side, 0), (side, side), (0, side), (0, 0)]
    out += [_svg_line(*a, *b) for a, b in zip(corners[:-1], corners[1:])]  # open: not a shape
    out += [
        "</g>",
        f'<path id="outline" d="{d}" fill="#9ecae1" fill-rule="evenodd" stroke="#08519c" '
        f'stroke-width="{num(2 * stroke)}"/>',
    ]
    tethers = np.asarray(mould.tethers).reshape(-1, 3)
    for i, (x, y, r) in enumerate(tethers, start=1):
        cx, cy = xy(x, y)
        out.append(f'<circle id="tether-{i}" cx="{num(cx)}" cy="{num(cy)}" r="{num(r * f)}" '
                   'fill="#d62728"/>')
    out.append('<g font-family="sans-serif" fill="#222222">')
    for i, (x, y, r) in enumerate(tethers, start=1):
        cx, cy = xy(x, y)
        out.append(_svg_text(cx + 0.8 * r * f, cy - 0.8 * r * f, f"T{i}", 0.6, font))
    below, aside, tick = side + 1.4 * font, -1.4 * font, 0.4 * font
    out += [
        f'<g stroke="#222222" stroke-width="{num(stroke)}">',
        # width: extension lines down from the outline to the dimension line, ticks at ends
        _svg_line(x0, y0, x0, below + tick), _svg_line(x1, y0, x1, below + tick),
        _svg_line(x0, below, x1, below),
        _svg_line(x0 - tick, below + tick, x0 + tick, below - tick),
        _svg_line(x1 - tick, below + tick, x1 + tick, below - tick),
        # height: extension lines left from the outline to the dimension line
        _svg_line(x0, y0, aside - tick, y0), _svg_line(x0, y1, aside - tick, y1),
        _svg_line(aside, y0, aside, y1),
        _svg_line(aside - tick, y0 + tick, aside + tick, y0 - tick),
        _svg_line(aside - tick, y1 + tick, aside + tick, y1 - tick),
        "</g>",
        _svg_text(0.5 * (x0 + x1), below + 1.2 * font, f"width {_both(xmax - xmin, l0_um)}",
                  0.9, font, ' text-anchor="middle"'),
        _svg_text(aside - 0.5 * font, 0.5 * (y0 + y1), f"height {_both(ymax - ymin, l0_um)}",
                  0.9, font, ' text-anchor="middle"', rotate=-90),
        _svg_text(-left + 0.5 * font, -2.6 * font, title, 1.0, font),
        _svg_text(-left + 0.5 * font, -1.3 * font, subtitle, 0.8, font),
    ]
    if rows:
        heading = ("tether", f"x ({_pair_unit(l0_um)})", f"y ({_pair_unit(l0_um)})",
                   f"diameter ({_pair_unit(l0_um)})")
        columns = (0.0, 3.5, 13.0, 22.5) if l0_um is not None else (0.0, 3.5, 9.5, 15.5)
        out.append(_svg_text(0, table_top, "Tether centres from the outline's lower-left "
                             "corner (x right, y up) and diameters:", 0.8, font))
        for k, row in enumerate([heading, *rows], start=1):
            for column, cell in zip(columns, row):
                out.append(_svg_text(column * font, table_top + 1.3 * k * font, cell, 0.8,
                                     font, ' font-family="monospace"'))
    else:
        out.append(_svg_text(0, table_top, "No tethers.", 0.8, font))
    out += ["</g>", "</svg>", ""]
    Path(path).write_text("\n".join(out), encoding="utf-8")


def _pair_unit(l0_um: float | None) -> str:
    return "l0 / mm" if l0_um is not None else "l0"


def _svg_line(x1, y1, x2, y2) -> str:
    return f'<line x1="{x1:.10g}" y1="{y1:.10g}" x2="{x2:.10g}" y2="{y2:.10g}"/>'


def _title_lines(mould: Mould, l0_um: float | None, box_drawn: bool = True) -> tuple[str, str]:
    kind = (f"{mould.symmetry}, seed {mould.seed}" if mould.is_generated else mould.symmetry)
    scale = f"l0 = {l0_um:g} um; " if l0_um is not None else ""
    unit = "mm" if l0_um is not None else "l0"
    dashed = " (dashed)" if box_drawn else ""
    fraction = mould.polygon.area / mould.box**2
    return (f"condor mould {mould.mould_id} ({kind}), {mould.n_tethers} tethers",
            f"box {_both(mould.box, l0_um)}{dashed}; area {fraction:.3g} of the box; "
            f"{scale}drawn in {unit}")


def write_dxf(mould: Mould, path, l0_um: float | None = None) -> None:
    """Write `mould` as a DXF drawing for CAD: the outline (and holes) as closed polylines on
    layer OUTLINE, tethers as circles on layer TETHERS, and on layer DIMENSIONS the overall
    width and height, tether labels and a table of tether centres and diameters.

    Given l0_um the drawing is in mm at true size ($INSUNITS = mm); otherwise it is in l0
    ($INSUNITS = 0, header property condor_units = "l0"). Box coordinates, y up."""
    unit, f = _drawing_scale(l0_um)
    doc = ezdxf.new("R2013", setup=True)
    doc.header["$MEASUREMENT"] = 1  # metric
    if unit == "mm":
        doc.units = dxfunits.MM
    else:
        doc.units = 0
        doc.header.custom_vars.append(DXF_UNITS_PROPERTY, "l0")
    for name, colour in (("OUTLINE", 5), ("TETHERS", 1), ("DIMENSIONS", 8)):
        doc.layers.add(name, color=colour)
    msp = doc.modelspace()
    for ring in [mould.polygon.exterior, *mould.polygon.interiors]:
        points = np.asarray(ring.coords)[:-1] * f
        msp.add_lwpolyline(points.tolist(), close=True, dxfattribs={"layer": "OUTLINE"})
    tethers = np.asarray(mould.tethers).reshape(-1, 3)
    for x, y, r in tethers:
        msp.add_circle((x * f, y * f), r * f, dxfattribs={"layer": "TETHERS"})
    size = mould.box * f / 40
    style = {"dimtxt": size, "dimasz": 0.7 * size, "dimexo": 0.3 * size, "dimexe": 0.5 * size,
             "dimgap": 0.3 * size}
    dims = {"layer": "DIMENSIONS"}
    xmin, ymin, xmax, ymax = np.asarray(mould.polygon.bounds) * f
    msp.add_linear_dim(base=(xmin, ymin - 3 * size), p1=(xmin, ymin), p2=(xmax, ymin),
                       text=f"width {_both((xmax - xmin) / f, l0_um)}", override=style,
                       dxfattribs=dims).render()
    msp.add_linear_dim(base=(xmin - 3 * size, ymin), p1=(xmin, ymin), p2=(xmin, ymax), angle=90,
                       text=f"height {_both((ymax - ymin) / f, l0_um)}", override=style,
                       dxfattribs=dims).render()
    for i, (x, y, r) in enumerate(tethers, start=1):
        msp.add_text(f"T{i}", height=0.6 * size, dxfattribs=dims).set_placement(
            ((x + 0.8 * r) * f, (y + 0.8 * r) * f))
    rows = [*_title_lines(mould, l0_um, box_drawn=False), "Box coordinates, y up."]
    if len(tethers):
        rows.append("Tether centres from the outline's lower-left corner, diameters "
                    f"({_pair_unit(l0_um)}):")
        rows += [f"{t}: x {x}, y {y}, diameter {d}" for t, x, y, d in _tether_rows(mould, l0_um)]
    msp.add_mtext("\\P".join(rows), dxfattribs={"layer": "DIMENSIONS", "char_height": size,
                                                "insert": (0, -6 * size)})
    doc.saveas(str(path))
