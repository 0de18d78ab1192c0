"""Rasterise cells into the paper's 8 fields, and normalise them.

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
The whole-mould statistics of the fields: condor.data.statistics.
"""

from __future__ import annotations

import functools
import math

import numba
import numpy as np

from condor.model.scenes import SIGMA_L0

FIELD_NAMES = ("P", "T", "Sx2", "Sy2", "Sz2", "SxSy", "SxSz", "SySz")

# Half-width of the kernel window in sigma. Per axis the neglected mass is
# erfc(5.5 / sqrt 2) = 3.8e-8, so at most 7.6e-8 of a cell's 2-D mass is dropped.
WINDOW_SIGMAS = 5.5


def window_width(pixels_per_sigma: float) -> int:
    """Number of pixels per axis in the kernel window for sigma = `pixels_per_sigma` px.

    The window [floor(u - R), floor(u - R) + width) covers [u - R, u + R] for every
    cell coordinate u (in px), with R = WINDOW_SIGMAS * sigma_px.
    """
    reach = WINDOW_SIGMAS * pixels_per_sigma
    return int(math.floor(2.0 * reach)) + 2


# The 1-D weights as piecewise polynomials. With t = u - R (u the cell's coordinate in px, R the
# reach) the window starts at k0 = floor(t), and the W weights depend on the cell only through
# f = t - k0 in [0, 1):
#     w_k(f) = (erf(s (k + 1 - R - f)) - erf(s (k - R - f))) / 2,   s = 1 / (sqrt2 sigma_px).
# `_weight_table` splits [0, 1) into M pieces and stores each weight's Taylor polynomial of
# degree TAYLOR_DEGREE about the start of each piece; a cell's W weights are then W Horner
# evaluations in one shared offset, instead of W + 1 erf calls. M is the smallest power of two
# with s / M <= 1/64, where the first neglected term is below 1e-18 (Cramer's bound on
# Hermite functions), so the polynomials are as accurate as the arithmetic: relative errors
# of 1e-14 at most in every pixel, tails included (tested to 1e-13), where a difference of two
# erf values near 1 is only accurate to 1e-16 absolute; the two differ by about that.
TAYLOR_DEGREE = 8
TAYLOR_STEP = 1.0 / 64.0  # the most a piece spans, in units of sqrt2 sigma


@functools.lru_cache(maxsize=32)
def _weight_table(sigma_px: float) -> np.ndarray:
    """Taylor coefficients (M, TAYLOR_DEGREE + 1, W) of the W window weights in f on each of
    M pieces [m / M, (m + 1) / M) (see above); read-only, one per sigma in px."""
    s = 1.0 / (math.sqrt(2.0) * sigma_px)
    pieces = 1 << max(0, math.ceil(math.log2(s / TAYLOR_STEP)))
    table = np.empty((pieces, TAYLOR_DEGREE + 1, window_width(sigma_px)))
    _fill_weight_table(WINDOW_SIGMAS * sigma_px, s, table)
    table.setflags(write=False)
    return table


