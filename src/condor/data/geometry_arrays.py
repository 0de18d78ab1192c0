"""A mould's geometry as the store keeps it (condor.data.store, GEOMETRY_ARRAYS), in l0 in the
frame of the store's x and y coordinates: its outline (the exterior ring, closed: its first
vertex repeated last; then each hole's ring, closed, after one NaN) as x and y arrays with the
count of entries in use, NaN after; its tethers (x, y, radius) as three arrays, NaN after the
last. The lengths are fixed: MAX_TETHERS is the generator's limit (MouldParams.max_tethers);
MAX_VERTICES is far above the most a generated mould was seen to need (docs/moulds.md, "The
mould in the store"). A mould needing more is refused (ValueError; the store's write_inputs
names the mould), never cut.
"""

from __future__ import annotations

import numpy as np
from shapely.geometry import Polygon

from condor.moulds.paper import MouldParams

MAX_VERTICES = 2048
MAX_TETHERS = MouldParams().max_tethers


def outline_arrays(polygon, limit: int = MAX_VERTICES) -> tuple[np.ndarray, np.ndarray, int]:
    """(x, y, count): `polygon`'s rings as the store keeps them (GEOMETRY_ARRAYS): the
    exterior ring closed, then each hole's ring closed after one NaN, float64, NaN-padded to
    `limit`. ValueError when it is not one Polygon with finite vertices or needs more than
    `limit` entries (it is never cut)."""
    if not isinstance(polygon, Polygon) or polygon.is_empty:
        raise ValueError(f"the outline is a {getattr(polygon, 'geom_type', type(polygon).__name__)}"
                         ", not one non-empty Polygon")
    rings = [np.asarray(polygon.exterior.coords, dtype=np.float64)[:, :2]]
    rings += [np.asarray(ring.coords, dtype=np.float64)[:, :2] for ring in polygon.interiors]
    gap = np.full((1, 2), np.nan)
    joined = np.concatenate([part for k, ring in enumerate(rings)
                             for part in ((gap, ring) if k else (ring,))])
    if not np.isfinite(np.concatenate(rings)).all():
        raise ValueError("the outline has NaN or infinite vertices")
    count = len(joined)
    if count > limit:
        raise ValueError(f"the outline needs {count} entries ({len(rings[0])} exterior vertices, "
                         f"{len(rings) - 1} hole(s)), the store holds at most {limit} "
                         "(MAX_VERTICES)")
    padded = np.full((limit, 2), np.nan)
    padded[:count] = joined
    return padded[:, 0].copy(), padded[:, 1].copy(), count


def outline_polygon(x, y, count: int):
    """The shapely Polygon `outline_arrays` stored: the inverse, exact to the last bit."""
    count = int(count)
    if count < 4:
        raise ValueError(f"an outline of {count} entries holds no polygon (not written?)")
    xy = np.column_stack([np.asarray(x, np.float64)[:count], np.asarray(y, np.float64)[:count]])
    gaps = np.flatnonzero(np.isnan(xy[:, 0]))
    rings = np.split(xy, gaps)
    rings = [rings[0]] + [ring[1:] for ring in rings[1:]]
    return Polygon(rings[0], rings[1:])


def tether_arrays(tethers, limit: int = MAX_TETHERS) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """(x, y, r) of `tethers` (n, 3), float64, NaN-padded to `limit`; ValueError when they
    are not (n, 3) finite numbers or more than `limit` (never cut)."""
    tethers = np.asarray(tethers, dtype=np.float64)
    if tethers.size == 0:
        tethers = tethers.reshape(0, 3)
    if tethers.ndim != 2 or tethers.shape[1] != 3:
        raise ValueError(f"tethers have shape {tethers.shape}, expected (n, 3): x, y, radius")
    if not np.isfinite(tethers).all():
        raise ValueError("tethers hold NaN or infinite values")
    if len(tethers) > limit:
        raise ValueError(f"{len(tethers)} tethers, the store holds at most {limit} (MAX_TETHERS)")
    padded = np.full((limit, 3), np.nan)
    padded[:len(tethers)] = tethers
    return padded[:, 0].copy(), padded[:, 1].copy(), padded[:, 2].copy()
