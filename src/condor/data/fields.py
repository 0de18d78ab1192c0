"""Rasterise cells into the paper's 8 fields and compute whole-mould statistics.

The paper's kernel density estimate (Machine learning section): every cell i with value z_i
adds z_i * w_{i,p} to pixel p, where w_{i,p} is the integral over the pixel of an isotropic
2-D Gaussian of width sigma centred on the cell's (x, y) projection. The integral is separable:

    w_{i,p} = wx * wy,
    wx = (erf((x_hi - x_i) / (sqrt2 sigma)) - erf((x_lo - x_i) / (sqrt2 sigma))) / 2

Lengths are in l0; sigma is fixed in l0 (`SIGMA_L0`, 3 px at 256 px over 62.5 l0), so fields
at any resolution sample the same smooth density. The Gaussian is truncated to a window of
`WINDOW_SIGMAS` sigma either side of the cell, which neglects less than 1e-7 of each cell's
mass (see `docs/fields.md`). Mass that falls outside the grid is lost (not wrapped or
folded back).

Channels, in order: P (density, value 1), T (tension tau), Sx2, Sy2, Sz2, SxSy, SxSz, SySz.
"""

from __future__ import annotations

import math

import numba
import numpy as np
import pandas as pd

from condor.model.scenes import PAPER_BOX, PAPER_PIXELS, SIGMA_L0

FIELD_NAMES = ("P", "T", "Sx2", "Sy2", "Sz2", "SxSy", "SxSz", "SySz")

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

# Half-width of the kernel window in sigma. Per axis the neglected mass is
# erfc(5.5 / sqrt 2) = 3.8e-8, so at most 7.6e-8 of a cell's 2-D mass is dropped.
WINDOW_SIGMAS = 5.5

# The paper's pixel side l_p (62.5 l0 / 256 = 125 l0 / 512): statistics are expressed in it.
PAPER_PIXEL_SIZE = PAPER_BOX / PAPER_PIXELS

# The paper's area threshold: density above 0.2 cells per paper pixel.
DENSITY_THRESHOLD = 0.2


def window_width(pixels_per_sigma: float) -> int:
    """Number of pixels per axis in the kernel window for sigma = `pixels_per_sigma` px.

    The window [floor(u - R), floor(u - R) + width) covers [u - R, u + R] for every
    cell coordinate u (in px), with R = WINDOW_SIGMAS * sigma_px.
    """
    reach = WINDOW_SIGMAS * pixels_per_sigma
    return int(math.floor(2.0 * reach)) + 2


@numba.njit(cache=True)
def _axis_weights(coord_px, reach, width, sigma_px, first, weights):
    """Fill first[i] and weights[i, :] for coordinates in pixel units (edges at integers)."""
    scale = 1.0 / (math.sqrt(2.0) * sigma_px)
    for i in range(coord_px.shape[0]):
        u = coord_px[i]
        k0 = int(math.floor(u - reach))
        first[i] = k0
        lower = math.erf((k0 - u) * scale)
        for k in range(width):
            upper = math.erf((k0 + k + 1 - u) * scale)
            weights[i, k] = 0.5 * (upper - lower)
            lower = upper


def pixel_weights(
    coord: np.ndarray, pixels: int, pixel_size: float, sigma: float
) -> tuple[np.ndarray, np.ndarray]:
    """1-D pixel-integrated Gaussian weights along one axis.

    coord: (N,) cell coordinates, l0 (pixel k covers [k, k+1) * pixel_size).
    pixels: grid side (only validated here: windows may extend past the grid; the
        rasteriser drops the pixels outside).
    pixel_size, sigma: l0.
    Returns (first, weights): first (N,) int64, the index of the window's first pixel
    (may be negative or past the grid), and weights (N, W) float64, the Gaussian mass of
    each of the W window pixels. The 2-D weight of pixel (iy, ix) is wy * wx.
    """
    coord = np.asarray(coord, dtype=np.float64)
    if coord.ndim != 1:
        raise ValueError(f"coord must be 1-D, got shape {coord.shape}")
    _check_finite("coord", coord)
    _check_grid(pixels, pixel_size, sigma)
    coord_px = coord / pixel_size
    if coord.size and np.abs(coord_px).max() > 1e15:  # floor() to int64 would overflow
        raise ValueError(f"coord {coord[np.argmax(np.abs(coord_px))]} l0 is too far from the grid")
    sigma_px = sigma / pixel_size
    width = window_width(sigma_px)
    first = np.empty(coord.shape[0], dtype=np.int64)
    weights = np.empty((coord.shape[0], width), dtype=np.float64)
    _axis_weights(coord_px, WINDOW_SIGMAS * sigma_px, width, sigma_px, first, weights)
    return first, weights


