"""The whole-mould statistics of one mould's 8 fields (condor.data.fields): condor's
(`MOULD_STATISTICS`, `mould_summary_statistics`), which condor answers with, and the paper's
(`STATISTICS`, `mould_statistics`, `statistics_table`), kept where the paper's r is compared.
docs/fields.md, "Whole-mould statistics", defines each once.
"""

from __future__ import annotations

import math

import numpy as np
import pandas as pd

from condor.data.fields import FIELD_NAMES, check_finite
from condor.model.scenes import PAPER_BOX, PAPER_PIXELS

STATISTICS = (
    "mean_P",
    "n_P_gt_0.2",
    "mean_T",
    "mean_T_norm",
    "mean_Sx2",
    "mean_Sx2_norm",
    "mean_Sy2",
    "mean_Sy2_norm",
)

# The whole-mould statistics condor answers with (`mould_summary_statistics`; what predict,
# simulate, predict --check, design and condor.score print, under these names), each with its
# unit. docs/fields.md, "Whole-mould statistics", defines each once, beside the paper's
# (STATISTICS, `mould_statistics`: kept where the paper's r is compared).
MOULD_STATISTICS = ("alignment", "direction", "alignment_x", "mean_tension", "tissue_area")
STATISTIC_UNITS = {"alignment": "0..1", "direction": "deg from x", "alignment_x": "-1..1",
                   "mean_tension": "T units", "tissue_area": "l0^2"}

# The paper's pixel side l_p (62.5 l0 / 256 = 125 l0 / 512): statistics are expressed in it.
PAPER_PIXEL_SIZE = PAPER_BOX / PAPER_PIXELS

# The paper's area threshold: density above 0.2 cells per paper pixel.
DENSITY_THRESHOLD = 0.2



def mould_statistics(
    fields: np.ndarray, pixel_size: float, n_cells: float | None = None
) -> dict[str, float]:
    """The paper's whole-mould statistics (Results section) of one sample's 8 fields.

    fields: (8, H, W) un-normalised fields; pixel_size: l0. n_cells: N_c for the
    normalised means; None uses the density sum P.sum() (as for predicted fields).
    Resolution-independent definitions, in the paper's pixel l_p = 62.5/256 l0
    (at the paper's 256 px over 62.5 l0 they reduce to the paper's own):
      mean_P, mean_T, mean_Sx2, mean_Sy2: mean over all grid pixels of the field expressed
          per paper pixel area (field * (l_p / pixel_size)^2) = field sum * l_p^2 / box^2.
      n_P_gt_0.2: area, in paper pixels, where P exceeds 0.2 cells per paper pixel.
      mean_X_norm: mean over all pixels of normalise(X) = X.sum() / N_c, a cell average.
    """
    fields = np.asarray(fields, dtype=np.float64)
    if fields.ndim != 3 or fields.shape[0] != len(FIELD_NAMES):
        raise ValueError(f"fields must have shape (8, H, W), got {fields.shape}")
    check_finite("fields", fields)
    if not (np.isfinite(pixel_size) and pixel_size > 0):
        raise ValueError(f"pixel_size must be positive, got {pixel_size}")
    density, tension, sx2, sy2 = (fields[FIELD_NAMES.index(n)] for n in ("P", "T", "Sx2", "Sy2"))
    if n_cells is None:
        n_cells = float(density.sum())
    if not (np.isfinite(n_cells) and n_cells > 0):
        raise ValueError(f"n_cells (or the density sum) must be positive, got {n_cells}")
    # Grid pixels per paper pixel: converts per-pixel sums to per-paper-pixel densities.
    per_paper_pixel = (PAPER_PIXEL_SIZE / pixel_size) ** 2
    return {
        "mean_P": float(density.mean() * per_paper_pixel),
        "n_P_gt_0.2": float(np.count_nonzero(density * per_paper_pixel > DENSITY_THRESHOLD))
        / per_paper_pixel,
        "mean_T": float(tension.mean() * per_paper_pixel),
        "mean_T_norm": float(tension.sum() / n_cells),
        "mean_Sx2": float(sx2.mean() * per_paper_pixel),
        "mean_Sx2_norm": float(sx2.sum() / n_cells),
        "mean_Sy2": float(sy2.mean() * per_paper_pixel),
        "mean_Sy2_norm": float(sy2.sum() / n_cells),
    }


