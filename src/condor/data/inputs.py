"""What the surrogate sees of a mould: the mask channels, or the lattice channels.

The paper's inputs are two 0/1 masks (`condor.data.moulds.input_channels`: mould, tether), each
pixel judged at its centre. They hide what sets the tension: a post is a few whole pixels at
64 px (tether radii 1.3-4 px), and a tether narrower than a/2 anchors the posts picked within
a/2 (`condor.model.lattice`), so the number of fixed cells it holds is not in the picture at all.
The *lattice channels* are the simulation's own starting point instead: the initial cells of
`condor.model.lattice.build_lattice` (mobile, fixed) rasterised with the fields' kernel
(`condor.data.fields.rasterise`), per pixel in units of a full FCC column (`column_cells`), so the
inside of a mould reads ~1 whatever the scene. They place the outline and every post to a
fraction of a pixel, and their sum times the column unit is N_c. Measured in
experiments/surrogate/README.md ("The inputs"): the tension field's error falls by a third.

A mould known only as a picture has no lattice; `estimate_lattice_channels` places the same
FCC sites over the occupied pixels (as `physics.estimate_n_cells` counts them): approximate,
and measured worse than the masks themselves for training, so the workflow stores the exact
channels (`lattice` in the dataset store) and prediction from a mould file builds them.

The *stress channels* (`spring_stress`, input kind `mechanics`) are a cheap mechanical prior:
the stress of a linear spring network on the pixel grid (springs to the 4 axial and 4
diagonal neighbours inside the mould and its posts) that contracts isotropically with the
post pixels held fixed, sigma_xx and sigma_yy per pixel. Cells align with tension, and the
network alone misreads the orientation of some geometries (experiments/surrogate/README.md, "A mechanical
prior"). Both channels are even under the mirrors and swapped by the transpose. Input kind
`mechanics_shear` adds sigma_xy (`spring_stress(..., shear=True)`), which says how the
principal axes tilt: odd under each mirror, unchanged by the transpose.
"""

from __future__ import annotations

import math
from collections import OrderedDict

import numpy as np

# TrainConfig.inputs; both: masks, then lattice; mechanics: masks, lattice, stress channels
INPUT_KINDS = ("mask", "lattice", "both", "mechanics", "mechanics_shear")
LATTICE_CHANNELS = ("mobile", "fixed")
STRESS_CHANNELS = ("stress_xx", "stress_yy")
SHEAR_CHANNEL = "stress_xy"
# (row, column) offset and stiffness of the spring network's bonds; diagonal springs at half
# the axial stiffness make a square spring lattice elastically isotropic (Poisson ratio 1/3)
SPRING_BONDS = (((0, 1), 1.0), ((1, 0), 1.0), ((1, 1), 0.5), ((1, -1), 0.5))


def column_cells(depth: float, pixel_size: float) -> float:
    """Cells per pixel of a full FCC column of `depth` (the lattice channels' unit): the
    projected site density n_layers / 2 per HALF^2, times the pixel area."""
    from condor.model.lattice import HALF, fcc_layers

    return 0.5 * fcc_layers(depth) * (pixel_size / HALF) ** 2


def rasterise_cells(xy: np.ndarray, weights: np.ndarray, depth: float, box: float,
                    pixels: int, sigma: float) -> np.ndarray:
    """Cells at `xy` (N, 2) with per-channel weights (N, 2) -> lattice channels (2, P, P)
    float32 in column units."""
    from condor.data.fields import rasterise

    image = rasterise(np.asarray(xy, np.float64), np.asarray(weights, np.float64), box, pixels,
                      sigma)
    return (image / column_cells(depth, box / pixels)).astype(np.float32)


def lattice_channels(polygon, tethers, depth: float, box: float, pixels: int,
                     sigma: float) -> np.ndarray:
    """(2, pixels, pixels) float32 [channel, y, x]: the mould's initial mobile and fixed cells
    (condor.model.lattice.lattice_sites) rasterised like the fields, in column units."""
    from condor.model.lattice import lattice_sites

    return channels_of_sites(*lattice_sites(polygon, tethers, depth), depth, box, pixels, sigma)