@numba.njit(cache=True)
def _fill_weight_table(reach, s, table):
    pieces, terms, width = table.shape
    x = np.empty(width + 1)
    edge = np.empty(width + 1)
    q_before, q, q_next = np.empty(width + 1), np.empty(width + 1), np.empty(width + 1)
    for m in range(pieces):
        for j in range(width + 1):  # the window's edges, in units of sqrt2 sigma
            x[j] = s * ((j - m / pieces) - reach)
        # Degree 0: each pixel's mass, from erfc in the tails (no cancellation of erf near 1).
        for k in range(width):
            a, b = x[k], x[k + 1]
            if a >= 0.0:
                table[m, 0, k] = 0.5 * (math.erfc(a) - math.erfc(b))
            elif b <= 0.0:
                table[m, 0, k] = 0.5 * (math.erfc(-b) - math.erfc(-a))
            else:
                table[m, 0, k] = 0.5 * (math.erf(b) - math.erf(a))
        # Degree n >= 1: d^n/df^n erf(s (j - R - f)) / n! = -(2/sqrt pi) e^{-x^2} q_n(x), with
        # q_n = H_{n-1}(x) s^n / n! (Hermite polynomials; q_1 = s, q_2 = x s^2).
        for j in range(width + 1):
            q_before[j], q[j] = 0.0, s
        for n in range(1, terms):
            for j in range(width + 1):
                edge[j] = -q[j] * (2.0 / math.sqrt(math.pi)) * math.exp(-x[j] * x[j])
                q_next[j] = (2.0 * s * x[j] * q[j]
                             - 2.0 * (n - 1) * s * s * q_before[j] / n) / (n + 1)
            for k in range(width):
                table[m, n, k] = 0.5 * (edge[k + 1] - edge[k])
            for j in range(width + 1):
                q_before[j], q[j] = q[j], q_next[j]


@numba.njit(cache=True)
def _axis_weights(coord_px, reach, table, first, weights):
    """Fill first[i] and weights[i, :] for coordinates in pixel units (edges at integers)."""
    pieces, width = table.shape[0], table.shape[2]
    for i in range(coord_px.shape[0]):
        k0 = math.floor(coord_px[i] - reach)
        first[i] = int(k0)
        # The offset as (u - k0) - R: u - k0 is exact (or nearly: it lies in [R, R + 1)), so
        # f carries no rounding of u's own size, whatever R is.
        f = (coord_px[i] - k0) - reach
        m = min(max(int(f * pieces), 0), pieces - 1)
        d = f - m / pieces
        row, coefficients = weights[i], table[m]
        for k in range(width):  # the degree a constant: Horner unrolled, vectorised over k
            acc = coefficients[TAYLOR_DEGREE, k]
            for n in range(TAYLOR_DEGREE - 1, -1, -1):
                acc = acc * d + coefficients[n, k]
            row[k] = acc


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
    check_finite("coord", coord)
    _check_grid(pixels, pixel_size, sigma)
    coord_px = coord / pixel_size
    if coord.size and np.abs(coord_px).max() > 1e15:  # floor() to int64 would overflow
        raise ValueError(f"coord {coord[np.argmax(np.abs(coord_px))]} l0 is too far from the grid")
    sigma_px = sigma / pixel_size
    table = _weight_table(sigma_px)
    first = np.empty(coord.shape[0], dtype=np.int64)
    weights = np.empty((coord.shape[0], table.shape[2]), dtype=np.float64)
    _axis_weights(coord_px, WINDOW_SIGMAS * sigma_px, table, first, weights)
    return first, weights


# The splat. Cell by cell, each of a cell's W rows is a read, an add and a write of the grid
# per multiply (W x W x C of them), and a cell's window (78 KB at 256 px) does not stay in the
# core's first cache. So the cells are sorted by the bin of their window's first pixel
# (`_cell_order`) and taken in groups of GROUP cells whose windows start within `span` px of
# each other (`_cell_groups`; a group that falls short takes 4 cells, else one): each row of
# the group's union window is then read and written once for GROUP multiply-adds. A cell's
# terms are the same products as cell by cell (wy * (wx * value)), added to a pixel in a fixed
# order (group by group, cells in group order), so the fields differ from a cell-by-cell sum
# by rounding only, and are the same bits on any number of threads (bands of rows).
GROUP = 8


