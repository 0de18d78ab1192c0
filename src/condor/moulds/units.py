"""Lengths of a drawing: the units it may be in, their conversion to l0 (given the cell
spacing l0 in micrometres), and how a length or a list is written in a message."""

from __future__ import annotations

import math
import numbers

from condor.moulds.mould import DrawingError

UNITS = ("l0", "mm", "um")  # units a drawing may be in (um is read as mm / 1000)
DXF_UNITS_PROPERTY = "condor_units"  # DXF custom header property naming a drawing's units


def check_l0_um(l0_um) -> None:
    if l0_um is None:
        return
    if isinstance(l0_um, bool) or not isinstance(l0_um, numbers.Real) \
            or not math.isfinite(l0_um) or l0_um <= 0:
        raise DrawingError(f"--l0-um {l0_um!r} must be a positive number of micrometres "
                           "(the cell spacing l0)")


def l0_per_unit(unit: str, l0_um: float | None, source: str, label: str, how: str) -> float:
    """Length in l0 of one drawing unit ("l0" or "mm"); `label` is the file's own unit
    (meters, um, user units, ...) and `how` says where it came from, for the message."""
    if unit == "l0":
        return 1.0
    if l0_um is None:
        raise DrawingError(f"{source} is drawn in {label} ({how}): give the cell spacing l0 "
                           "in micrometres with --l0-um (e.g. --l0-um 16) to convert it to l0 "
                           "(or --units l0 if it is drawn in l0)")
    return 1000.0 / float(l0_um)


def resolve_units(stated: str | None, given: str | None, source: str, where: str) -> str:
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


def drawing_scale(l0_um: float | None) -> tuple[str, float]:
    """(unit, drawing units per l0) of a written drawing: mm given l0_um, else l0."""
    check_l0_um(l0_um)
    return ("mm", float(l0_um) / 1000.0) if l0_um is not None else ("l0", 1.0)


def length_text(value_l0: float, l0_um: float | None) -> str:
    """A length in l0 and, given l0_um, in mm."""
    text = f"{value_l0:.4g} l0"
    return text + f" = {value_l0 * l0_um / 1000:.4g} mm" if l0_um is not None else text


def listing(values, limit: int = 6) -> str:
    items = [f"{v:.3g}" if isinstance(v, float) else str(v) for v in list(values)[:limit]]
    return ", ".join(items) + (", ..." if len(values) > limit else "")
