"""Writing a mould as a drawing with dimensions: SVG (`write_svg`, opens in a browser) and
DXF (`write_dxf`, for CAD), in mm given the cell spacing l0, else in l0. `condor.moulds.read`
reads both back."""

from __future__ import annotations

from pathlib import Path
from xml.sax.saxutils import escape

import ezdxf
import numpy as np
from ezdxf import units as dxfunits

from condor.moulds.mould import USER, Mould
from condor.moulds.units import DXF_UNITS_PROPERTY, drawing_scale, length_text

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


def drawn_mould(mould: Mould, scale: float) -> Mould:
    """`mould` at the size its user drew it: a mould placed scaled by `scale` (--fit; a
    Placement's scale) scaled back by 1 / scale about the box's corner, its box with it."""
    from dataclasses import replace

    from shapely import affinity

    factor = 1.0 / float(scale)
    tethers = np.asarray(mould.tethers, dtype=np.float64).reshape(-1, 3) * factor
    return replace(mould, box=float(mould.box) * factor,
                   polygon=affinity.scale(mould.polygon, factor, factor, origin=(0, 0)),
                   tethers=tethers, area_fraction=None, origin=None, unpruned_tethers=None,
                   symmetry=USER if mould.is_generated else mould.symmetry)


def write_svg(mould: Mould, path, l0_um: float | None = None, note: str | None = None) -> None:
    """Write `mould` as an SVG drawing that opens in a browser: the outline (holes
    included) and tethers, the simulation box (dashed), the overall width and height, and a
    table of tether centres and diameters, in l0 and, given `l0_um`, in mm.

    The geometry is in one unit, stated by data-units on <svg>: mm given l0_um (one user
    unit = 1 mm), else l0. load_mould reads it back (annotations are lines and text, which
    it ignores); y points up in the mould and down in SVG, so the drawing is mirrored into
    SVG's axes and back. `note`: a line under the title (the scale it is drawn at)."""
    unit, f = drawing_scale(l0_um)
    box = float(mould.box)
    side = box * f
    font = side / 36  # user units per font unit
    rows = _tether_rows(mould, l0_um)
    left, top, right = 4.0 * font, (5.5 if note else 4.2) * font, 1.0 * font
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
        _svg_text(0.5 * (x0 + x1), below + 1.2 * font, f"width {length_text(xmax - xmin, l0_um)}",
                  0.9, font, ' text-anchor="middle"'),
        _svg_text(aside - 0.5 * font, 0.5 * (y0 + y1), f"height {length_text(ymax - ymin, l0_um)}",
                  0.9, font, ' text-anchor="middle"', rotate=-90),
        _svg_text(-left + 0.5 * font, -(3.9 if note else 2.6) * font, title, 1.0, font),
        _svg_text(-left + 0.5 * font, -(2.6 if note else 1.3) * font, subtitle, 0.8, font),
    ]
    if note:
        out.append(_svg_text(-left + 0.5 * font, -1.3 * font, note, 0.8, font))
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
    kind = (f"{mould.symmetry}, seed {mould.seed}" if mould.is_generated else
            f"lab family {mould.family}, seed {mould.seed}" if mould.family != USER else
            mould.symmetry)
    scale = f"l0 = {l0_um:g} um; " if l0_um is not None else ""
    unit = "mm" if l0_um is not None else "l0"
    dashed = " (dashed)" if box_drawn else ""
    fraction = mould.polygon.area / mould.box**2
    return (f"condor mould {mould.mould_id} ({kind}), {mould.n_tethers} tethers",
            f"box {length_text(mould.box, l0_um)}{dashed}; area {fraction:.3g} of the box; "
            f"{scale}drawn in {unit}")


def write_dxf(mould: Mould, path, l0_um: float | None = None, note: str | None = None) -> None:
    """Write `mould` as a DXF drawing for CAD: the outline (and holes) as closed polylines on
    layer OUTLINE, tethers as circles on layer TETHERS, and on layer DIMENSIONS the overall
    width and height, tether labels and a table of tether centres and diameters.

    Given l0_um the drawing is in mm at true size ($INSUNITS = mm); otherwise it is in l0
    ($INSUNITS = 0, header property condor_units = "l0"). Box coordinates, y up. `note`: a
    line under the title (the scale it is drawn at)."""
    unit, f = drawing_scale(l0_um)
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
                       text=f"width {length_text((xmax - xmin) / f, l0_um)}", override=style,
                       dxfattribs=dims).render()
    msp.add_linear_dim(base=(xmin - 3 * size, ymin), p1=(xmin, ymin), p2=(xmin, ymax), angle=90,
                       text=f"height {length_text((ymax - ymin) / f, l0_um)}", override=style,
                       dxfattribs=dims).render()
    for i, (x, y, r) in enumerate(tethers, start=1):
        msp.add_text(f"T{i}", height=0.6 * size, dxfattribs=dims).set_placement(
            ((x + 0.8 * r) * f, (y + 0.8 * r) * f))
    rows = [*_title_lines(mould, l0_um, box_drawn=False), *([note] if note else []),
            "Box coordinates, y up."]
    if len(tethers):
        rows.append("Tether centres from the outline's lower-left corner, diameters "
                    f"({_pair_unit(l0_um)}):")
        rows += [f"{t}: x {x}, y {y}, diameter {d}" for t, x, y, d in _tether_rows(mould, l0_um)]
    msp.add_mtext("\\P".join(rows), dxfattribs={"layer": "DIMENSIONS", "char_height": size,
                                                "insert": (0, -6 * size)})
    doc.saveas(str(path))