def mould_summary_statistics(normalised: np.ndarray, n_cells: float, pixel_size: float) -> dict:
    """The whole-mould statistics (MOULD_STATISTICS) of one mould's normalised fields
    (8, H, W); n_cells: N_c (to undo the normalisation for the area); pixel_size: l0.

    Ratios of sums over the normalised fields, so they read the same at any normalisation:
    alignment, the in-plane nematic order of the whole mould along its principal direction,
    |(sum(Sx2 - Sy2), 2 sum SxSy)| / sum(Sx2 + Sy2) in [0, 1]; direction, that direction in
    degrees from x in (-90, 90]; alignment_x, sum(Sx2 - Sy2) / sum(Sx2 + Sy2) in [-1, 1];
    mean_tension, sum T / sum P (the paper's mean T normalised, mean_T_norm, for a mould away
    from the grid's edge); tissue_area, the area in l0^2 where the density exceeds
    DENSITY_THRESHOLD cells per paper pixel (the paper's n_P_gt_0.2 times the paper pixel's
    area)."""
    f = np.asarray(normalised, dtype=np.float64)
    total = f.sum(axis=(-2, -1))
    p, t, sx2, sy2, sxsy = (total[FIELD_NAMES.index(n)] for n in ("P", "T", "Sx2", "Sy2", "SxSy"))
    along, shear, in_plane = sx2 - sy2, 2 * sxsy, sx2 + sy2
    raw_density = f[FIELD_NAMES.index("P")] * float(n_cells) / f[0].size  # cells per grid pixel
    per_paper_pixel = (PAPER_PIXEL_SIZE / pixel_size) ** 2
    area = np.count_nonzero(raw_density * per_paper_pixel > DENSITY_THRESHOLD) * pixel_size ** 2
    return {"alignment": math.hypot(along, shear) / in_plane if in_plane > 0 else math.nan,
            "direction": 0.5 * math.degrees(math.atan2(shear, along)),
            "alignment_x": along / in_plane if in_plane > 0 else math.nan,
            "mean_tension": t / p if p > 0 else math.nan,
            "tissue_area": float(area)}


def axial_mean_sd(degrees) -> tuple[float, float]:
    """The mean and spread of axes given as angles in degrees (an axis at 90 is the one at
    -90; `direction`): half the angle of the mean of the doubled angles' unit vectors, in
    (-90, 90], and half the circular standard deviation of the doubled angles, sqrt(-2 ln R)."""
    doubled = np.radians(2 * np.asarray(degrees, dtype=np.float64))
    c, s = float(np.cos(doubled).mean()), float(np.sin(doubled).mean())
    length = math.hypot(c, s)
    spread = 0.5 * math.degrees(math.sqrt(max(-2 * math.log(length), 0.0))) if length > 0 \
        else math.inf
    return 0.5 * math.degrees(math.atan2(s, c)), spread


def axial_difference(a: float, b: float) -> float:
    """a - b for axes in degrees, wrapped to (-90, 90]: 89 and -89 lie 2 degrees apart."""
    d = (float(a) - float(b)) % 180.0
    return d - 180.0 if d > 90.0 else d


def statistics_table(
    fields_batch: np.ndarray, pixel_size: float, n_cells: np.ndarray | None = None
) -> pd.DataFrame:
    """mould_statistics for each sample of fields_batch (S, 8, H, W): a DataFrame with one
    row per sample (index 0..S-1) and the columns STATISTICS. n_cells: (S,) or None."""
    fields_batch = np.asarray(fields_batch)
    if fields_batch.ndim != 4:
        raise ValueError(f"fields_batch must have shape (S, 8, H, W), got {fields_batch.shape}")
    if n_cells is not None and np.shape(n_cells) != (fields_batch.shape[0],):
        raise ValueError(
            f"n_cells must have shape ({fields_batch.shape[0]},), got {np.shape(n_cells)}"
        )
    rows = [
        mould_statistics(fields, pixel_size, None if n_cells is None else float(n_cells[s]))
        for s, fields in enumerate(fields_batch)
    ]
    return pd.DataFrame(rows, columns=list(STATISTICS))
