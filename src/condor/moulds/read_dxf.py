"""Reading a DXF drawing (ezdxf): its rings (closed entities, and open edges joined into
loops) and circles, and the units its header states."""

from __future__ import annotations

from pathlib import Path

import ezdxf
import numpy as np
from ezdxf import edgeminer, edgesmith
from ezdxf import path as dxfpath
from ezdxf import units as dxfunits

from condor.moulds.mould import DrawingError
from condor.moulds.shapes import (FLATTEN_TOLERANCE_L0, HOLE_LAYERS, Circle, Drawing, Ring,
                                  Shapes, drop_closing_point, finish_drawing, sort_rings)
from condor.moulds.units import DXF_UNITS_PROPERTY, l0_per_unit, listing, resolve_units

_DXF_OPEN_EDGES = ("LINE", "ARC", "LWPOLYLINE", "POLYLINE", "SPLINE", "ELLIPSE")


def read_dxf(path: Path, units: str | None, l0_um: float | None) -> Drawing:
    """Rings and circles of a DXF drawing's modelspace (read with ezdxf).

    CIRCLE entities are tethers (holes on a layer named HOLE or HOLES); closed LWPOLYLINE, POLYLINE, SPLINE and ELLIPSE are closed
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
        unit = resolve_units(declared, units, source, where)
        mm_per_unit = 1e-3 if unit == "um" else 1.0
        unit, label = ("l0" if unit == "l0" else "mm"), unit
        how = (f"{where} = {label!r}" if declared is not None
               else f"{where}: --units {label} says so")
    tol = FLATTEN_TOLERANCE_L0 / (mm_per_unit * l0_per_unit(unit, l0_um, source, label, how))

    hidden = {layer.dxf.name.lower() for layer in doc.layers
              if layer.is_off() or layer.is_frozen()}
    rings, circles, edges_entities, ignored = [], [], [], 0
    for entity, name in _dxf_entities(doc.modelspace(), hidden):
        kind = entity.dxftype()
        if kind == "CIRCLE":
            centre = entity.ocs().to_wcs(entity.dxf.center)
            hole = str(entity.dxf.get("layer", "0")).lower() in HOLE_LAYERS
            circles.append(Circle(name, float(centre.x), float(centre.y),
                                   float(entity.dxf.radius), hole=hole))
        elif kind in _DXF_OPEN_EDGES and edgesmith.is_closed_entity(entity):
            points = np.array([(v.x, v.y) for v in dxfpath.make_path(entity).flattening(tol)])
            rings.append(Ring(name, drop_closing_point(points, tol)))
        elif kind in _DXF_OPEN_EDGES:
            edges_entities.append((entity, name))
        else:
            ignored += 1
    loops, loose = _dxf_loops([e for e, _ in edges_entities], tol)
    names = {id(e): n for e, n in edges_entities}
    for chain in loops:
        parts = [names[id(edge.payload)] for edge in chain]
        loop = f"a loop of {len(parts)} joined edges ({listing(parts, 3)})"
        points = np.array([(v.x, v.y) for v in edgesmith.path2d_from_chain(chain).flattening(tol)])
        rings.append(Ring(loop, drop_closing_point(points, tol)))
    ignored += loose
    shell, holes, tethers = sort_rings(source, rings, circles, ignored, tol)
    shapes = Shapes(source, unit, label, shell=shell, holes=holes, circles=tethers)
    return finish_drawing(shapes, mm_per_unit, l0_um, flip_y=False, how=how)


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
