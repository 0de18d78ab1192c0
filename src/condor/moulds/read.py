"""A user's own mould read from a file and placed in a scene (`load_mould`).

`load_mould(path, scene, l0_um=None, fit=False, units=None)` accepts

- the generator's mould JSON (`condor.moulds.mould.save_json`; validated as before);
- a minimal JSON: {"outline": [[x, y], ...], "holes": [[[x, y], ...], ...],
  "tethers": [[x, y, r], ...], "units": "l0" | "mm" | "um"} (holes and tethers optional);
- an SVG drawing (read with svgelements) or a DXF drawing (read with ezdxf): exactly one
  closed shape is the outline, closed shapes inside it are holes, circles are tethers.

Drawings in mm (or um) need the cell spacing `l0_um` (micrometres) to become l0. The
drawing keeps its size and is centred in the scene's box; `fit="extent"` scales it to the
window, `fit="area"` (or True) to the training moulds' area instead (`load_placement`
returns the scale factor: condor.moulds.place). The SVG and DXF readers are
condor.moulds.read_svg and condor.moulds.read_dxf; docs/user_moulds.md states every rule.
"""

from __future__ import annotations

import json
import math
from dataclasses import replace
from pathlib import Path

import numpy as np

from condor.model.scenes import Scene, same_length
from condor.moulds.mould import DrawingError, InvalidMouldError, Mould, load_json
from condor.moulds.place import Placement, fit_factor, fit_mode, place_drawing
from condor.moulds.read_dxf import read_dxf
from condor.moulds.read_picture import PICTURE_SUFFIXES, PictureOptions, read_picture
from condor.moulds.read_svg import read_svg
from condor.moulds.shapes import (Circle, Drawing, Ring, Shapes, drop_closing_point,
                                  finish_drawing)
from condor.moulds.units import UNITS, check_l0_um, resolve_units


def load_mould(path, scene: Scene, l0_um: float | None = None, fit=False,
               units: str | None = None, picture: PictureOptions | None = None) -> Mould:
    """The mould in `path` (.json, .svg, .dxf, or a picture: .png, .tif, .tiff, .jpg, .jpeg),
    placed in `scene`'s box (lengths in l0).

    l0_um: the cell spacing l0 in micrometres; required for a drawing in mm or um.
    fit: False keeps the drawn size; "extent" scales the drawing, keeping its aspect
        ratio, so that its larger side is scene.max_extent of the box; "area" (or True)
        so that its area is the training moulds' (scene.area_fraction of the box), capped
        by the extent fit. `load_placement` also returns the scale factor.
    units: "l0", "mm" or "um", for a file that does not state its units (a minimal JSON
        without "units", a DXF with $INSUNITS = 0, an SVG whose root has neither
        data-units nor an absolute width/height); a file that states other units is an
        error.
    picture: how to read a picture (condor.moulds.read_picture.PictureOptions: --invert,
        --posts, --pixel-um); a picture that states no scale spans `scene`'s box.

    Raises DrawingError (unreadable file, no or several outlines, missing units or l0_um)
    or InvalidMouldError (a mould that does not fit: too large, tether outside the
    outline, overlapping tethers, self-intersecting outline, narrower than a cell, ...),
    both ValueErrors whose message names the file and the bad value. OSError if the file
    cannot be read.
    """
    return load_placement(path, scene, l0_um=l0_um, fit=fit, units=units,
                          picture=picture).mould


def load_placement(path, scene: Scene, l0_um: float | None = None, fit=False,
                   units: str | None = None, data=None,
                   picture: PictureOptions | None = None) -> Placement:
    """As load_mould, with how the mould was placed: its scale factor (`Placement.scale`),
    the fit mode and the drawn size (for printing and recording)."""
    path = Path(path)
    _check_arguments(l0_um, units)
    if data is None and path.suffix.lower() == ".json":
        data = _read_json(path)
    if isinstance(data, dict) and "polygon" in data:
        return _mould_json(path, scene, fit, units, l0_um)
    if path.suffix.lower() in PICTURE_SUFFIXES:
        if units is not None:
            raise DrawingError(f"{path} is a picture: --units says nothing about it (its scale "
                               "is its own, --pixel-um, or the scene's box)")
        drawing = read_picture(path, float(scene.box), l0_um, picture)
    else:
        drawing = _read_drawing(path, l0_um, units, data)
    placement = place_drawing(drawing.polygon, drawing.tethers, scene, fit=fit, l0_um=l0_um,
                      source=str(path))
    return replace(placement, reading=drawing.reading)


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
        return read_svg(path, units, l0_um)
    if suffix == ".dxf":
        return read_dxf(path, units, l0_um)
    raise DrawingError(f"{path}: unknown mould file type {suffix!r}; use .json (a mould or "
                       "an outline), .svg, .dxf, or a picture (.png, .tif, .jpg)")


def _check_arguments(l0_um, units) -> None:
    check_l0_um(l0_um)
    if units is not None and units not in UNITS:
        raise DrawingError(f"--units {units!r}: choose one of {UNITS}")


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
    mode = fit_mode(fit)
    if mode is not None and not math.isclose(fit_factor(mould.polygon, scene, mode), 1.0,
                                             rel_tol=1e-6):
        return place_drawing(mould.polygon, mould.tethers, scene, fit=mode, l0_um=l0_um,
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
    unit = resolve_units(data.get("units"), units, source, "'units'")
    shell = _points(data["outline"], 2, f"{path}: 'outline'")
    holes = [_points(h, 2, f"{path}: 'holes'[{i}]") for i, h in enumerate(data.get("holes", []))]
    tethers = _points(data.get("tethers", []), 3, f"{path}: 'tethers'", minimum=0)
    mm_per_unit = 1e-3 if unit == "um" else 1.0
    unit, label = ("l0" if unit == "l0" else "mm"), unit
    for ring, name in [(shell, "outline")] + [(h, f"holes[{i}]") for i, h in enumerate(holes)]:
        if len(drop_closing_point(ring, 0.0)) < 3:
            raise DrawingError(f"{path}: the {name} needs at least 3 distinct points")
    circles = [Circle(f"tethers[{i}]", *t) for i, t in enumerate(tethers)]
    shapes = Shapes(source, unit, label, shell=Ring("the outline", shell),
                     holes=[Ring(f"holes[{i}]", h) for i, h in enumerate(holes)],
                     circles=circles)
    return finish_drawing(shapes, mm_per_unit, l0_um, flip_y=False, how="'units' in the file")


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
