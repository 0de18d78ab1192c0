"""What the surrogate sees of a mould: the mask channels, or the lattice channels.

The paper's inputs are two 0/1 masks (`condor.moulds.mould.input_channels`: mould, tether), each
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

import functools
import math
import os
from collections import OrderedDict
from concurrent.futures import ThreadPoolExecutor

import llvmlite.binding as _llvm
import numba
import numpy as np
from numba.extending import get_cython_function_address

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
    """The lattice channels of a `condor.moulds.mould.Mould` on `scene`'s grid."""
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


# The bonds as arrays for the compiled kernels: (row, column) offset, stiffness, length and
# unit (x, y) vector of each SPRING_BONDS entry
_BOND_DY = np.array([dy for (dy, _), _ in SPRING_BONDS], dtype=np.int64)
_BOND_DX = np.array([dx for (_, dx), _ in SPRING_BONDS], dtype=np.int64)
_BOND_K = np.array([k for _, k in SPRING_BONDS], dtype=np.float64)
_BOND_LENGTH = np.sqrt(_BOND_DX ** 2 + _BOND_DY ** 2).astype(np.float64)
_BOND_NX, _BOND_NY = _BOND_DX / _BOND_LENGTH, _BOND_DY / _BOND_LENGTH
# LAPACK's banded Cholesky solve (dpbsv, scipy's own LAPACK at the address that
# scipy.linalg.cython_lapack exports), registered under a symbol so that the compiled solve
# calls it without the GIL (moulds solve in parallel threads) and is cached on disk like the
# rest of the package's kernels.
_llvm.add_symbol("condor_dpbsv", get_cython_function_address("scipy.linalg.cython_lapack",
                                                              "dpbsv"))
_dpbsv = numba.types.ExternalFunction("condor_dpbsv",
                                      numba.types.void(*[numba.types.voidptr] * 9))


@numba.njit(cache=True, nogil=True)
def _domain_bonds(domain: np.ndarray) -> np.ndarray:
    """Every bond of the network on the True pixels of `domain` (H, W): (B, 3) int64 rows of
    its start's flat (row-major) pixel, its end's (start + the bond's offset) and its
    SPRING_BONDS entry."""
    H, W = domain.shape
    bonds = np.empty((len(_BOND_DY) * H * W, 3), dtype=np.int64)
    count = 0
    for y in range(H):
        for x in range(W):
            if not domain[y, x]:
                continue
            for b in range(len(_BOND_DY)):
                y2, x2 = y + _BOND_DY[b], x + _BOND_DX[b]
                if 0 <= y2 < H and 0 <= x2 < W and domain[y2, x2]:
                    bonds[count, 0], bonds[count, 1], bonds[count, 2] = y * W + x, y2 * W + x2, b
                    count += 1
    return bonds[:count]


@numba.njit(cache=True, nogil=True)
def _numbering(free: np.ndarray, by_columns: bool) -> np.ndarray:
    """(H*W,) int64: each free pixel's number, row by row (or column by column), -1 elsewhere."""
    H, W = free.shape
    index = np.full(H * W, -1, dtype=np.int64)
    count = 0
    for a in range(W if by_columns else H):
        for b in range(H if by_columns else W):
            y, x = (b, a) if by_columns else (a, b)
            if free[y, x]:
                index[y * W + x] = count
                count += 1
    return index


@numba.njit(cache=True, nogil=True)
def _bond_width(bonds: np.ndarray, index: np.ndarray) -> int:
    """The largest number difference across a bond between two numbered pixels."""
    width = 0
    for e in range(len(bonds)):
        i, j = index[bonds[e, 0]], index[bonds[e, 1]]
        if i >= 0 and j >= 0 and abs(i - j) > width:
            width = abs(i - j)
    return width