def channels_of_sites(positions: np.ndarray, fixed: np.ndarray, depth: float, box: float,
                      pixels: int, sigma: float) -> np.ndarray:
    """The lattice channels of cells already placed (condor.model.lattice.lattice_sites)."""
    weights = np.stack([~fixed, fixed], axis=1).astype(np.float64)
    return rasterise_cells(positions[:, :2], weights, depth, box, pixels, sigma)


def of_mould(mould, scene) -> np.ndarray:
    """The lattice channels of a `condor.data.moulds.Mould` on `scene`'s grid."""
    return lattice_channels(mould.polygon, mould.tethers, scene.depth, scene.box, scene.pixels,
                            scene.sigma)


def mask_sites(masks: np.ndarray, pixel_size: float, depth: float):
    """FCC site columns over the occupied pixels of masks (2, H, W) (mould, tether): xy (K, 2)
    of the columns whose (x, y) falls in an occupied pixel, their cell count (K,) and whether
    the pixel is a tether's (K,). The origin is the centre of the occupied pixels' bounding
    box (condor.model.lattice puts it at the polygon's)."""
    from condor.model.lattice import HALF, fcc_layers

    occupied = masks.astype(bool).any(axis=0)  # [y, x]
    if not occupied.any():
        return np.zeros((0, 2)), np.zeros(0), np.zeros(0, bool)
    ys, xs = np.nonzero(occupied)
    cx = 0.5 * (xs.min() + xs.max() + 1) * pixel_size
    cy = 0.5 * (ys.min() + ys.max() + 1) * pixel_size
    h, w = occupied.shape
    p = np.arange(math.floor(-cx / HALF) - 1, math.ceil((w * pixel_size - cx) / HALF) + 2)
    q = np.arange(math.floor(-cy / HALF) - 1, math.ceil((h * pixel_size - cy) / HALF) + 2)
    pp, qq = np.meshgrid(p, q, indexing="ij")
    x, y = cx + pp * HALF, cy + qq * HALF
    col = np.floor(x / pixel_size).astype(int)
    row = np.floor(y / pixel_size).astype(int)
    valid = (col >= 0) & (col < w) & (row >= 0) & (row < h)
    hit = np.zeros_like(valid)
    hit[valid] = occupied[row[valid], col[valid]]
    tether = np.zeros_like(valid)
    tether[valid] = masks[1].astype(bool)[row[valid], col[valid]]
    # layer r holds the sites with p + q + r even
    n_layers = fcc_layers(depth)
    count = np.where((pp + qq) % 2 == 0, (n_layers + 1) // 2, n_layers // 2)
    return np.stack([x[hit], y[hit]], axis=1), count[hit].astype(np.float64), tether[hit]


def estimate_lattice_channels(masks: np.ndarray, pixel_size: float, depth: float,
                              sigma: float) -> np.ndarray:
    """Approximate lattice channels from masks (2, H, W) or (S, 2, H, W) alone (mask_sites;
    tether pixels hold the fixed cells). Exact lattice channels need the geometry."""
    masks = np.asarray(masks)
    batch = masks[None] if masks.ndim == 3 else masks
    if batch.ndim != 4 or batch.shape[1] != 2:
        raise ValueError(f"masks must be (2, H, W) or (S, 2, H, W), got shape {masks.shape}")
    pixels = batch.shape[-1]
    out = np.zeros(batch.shape, dtype=np.float32)
    for s, channels in enumerate(batch):
        xy, count, tether = mask_sites(channels, pixel_size, depth)
        if len(count):
            weights = np.stack([count * ~tether, count * tether], axis=1)
            out[s] = rasterise_cells(xy, weights, depth, pixel_size * pixels, pixels, sigma)
    return out[0] if masks.ndim == 3 else out


def _spring_bonds(domain: np.ndarray):
    """Every bond of the network on the True pixels of `domain` (H, W), all SPRING_BONDS
    directions at once: the flat (row-major) pixel index of each bond's two ends (start,
    end = start + the bond's offset), its stiffness, its length and its unit (x, y) vector
    (each an array over the bonds; the unit vectors (B, 2))."""
    H, W = domain.shape
    flat = np.arange(H * W).reshape(H, W)
    starts, ends, stiffness, lengths, units = [], [], [], [], []
    for (dy, dx), k in SPRING_BONDS:
        y0, y1, x0, x1 = max(0, -dy), min(H, H - dy), max(0, -dx), min(W, W - dx)
        both = domain[y0:y1, x0:x1] & domain[y0 + dy:y1 + dy, x0 + dx:x1 + dx]
        start = flat[y0:y1, x0:x1][both]
        length = math.hypot(dx, dy)
        starts.append(start)
        ends.append(start + dy * W + dx)
        stiffness.append(np.full(len(start), k))
        lengths.append(np.full(len(start), length))
        units.append(np.broadcast_to(np.array([dx, dy]) / length, (len(start), 2)))
    return (np.concatenate(starts), np.concatenate(ends), np.concatenate(stiffness),
            np.concatenate(lengths), np.concatenate(units))


def _banded_order(free: np.ndarray, start: np.ndarray, end: np.ndarray):
    """The free pixels numbered row by row or column by column, whichever keeps every pair of
    bonded free pixels closer in the numbering: (index (H*W,) flat pixel -> its number, or -1
    for a pixel that is not free; the largest number difference across a bond)."""
    H, W = free.shape
    best = None
    for by_columns in (False, True):
        index = np.full(H * W, -1, dtype=np.int64)
        where = np.flatnonzero((free.T if by_columns else free).ravel())
        if by_columns:  # a flat index of the transpose, x * H + y, back to y * W + x
            where = (where % H) * W + where // H
        index[where] = np.arange(len(where))
        i, j = index[start], index[end]
        both = (i >= 0) & (j >= 0)
        width = int(np.abs(i[both] - j[both]).max()) if both.any() else 0
        if best is None or width < best[1]:
            best = (index, width)
    return best


def spring_displacement(masks: np.ndarray) -> np.ndarray:
    """(2, H, W) masks (mould, tether) -> (H, W, 2) displacements (x, y), in pixels per unit
    contraction strain, of the linear spring network over mould | tether whose rest lengths
    shrink by that strain, the tether pixels held fixed: the minimiser of
    E(u) = sum over bonds of k/2 (n . (u_j - u_i) + |d|)^2. Zero without posts (the free
    network contracts without stress; its rigid motions are pinned by a 1e-9 ridge).

    One direct solve of K u = f (K the Hessian of E over the free pixels' 2 coordinates,
    f = -grad E at u = 0): K is symmetric positive definite (the ridge pins a part the posts
    do not hold) and banded once the free pixels are numbered along the mould's narrower
    direction (_banded_order: about 2 x 50 + 1 diagonals at 64 px), so a banded Cholesky
    (LAPACK's pbsv) solves it; it agrees with a general sparse LU solve of the same system to
    round-off (tested), several times faster."""
    import scipy.linalg

    masks = np.asarray(masks)
    if masks.ndim != 3 or masks.shape[0] != 2:
        raise ValueError(f"masks must have shape (2, H, W), got {masks.shape}")
    domain, fixed = (masks[0] > 0) | (masks[1] > 0), masks[1] > 0
    H, W = domain.shape
    u = np.zeros((H * W, 2))
    free = domain & ~fixed
    if not fixed.any() or not free.any():
        return u.reshape(H, W, 2)
    start, end, k, length, unit = _spring_bonds(domain)
    index, width = _banded_order(free, start, end)
    n, kd = 2 * int(free.sum()), 2 * width + 1  # unknowns; superdiagonals of K
    i, j = index[start], index[end]
    # a bond's 2x2 block k n n^T: + on both ends' diagonal blocks, - between two free ends;
    # the upper triangle only, stored as LAPACK's upper band: K[r, c] at ab[kd + r - c, c]
    kxx, kxy, kyy = k * unit[:, 0] ** 2, k * unit[:, 0] * unit[:, 1], k * unit[:, 1] ** 2
    rows, cols, values = [], [], []
    for p in (i, j):
        on = p >= 0
        q = 2 * p[on]
        rows += [q, q, q + 1]
        cols += [q, q + 1, q + 1]
        values += [kxx[on], kxy[on], kyy[on]]
    on = (i >= 0) & (j >= 0)
    lo, hi = 2 * np.minimum(i[on], j[on]), 2 * np.maximum(i[on], j[on])
    rows += [lo, lo, lo + 1, lo + 1]
    cols += [hi, hi + 1, hi, hi + 1]
    values += [-kxx[on], -kxy[on], -kxy[on], -kyy[on]]
    rows, cols = np.concatenate(rows), np.concatenate(cols)
    band = np.bincount((kd + rows - cols) * n + cols, np.concatenate(values),
                       minlength=(kd + 1) * n).reshape(kd + 1, n)
    band[kd] += 1e-9
    # -dE/du at u = 0: each bond pulls its ends together with k |d|
    pull = (k * length)[:, None] * unit
    rhs = np.zeros(n)
    for p, sign in ((i, 1.0), (j, -1.0)):
        on = p >= 0
        for a in range(2):
            rhs += np.bincount(2 * p[on] + a, sign * pull[on, a], minlength=n)
    solved = scipy.linalg.solveh_banded(band, rhs, check_finite=False)
    numbered = index >= 0
    u[numbered] = solved.reshape(-1, 2)[index[numbered]]
    return u.reshape(H, W, 2)


def spring_stress(masks: np.ndarray, shear: bool = False) -> np.ndarray:
    """(2, H, W) masks -> (2, H, W) float32 stress channels (STRESS_CHANNELS) of the
    contracting spring network (`spring_displacement`): per pixel, half of each bond's tension
    t = k (n . du + |d|) (its stretch beyond the rest length; > 0 pulling) times n_a n_b |d|,
    summed over the pixel's bonds; units of k per unit contraction strain; 0 outside the
    mould and its posts. `shear`: (3, H, W), SHEAR_CHANNEL (a = x, b = y) third."""
    masks = np.asarray(masks)
    u = spring_displacement(masks).reshape(-1, 2)
    domain = (masks[0] > 0) | (masks[1] > 0)
    H, W = domain.shape
    components = ((0, 0), (1, 1), (0, 1)) if shear else ((0, 0), (1, 1))
    stress = np.zeros((len(components), H * W))
    if not np.any(masks[1] > 0):
        return stress.reshape(-1, H, W).astype(np.float32)
    start, end, k, length, unit = _spring_bonds(domain)
    tension = k * (np.einsum("ba,ba->b", u[end] - u[start], unit) + length)
    for c, (a, b) in enumerate(components):
        share = 0.5 * tension * unit[:, a] * unit[:, b] * length
        stress[c] = np.bincount(start, share, minlength=H * W) + \
            np.bincount(end, share, minlength=H * W)
    return stress.reshape(-1, H, W).astype(np.float32)


# Stress channels of the moulds solved last (a mould's masks and `shear` -> its channels),
# so that a mould predicted again (design's confirmation, a user's repeated `predict`, the
# evaluation's modes) is not solved again. At the default's 64 px an entry is 32 KiB.
STRESS_CACHE_SIZE = 1024
_STRESS_CACHE: "OrderedDict[bytes, np.ndarray]" = OrderedDict()


def stress_channels(masks: np.ndarray, shear: bool = False) -> np.ndarray:
    """(S, 2, H, W) masks -> (S, 2, H, W) stress channels ((S, 3, H, W) with `shear`), each
    distinct mould solved once (and kept: the last STRESS_CACHE_SIZE moulds solved are not
    solved again)."""
    masks = np.asarray(masks)
    if masks.ndim != 4 or masks.shape[1] != 2:
        raise ValueError(f"masks must have shape (S, 2, H, W), got {masks.shape}")
    out = np.empty((masks.shape[0], 3 if shear else 2) + masks.shape[2:], dtype=np.float32)
    for s, sample in enumerate(masks):
        binary = np.ascontiguousarray(sample > 0)
        key = bytes([shear]) + repr(binary.shape).encode() + np.packbits(binary).tobytes()
        if key in _STRESS_CACHE:
            _STRESS_CACHE.move_to_end(key)
        else:
            _STRESS_CACHE[key] = spring_stress(sample, shear)
            _STRESS_CACHE[key].setflags(write=False)
            while len(_STRESS_CACHE) > STRESS_CACHE_SIZE:
                _STRESS_CACHE.popitem(last=False)
        out[s] = _STRESS_CACHE[key]
    return out