def _group_span(width: int) -> int:
    """How far apart (px, each axis) the windows of one group may start: a quarter window."""
    return max(1, width // 4)


@numba.njit(cache=True)
def _cell_order(coord_px, reach, width, height, breadth, bin_px):
    """Indices of the cells (coord_px (N, 2): x, y in px) whose window meets the grid, stably
    sorted by the bin_px x bin_px bin of their window's first pixel (rows of bins, then bins
    along x); the window starts where `_axis_weights` puts it."""
    n_bins_x = (breadth + width) // bin_px + 1
    n_bins = ((height + width) // bin_px + 1) * n_bins_x
    key = np.empty(coord_px.shape[0], dtype=np.int64)
    start = np.zeros(n_bins + 1, dtype=np.int64)
    for i in range(coord_px.shape[0]):
        x0 = int(math.floor(coord_px[i, 0] - reach))
        y0 = int(math.floor(coord_px[i, 1] - reach))
        if y0 + width <= 0 or y0 >= height or x0 + width <= 0 or x0 >= breadth:
            key[i] = -1
            continue
        key[i] = ((y0 + width) // bin_px) * n_bins_x + (x0 + width) // bin_px
        start[key[i] + 1] += 1
    for b in range(n_bins):
        start[b + 1] += start[b]
    order = np.empty(start[n_bins], dtype=np.int64)
    for i in range(coord_px.shape[0]):
        if key[i] >= 0:
            order[start[key[i]]] = i
            start[key[i]] += 1
    return order


@numba.njit(cache=True)
def _cell_groups(first_y, first_x, width, height, breadth, span):
    """Split the cells, in their order, into runs of GROUP, 4 or 1 whose windows start within
    `span` px of each other. Returns bounds (G + 1,), group g being cells
    bounds[g]:bounds[g + 1], and boxes (G, 4): its union window clipped to the grid, rows
    [boxes[g, 0], boxes[g, 1]) and columns [boxes[g, 2], boxes[g, 3])."""
    n = first_y.shape[0]
    bounds = np.empty(n + 1, dtype=np.int64)
    boxes = np.empty((n, 4), dtype=np.int64)
    g, a = 0, 0
    while a < n:
        y_min = y_max = first_y[a]
        x_min = x_max = first_x[a]
        box4 = (y_min, y_max, x_min, x_max)
        k = 1
        while k < GROUP and a + k < n:
            y0, y1 = min(y_min, first_y[a + k]), max(y_max, first_y[a + k])
            x0, x1 = min(x_min, first_x[a + k]), max(x_max, first_x[a + k])
            if y1 - y0 > span or x1 - x0 > span:
                break
            y_min, y_max, x_min, x_max = y0, y1, x0, x1
            k += 1
            if k == 4:
                box4 = (y_min, y_max, x_min, x_max)
        if k < GROUP:
            if k >= 4:
                k = 4
                y_min, y_max, x_min, x_max = box4
            else:
                k = 1
                y_min = y_max = first_y[a]
                x_min = x_max = first_x[a]
        bounds[g] = a
        boxes[g, 0] = max(0, y_min)
        boxes[g, 1] = min(height, y_max + width)
        boxes[g, 2] = max(0, x_min)
        boxes[g, 3] = min(breadth, x_max + width)
        g += 1
        a += k
    bounds[g] = n
    return bounds[: g + 1], boxes[:g]


@numba.njit(cache=True, inline="always")
def _template(i, first_y, wy, first_x, wx, values, y0, y1, x0, x1, row_weights, template, value):
    """Cell i over the box rows [y0, y1) x columns [x0, x1), zero outside its window:
    row_weights[r] = its wy of row y0 + r, template[(x - x0) * C + c] = its wx of column x
    times its value c (the same products as cell by cell). value: (C,) scratch."""
    width = wy.shape[1]
    n_channels = values.shape[1]
    fy, fx = first_y[i], first_x[i]
    # The cell's part of the box; in a band of rows it may have none (ys = ye).
    xs, ys = max(x0, fx), max(y0, fy)
    xe, ye = max(xs, min(x1, fx + width)), max(ys, min(y1, fy + width))
    template[: (xs - x0) * n_channels] = 0.0
    template[(xe - x0) * n_channels : (x1 - x0) * n_channels] = 0.0
    value[:] = values[i]
    window = template[(xs - x0) * n_channels : (xe - x0) * n_channels]
    column = wx[i, xs - fx : xe - fx]
    if n_channels == 8:  # a count known to the compiler: one vector multiply per pixel
        for k in range(xe - xs):
            a = column[k]
            for c in range(8):
                window[k * 8 + c] = a * value[c]
    else:
        for k in range(xe - xs):
            a = column[k]
            for c in range(n_channels):
                window[k * n_channels + c] = a * value[c]
    row_weights[: ys - y0] = 0.0
    row_weights[ys - y0 : ye - y0] = wy[i, ys - fy : ye - fy]
    row_weights[ye - y0 : y1 - y0] = 0.0


@numba.njit(cache=True)
def _splat_rows(first_y, wy, first_x, wx, values, bounds, boxes, span, y_lo, y_hi, grid):
    """Add every group's cells into rows [y_lo, y_hi) of grid[y, x, channel]."""
    width = wy.shape[1]
    n_channels = values.shape[1]
    height, breadth = grid.shape[0], grid.shape[1]
    rows = grid.reshape((height, breadth * n_channels))
    # The group's templates, each starting on a 64-byte boundary like the grid's pixels (a
    # vector load that straddles two cache lines costs two).
    length = -(-(width + span) * n_channels // 8) * 8
    store = np.empty(GROUP * length + 8)
    skip = (-store.ctypes.data % 64) // 8
    t = store[skip : skip + GROUP * length].reshape((GROUP, length))
    w = np.empty((GROUP, width + span))
    value = np.empty(n_channels)
    for g in range(bounds.shape[0] - 1):
        y0, y1 = max(y_lo, boxes[g, 0]), min(y_hi, boxes[g, 1])
        if y1 <= y0:
            continue
        x0, x1 = boxes[g, 2], boxes[g, 3]
        a, k = bounds[g], bounds[g + 1] - bounds[g]
        for q in range(k):
            _template(a + q, first_y, wy, first_x, wx, values, y0, y1, x0, x1, w[q], t[q],
                      value)
        s, run = x0 * n_channels, (x1 - x0) * n_channels
        if k == 8:
            t0, t1, t2, t3, t4, t5, t6, t7 = t[0], t[1], t[2], t[3], t[4], t[5], t[6], t[7]
            for y in range(y0, y1):
                r = y - y0
                w0, w1, w2, w3 = w[0, r], w[1, r], w[2, r], w[3, r]
                w4, w5, w6, w7 = w[4, r], w[5, r], w[6, r], w[7, r]
                row = rows[y, s : s + run]
                for j in range(run):
                    row[j] = (row[j] + w0 * t0[j] + w1 * t1[j] + w2 * t2[j] + w3 * t3[j]
                              + w4 * t4[j] + w5 * t5[j] + w6 * t6[j] + w7 * t7[j])
        elif k == 4:
            t0, t1, t2, t3 = t[0], t[1], t[2], t[3]
            for y in range(y0, y1):
                r = y - y0
                w0, w1, w2, w3 = w[0, r], w[1, r], w[2, r], w[3, r]
                row = rows[y, s : s + run]
                for j in range(run):
                    row[j] = row[j] + w0 * t0[j] + w1 * t1[j] + w2 * t2[j] + w3 * t3[j]
        else:
            t0 = t[0]
            for y in range(y0, y1):
                w0 = w[0, y - y0]
                row = rows[y, s : s + run]
                for j in range(run):
                    row[j] += w0 * t0[j]


# Twice, like the anneal's sweeps: the bands of rows one after another, and in parallel
# (numba's prange). A band adds the same terms to its pixels in the same order either way.

@numba.njit(cache=True)
def _splat_serial(first_y, wy, first_x, wx, values, bounds, boxes, span, edges, grid):
    for b in range(edges.shape[0] - 1):
        _splat_rows(first_y, wy, first_x, wx, values, bounds, boxes, span, edges[b],
                    edges[b + 1], grid)


@numba.njit(cache=True, parallel=True)
def _splat_parallel(first_y, wy, first_x, wx, values, bounds, boxes, span, edges, grid):
    for b in numba.prange(edges.shape[0] - 1):
        _splat_rows(first_y, wy, first_x, wx, values, bounds, boxes, span, edges[b],
                    edges[b + 1], grid)


def _zeros_aligned(shape: tuple[int, ...]) -> np.ndarray:
    """np.zeros(shape) starting on a 64-byte boundary (a cache line), so that the splat's
    vector loads and stores of a pixel's 8 channels never straddle two."""
    size = math.prod(shape)
    store = np.zeros(size + 8)
    skip = (-store.ctypes.data % 64) // 8
    return store[skip : skip + size].reshape(shape)


def _fields64(
    xy: np.ndarray, values: np.ndarray, box: float, pixels: int, sigma: float, threads: int = 1
) -> np.ndarray:
    """rasterise's float64 grid (pixels, pixels, C), indexed [y, x, channel]; the inputs are
    validated by the caller."""
    pixel_size = box / pixels
    sigma_px = sigma / pixel_size
    reach = WINDOW_SIGMAS * sigma_px
    table = _weight_table(sigma_px)
    width = table.shape[2]
    # Cells further than (window + 3 px) off the grid add nothing; clamping them there keeps
    # their window off the grid and the pixel indices far from integer overflow.
    margin = (reach + 3.0) * pixel_size
    coord_px = np.clip(xy, -margin, box + margin) / pixel_size
    span = _group_span(width)
    # The cells that meet the grid, in bin order, so that a group's cells lie side by side in
    # memory too.
    order = _cell_order(coord_px, reach, width, pixels, pixels, max(1, span // 2))
    coord_px = coord_px[order]
    values = np.ascontiguousarray(values[order], dtype=np.float64)
    n = order.shape[0]
    first_x, first_y = np.empty(n, dtype=np.int64), np.empty(n, dtype=np.int64)
    wx, wy = np.empty((n, width)), np.empty((n, width))
    _axis_weights(np.ascontiguousarray(coord_px[:, 0]), reach, table, first_x, wx)
    _axis_weights(np.ascontiguousarray(coord_px[:, 1]), reach, table, first_y, wy)
    bounds, boxes = _cell_groups(first_y, first_x, width, pixels, pixels, span)
    grid = _zeros_aligned((pixels, pixels, values.shape[1]))
    bands = max(1, min(int(threads), numba.config.NUMBA_NUM_THREADS, pixels))
    edges = np.linspace(0, pixels, bands + 1).round().astype(np.int64)
    args = (first_y, wy, first_x, wx, values, bounds, boxes, span, edges, grid)
    if bands == 1:
        _splat_serial(*args)
    else:
        before = numba.get_num_threads()
        numba.set_num_threads(bands)
        try:
            _splat_parallel(*args)
        finally:
            numba.set_num_threads(before)
    return grid


def rasterise(
    xy: np.ndarray,
    values: np.ndarray,
    box: float,
    pixels: int,
    sigma: float = SIGMA_L0,
    threads: int = 1,
) -> np.ndarray:
    """Kernel density estimate of per-cell values on a pixels x pixels grid over [0, box]^2.

    xy: (N, 2) cell positions (x, y), l0. values: (N, C) per-cell values (or (N,) for C = 1).
    box, sigma: l0. threads: the rows are split into this many bands, added in parallel
    (the same bits on any number). Returns (C, pixels, pixels) float32 indexed
    [channel, y, x]; each pixel holds sum_i values[i, c] * w_{i,p} (accumulated in float64).
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
    check_finite("xy", xy)
    check_finite("values", values)
    _check_grid(pixels, box, sigma)
    grid = _fields64(xy, values, box, pixels, sigma, threads)
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
    check_finite("orientations", s)
    check_finite("tension", tau)
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


def check_finite(name: str, array: np.ndarray) -> None:
    """ValueError naming `name` and the first index where `array` holds NaN or inf."""
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