@numba.njit(cache=True, nogil=True)
def _spring_solve(domain: np.ndarray, fixed: np.ndarray) -> tuple:
    """spring_displacement's solve, compiled: ((H*W, 2) displacements, LAPACK's info, the
    bonds (_domain_bonds), which the stress sums reuse)."""
    H, W = domain.shape
    u = np.zeros((H * W, 2))
    free = domain & ~fixed
    bonds = _domain_bonds(domain)
    if not fixed.any() or not free.any():
        return u, 0, bonds
    index = _numbering(free, False)
    width = _bond_width(bonds, index)
    columns = _numbering(free, True)
    width_columns = _bond_width(bonds, columns)
    if width_columns < width:
        index, width = columns, width_columns
    n, kd = 2 * int(free.sum()), 2 * width + 1  # unknowns; superdiagonals of K
    # LAPACK's upper band, column-major (kd + 1, n): K[r, c] (r <= c) at ab[c, kd + r - c]
    ab = np.zeros((n, kd + 1))
    rhs = np.zeros(n)
    for e in range(len(bonds)):
        b = bonds[e, 2]
        length, nx, ny, k = _BOND_LENGTH[b], _BOND_NX[b], _BOND_NY[b], _BOND_K[b]
        kxx, kxy, kyy = k * nx * nx, k * nx * ny, k * ny * ny
        i, j = index[bonds[e, 0]], index[bonds[e, 1]]
        # a bond's 2x2 block k n n^T: + on both ends' diagonal blocks, - between two free
        # ends; -dE/du at u = 0: the bond pulls its ends together with k |d|
        for p, sign in ((i, 1.0), (j, -1.0)):
            if p >= 0:
                q = 2 * p
                ab[q, kd] += kxx
                ab[q + 1, kd - 1] += kxy
                ab[q + 1, kd] += kyy
                rhs[q] += sign * k * length * nx
                rhs[q + 1] += sign * k * length * ny
        if i >= 0 and j >= 0:
            lo, hi = 2 * min(i, j), 2 * max(i, j)
            ab[hi, kd + lo - hi] -= kxx
            ab[hi + 1, kd + lo - hi - 1] -= kxy
            ab[hi, kd + lo + 1 - hi] -= kxy
            ab[hi + 1, kd + lo - hi] -= kyy
    for c in range(n):
        ab[c, kd] += 1e-9  # the ridge
    # dpbsv("U", n, kd, 1, ab, kd + 1, rhs, n, info): rhs becomes the solution
    args = np.array([n, kd, 1, kd + 1, n, 0], dtype=np.int32)
    uplo = np.array([ord("U")], dtype=np.uint8)
    _dpbsv(uplo.ctypes, args[0:1].ctypes, args[1:2].ctypes, args[2:3].ctypes, ab.ctypes,
           args[3:4].ctypes, rhs.ctypes, args[4:5].ctypes, args[5:6].ctypes)
    for p in range(H * W):
        if index[p] >= 0:
            u[p, 0] = rhs[2 * index[p]]
            u[p, 1] = rhs[2 * index[p] + 1]
    return u, int(args[5]), bonds


def spring_displacement(masks: np.ndarray) -> np.ndarray:
    """(2, H, W) masks (mould, tether) -> (H, W, 2) displacements (x, y), in pixels per unit
    contraction strain, of the linear spring network over mould | tether whose rest lengths
    shrink by that strain, the tether pixels held fixed: the minimiser of
    E(u) = sum over bonds of k/2 (n . (u_j - u_i) + |d|)^2. Zero without posts (the free
    network contracts without stress; its rigid motions are pinned by a 1e-9 ridge).

    One direct solve of K u = f (K the Hessian of E over the free pixels' 2 coordinates,
    f = -grad E at u = 0): K is symmetric positive definite (the ridge pins a part the posts
    do not hold) and banded once the free pixels are numbered along the mould's narrower
    direction (about 2 x 45 + 1 diagonals at 64 px), so a banded Cholesky (LAPACK's pbsv)
    solves it; it agrees with a general sparse LU solve of the same system to round-off
    (tested), several times faster. Assembly and solve are one compiled call that releases
    the GIL (stress_channels solves moulds in parallel threads)."""
    masks = np.asarray(masks)
    return _solved(masks)[0].reshape(masks.shape[1:] + (2,))


def _solved(masks: np.ndarray) -> tuple:
    """_spring_solve on (2, H, W) masks, its info checked: ((H*W, 2) displacements, bonds)."""
    if masks.ndim != 3 or masks.shape[0] != 2:
        raise ValueError(f"masks must have shape (2, H, W), got {masks.shape}")
    domain, fixed = (masks[0] > 0) | (masks[1] > 0), masks[1] > 0
    u, info, bonds = _spring_solve(np.ascontiguousarray(domain), np.ascontiguousarray(fixed))
    if info != 0:
        raise np.linalg.LinAlgError(f"the spring network's stiffness is not positive definite "
                                    f"(LAPACK dpbsv info {info})")
    return u, bonds


@numba.njit(cache=True, nogil=True)
def _bond_stress(bonds: np.ndarray, u: np.ndarray, shear: bool) -> np.ndarray:
    """spring_stress's sums over the bonds (_domain_bonds), compiled: (2 or 3, H*W) float64."""
    stress = np.zeros((3 if shear else 2, len(u)))
    for e in range(len(bonds)):
        p, q, b = bonds[e, 0], bonds[e, 1], bonds[e, 2]
        length, nx, ny = _BOND_LENGTH[b], _BOND_NX[b], _BOND_NY[b]
        tension = _BOND_K[b] * (nx * (u[q, 0] - u[p, 0]) + ny * (u[q, 1] - u[p, 1]) + length)
        half = 0.5 * tension * length
        for c, share in ((0, half * nx * nx), (1, half * ny * ny), (2, half * nx * ny)):
            if c < stress.shape[0]:
                stress[c, p] += share
                stress[c, q] += share
    return stress