@numba.njit(cache=True)
def _splat(first_y, wy, first_x, wx, values, grid):
    """Add every cell's separable kernel times its values into grid[y, x, channel].

    With channel fastest, one cell's window row is a contiguous run of (pixels x channels)
    numbers: build it once per cell (wx times values), then add wy times it to each row,
    a plain axpy that LLVM vectorises.
    """
    n_cells, width = wy.shape
    n_channels = values.shape[1]
    height, breadth = grid.shape[0], grid.shape[1]
    rows = grid.reshape((height, breadth * n_channels))
    template = np.empty(width * n_channels)
    for i in range(n_cells):
        # Clip the window to the grid once per cell.
        ky0 = max(0, -first_y[i])
        ky1 = min(width, height - first_y[i])
        kx0 = max(0, -first_x[i])
        kx1 = min(width, breadth - first_x[i])
        if ky1 <= ky0 or kx1 <= kx0:
            continue
        run = (kx1 - kx0) * n_channels
        for kx in range(kx0, kx1):
            for c in range(n_channels):
                template[(kx - kx0) * n_channels + c] = wx[i, kx] * values[i, c]
        start = (first_x[i] + kx0) * n_channels
        for ky in range(ky0, ky1):
            row = rows[first_y[i] + ky, start : start + run]
            w = wy[i, ky]
            for j in range(run):
                row[j] += w * template[j]


def rasterise(
    xy: np.ndarray, values: np.ndarray, box: float, pixels: int, sigma: float = SIGMA_L0
) -> np.ndarray:
    """Kernel density estimate of per-cell values on a pixels x pixels grid over [0, box]^2.

    xy: (N, 2) cell positions (x, y), l0. values: (N, C) per-cell values (or (N,) for C = 1).
    box, sigma: l0. Returns (C, pixels, pixels) float32 indexed [channel, y, x]; each pixel
    holds sum_i values[i, c] * w_{i,p} (accumulated in float64).
    """
    xy = np.asarray(xy, dtype=np.float64)
    values = np.asarray(values, dtype=np.float64)
    if values.ndim == 1:
        values = values[:, None]
    if xy.ndim != 2 or xy.shape[1] != 2:
        raise ValueError(f"xy must have shape (N, 2), got {xy.shape}")
    if values.ndim != 2 or values.shape[0] != xy.shape[0]:
        raise ValueError(
            f"values must have shape (N, C) with N = {xy.shape[0]} cells, got {values.shape}"
        )
    _check_finite("xy", xy)
    _check_finite("values", values)
    _check_grid(pixels, box, sigma)
    pixel_size = box / pixels
    # Cells further than (window + 3 px) off the grid add nothing; clamping them there keeps
    # their window off the grid and the pixel indices far from integer overflow.
    margin = (WINDOW_SIGMAS * sigma / pixel_size + 3.0) * pixel_size
    xy = np.clip(xy, -margin, box + margin)
    first_x, wx = pixel_weights(xy[:, 0], pixels, pixel_size, sigma)
    first_y, wy = pixel_weights(xy[:, 1], pixels, pixel_size, sigma)
    grid = np.zeros((pixels, pixels, values.shape[1]), dtype=np.float64)
    _splat(first_y, wy, first_x, wx, np.ascontiguousarray(values), grid)
    return np.ascontiguousarray(grid.transpose(2, 0, 1), dtype=np.float32)


def cell_values(orientations: np.ndarray, tension: np.ndarray) -> np.ndarray:
    """Per-cell channel values (N, 8) in FIELD_NAMES order: 1, tau, sx^2, sy^2, sz^2, sx sy,
    sx sz, sy sz.

    orientations: (N, 3) unit vectors s_i (|s| = 1 within 1e-3, so that Sx2 + Sy2 + Sz2 = P).
    tension: (N,) average tension tau_i (dimensionless, kappa0 l0 units).
    """
    s = np.asarray(orientations, dtype=np.float64)
    tau = np.asarray(tension, dtype=np.float64)
    if s.ndim != 2 or s.shape[1] != 3:
        raise ValueError(f"orientations must have shape (N, 3), got {s.shape}")
    if tau.shape != (s.shape[0],):
        raise ValueError(f"tension must have shape ({s.shape[0]},), got {tau.shape}")
    _check_finite("orientations", s)
    _check_finite("tension", tau)
    norms = np.linalg.norm(s, axis=1)
    bad = np.flatnonzero(np.abs(norms - 1.0) > 1e-3)
    if bad.size:
        raise ValueError(
            f"orientations must be unit vectors; cell {bad[0]} has |s| = {norms[bad[0]]:.6g}"
        )
    sx, sy, sz = s[:, 0], s[:, 1], s[:, 2]
    return np.stack(
        [np.ones_like(tau), tau, sx * sx, sy * sy, sz * sz, sx * sy, sx * sz, sy * sz], axis=1
    )


def cell_fields(
    positions: np.ndarray,
    orientations: np.ndarray,
    tension: np.ndarray,
    box: float,
    pixels: int,
    sigma: float = SIGMA_L0,
) -> np.ndarray:
    """The 8 fields (8, pixels, pixels) float32 of a cell configuration.

    positions: (N, 3) or (N, 2), l0; z is dropped (cells project to the x-y plane).
    Fixed tether cells are included like any other cell by passing them in.
    """
    positions = np.asarray(positions, dtype=np.float64)
    if positions.ndim != 2 or positions.shape[1] not in (2, 3):
        raise ValueError(f"positions must have shape (N, 3) or (N, 2), got {positions.shape}")
    values = cell_values(orientations, tension)
    if values.shape[0] != positions.shape[0]:
        raise ValueError(
            f"positions has {positions.shape[0]} cells but orientations has {values.shape[0]}"
        )
    return rasterise(positions[:, :2], values, box, pixels, sigma)


def normalise(fields: np.ndarray, n_cells) -> np.ndarray:
    """Density-normalised fields: fields * N_p / N_c (paper eq. for Z-bar).

    fields: (..., H, W); N_p = H * W pixels. n_cells: N_c, a positive number, or an array
    matching the leading axes of fields (e.g. (S,) for a batch (S, C, H, W)).
    For predicted fields, pass the predicted density sum P.sum() as n_cells.
    Returns the dtype of fields when it is floating, else float64.
    """
    fields = np.asarray(fields)
    if fields.ndim < 2:
        raise ValueError(f"fields must have at least 2 dimensions (H, W), got {fields.shape}")
    n_cells = np.asarray(n_cells, dtype=np.float64)
    if n_cells.shape != fields.shape[: n_cells.ndim] or n_cells.ndim > fields.ndim - 2:
        raise ValueError(
            f"n_cells of shape {n_cells.shape} does not match the leading axes of fields "
            f"{fields.shape}"
        )
    if not np.all(np.isfinite(n_cells)) or np.any(n_cells <= 0):
        raise ValueError(f"n_cells must be positive and finite, got {n_cells}")
    n_pixels = fields.shape[-1] * fields.shape[-2]
    scale = n_pixels / n_cells.reshape(n_cells.shape + (1,) * (fields.ndim - n_cells.ndim))
    dtype = fields.dtype if fields.dtype.kind == "f" else np.float64
    return (fields * scale).astype(dtype)


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
    _check_finite("fields", fields)
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


def _check_finite(name: str, array: np.ndarray) -> None:
    if not np.all(np.isfinite(array)):
        bad = np.argwhere(~np.isfinite(array))[0]
        raise ValueError(f"{name} contains NaN or inf, first at index {tuple(bad.tolist())}")


def _check_grid(pixels: int, length: float, sigma: float) -> None:
    """Validate a grid side `pixels` and positive lengths (box or pixel size, sigma), l0."""
    if isinstance(pixels, bool) or not isinstance(pixels, (int, np.integer)) or pixels < 1:
        raise ValueError(f"pixels must be a positive integer, got {pixels!r}")
    if not (np.isfinite(length) and length > 0):
        raise ValueError(f"box / pixel size must be positive and finite, got {length!r}")
    if not (np.isfinite(sigma) and sigma > 0):
        raise ValueError(f"sigma must be positive and finite, got {sigma!r}")