def spring_stress(masks: np.ndarray, shear: bool = False) -> np.ndarray:
    """(2, H, W) masks -> (2, H, W) float32 stress channels (STRESS_CHANNELS) of the
    contracting spring network (`spring_displacement`): per pixel, half of each bond's tension
    t = k (n . du + |d|) (its stretch beyond the rest length; > 0 pulling) times n_a n_b |d|,
    summed over the pixel's bonds; units of k per unit contraction strain; 0 outside the
    mould and its posts. `shear`: (3, H, W), SHEAR_CHANNEL (a = x, b = y) third."""
    masks = np.asarray(masks)
    u, bonds = _solved(masks)
    H, W = masks.shape[1:]
    if not np.any(masks[1] > 0):
        return np.zeros((3 if shear else 2, H, W), dtype=np.float32)
    return _bond_stress(bonds, u, shear).reshape(-1, H, W).astype(np.float32)


# Stress channels of the moulds solved last (a mould's masks and `shear` -> its channels),
# so that a mould predicted again (design's confirmation, a user's repeated `predict`, the
# evaluation's modes) is not solved again. At the default's 64 px an entry is 32 KiB.
STRESS_CACHE_SIZE = 1024
_STRESS_CACHE: "OrderedDict[bytes, np.ndarray]" = OrderedDict()


def _cpus() -> int:
    """The CPUs this process may run on (its affinity: a SLURM job's share, not the node's)."""
    try:
        return len(os.sched_getaffinity(0))
    except AttributeError:  # not on Linux
        return os.cpu_count() or 1


@functools.cache
def _blas_controller():
    """threadpoolctl's view of the BLAS libraries loaded (found once)."""
    from threadpoolctl import ThreadpoolController

    return ThreadpoolController()


def _one_blas_thread():
    """A context in which BLAS (the OpenBLAS under LAPACK's banded Cholesky) runs on one
    thread: its own threads on a solve this small cost more than they give (measured 4.0
    against 2.5 ms a mould, and 5.7 against 1.4 with two solves in parallel on 2 CPUs)."""
    return _blas_controller().limit(limits=1, user_api="blas")


# The channels derived from a mould's masks alone, by the store-variable name a network reads
# them under (condor.surrogate.samples.INPUT_VARIABLES): a function of one mould's (2, H, W)
# masks -> (C, H, W) float32 (looked up at call time, so that spring_stress can be replaced).
DERIVED_CHANNELS = {"stress": lambda b: spring_stress(b),
                    "stress_tensor": lambda b: spring_stress(b, shear=True)}


def stress_channels(masks: np.ndarray, shear: bool = False, threads: int | None = None) -> np.ndarray:
    """(S, 2, H, W) masks -> (S, 2, H, W) stress channels ((S, 3, H, W) with `shear`):
    derived_channels "stress" ("stress_tensor")."""
    return derived_channels(masks, "stress_tensor" if shear else "stress", threads)


def derived_channels(masks: np.ndarray, name: str, threads: int | None = None) -> np.ndarray:
    """(S, 2, H, W) masks -> (S, C, H, W) channels DERIVED_CHANNELS[name], each distinct
    mould solved once (and kept: the last STRESS_CACHE_SIZE moulds solved are not solved
    again). The moulds not in the cache are solved in `threads` parallel threads (default: the
    CPUs this process may use; the solve releases the GIL)."""
    masks = np.asarray(masks)
    if masks.ndim != 4 or masks.shape[1] != 2:
        raise ValueError(f"masks must have shape (S, 2, H, W), got {masks.shape}")
    if name not in DERIVED_CHANNELS:
        raise ValueError(f"no derived channels {name!r}: one of {tuple(DERIVED_CHANNELS)}")
    function = DERIVED_CHANNELS[name]
    keys, found, missing = [], {}, {}
    for sample in masks:
        binary = np.ascontiguousarray(sample > 0)
        key = name.encode() + repr(binary.shape).encode() + np.packbits(binary).tobytes()
        keys.append(key)
        if key in _STRESS_CACHE:
            _STRESS_CACHE.move_to_end(key)
            found[key] = _STRESS_CACHE[key]
        elif key not in missing:
            missing[key] = binary
    workers = min(len(missing), threads or _cpus())
    with _one_blas_thread():
        if workers > 1:
            with ThreadPoolExecutor(workers) as pool:
                solved = list(pool.map(function, missing.values()))
        else:
            solved = [function(b) for b in missing.values()]
    for key, channels in zip(missing, solved):
        channels.setflags(write=False)
        found[key] = _STRESS_CACHE[key] = channels
        while len(_STRESS_CACHE) > STRESS_CACHE_SIZE:
            _STRESS_CACHE.popitem(last=False)
    out = np.empty((masks.shape[0], found[keys[0]].shape[0]) + masks.shape[2:], dtype=np.float32)
    for s, key in enumerate(keys):
        out[s] = found[key]
    return out
