"""FCC lattice of cells filling a tethered mould, its bonds, and the confinement geometry.

Lengths are in l0 (the nearest-neighbour rest length). The lattice is face-centred cubic with
its conventional cube axes along x, y and z (cube side a = sqrt(2) l0), so the (001) planes are
horizontal: layers at z = 0, a/2, a, ... <= depth (6 layers for depth 4). In units of a/2 a site
is an integer triple (p, q, r) with p + q + r even. One site sits exactly at the centre of the
polygon's bounding box, so a mould centred in the box and mirror-symmetric about x = centre or
y = centre (or 4-fold symmetric about the centre) gets a lattice with the same symmetry.

Bonds join every pair within the first four shells (distances 1, sqrt 2, sqrt 3, 2; kbar
1, 0.4, 0.2, 0.2), each bond once, rest length = lattice distance.

Tethers are posts: sites whose (x, y) lies inside a tether disk are fixed at every layer and
keep their bonds. A disk narrower than a/2 (0.707 l0) may contain no site of some layer, so the
post sites are picked within max(radius, a/2) of the centre (every layer then holds at least one
post cell); mobile cells are still kept out of the true disk. A tether whose widened disk holds
no site of the mould (it lies outside it) anchors nothing and is counted in `n_empty_tethers`.

Thin features: a neck narrower than the lattice spacing holds few or no sites, so the lattice
can split into pieces joined by a few long bonds or not at all; pieces without a post float
freely (their energy is translation invariant) and the confinement still holds them in.

Confinement: mobile cells must stay in the allowed region, the mould polygon minus the tether
disks, 0 <= z <= depth. Its signed distance (> 0 inside, l0) is the smaller of two parts:
the polygon's, sampled on a grid of spacing `PHI_SPACING` and read by bilinear interpolation
(exact for straight walls away from corners), and each post's, |(x, y) - centre| - radius,
computed exactly (a sampled circle would be faceted, and a cell pressed on a facet edge could
never balance its force). The Metropolis kernel rejects a move outside; the minimisers treat
the region as a hard constraint (`condor.model.walls`) or a stiff wall (FIRE).
"""

from __future__ import annotations

import math
from dataclasses import dataclass

import numba
import numpy as np
import shapely
from shapely.geometry import Polygon

A_CUBIC = math.sqrt(2.0)  # conventional FCC cube side for nearest-neighbour distance 1, l0
HALF = A_CUBIC / 2.0  # lattice unit of the integer site coordinates, l0
SHELL_KBAR = (1.0, 0.4, 0.2, 0.2)  # dimensionless spring constants of shells 1-4
PHI_SPACING = 0.1  # grid spacing of the signed-distance field, l0
PHI_PAD = 2.0  # margin of the distance grid around the polygon, l0
PHI_OUTSIDE = -1.0e3  # phi reported off the grid (far outside), l0


def _shell_offsets() -> tuple[np.ndarray, np.ndarray]:
    """Half of the neighbour offsets (units of a/2) of shells 1-4 and their shell index (0-3).

    Keeping only offsets whose first non-zero component is positive counts each bond once.
    """
    offsets, shells = [], []
    rng = range(-2, 3)
    for dp in rng:
        for dq in rng:
            for dr in rng:
                d2 = dp * dp + dq * dq + dr * dr  # in (a/2)^2 = 1/2 l0^2
                if (dp + dq + dr) % 2 or d2 not in (2, 4, 6, 8):
                    continue
                first = next(v for v in (dp, dq, dr) if v != 0)
                if first > 0:
                    offsets.append((dp, dq, dr))
                    shells.append(d2 // 2 - 1)
    return np.array(offsets, dtype=np.int64), np.array(shells, dtype=np.int64)


@dataclass(frozen=True)
class Region:
    """Allowed region of mobile cells: polygon minus tether disks, 0 <= z <= depth (l0)."""

    depth: float
    phi: np.ndarray  # (ny, nx) signed distance at grid nodes, > 0 inside, l0
    phi_x0: float  # x of node column 0, l0
    phi_y0: float  # y of node row 0, l0
    phi_h: float  # node spacing, l0
    posts: np.ndarray  # (k, 3) tether disks x, y, radius that cells stay out of, l0

    def signed_distance(self, xy: np.ndarray) -> np.ndarray:
        """Signed distance at points xy (n, 2), l0 (> 0 inside): min of the polygon's
        (bilinear on the grid) and the posts' (exact)."""
        xy = np.asarray(xy, dtype=np.float64).reshape(-1, 2)
        out = np.empty(len(xy))
        for n in range(len(xy)):
            out[n] = region_distance(self.phi, self.phi_x0, self.phi_y0, self.phi_h, self.posts,
                                     xy[n, 0], xy[n, 1])
        return out

    def violation(self, positions: np.ndarray) -> np.ndarray:
        """How far each point (n, 3) lies outside the region, l0 (0 inside)."""
        positions = np.asarray(positions, dtype=np.float64)
        outside_xy = np.maximum(-self.signed_distance(positions[:, :2]), 0.0)
        z = positions[:, 2]
        outside_z = np.maximum(np.maximum(-z, z - self.depth), 0.0)
        return np.maximum(outside_xy, outside_z)


@dataclass(frozen=True)
class Lattice:
    """Initial cells, bonds and confinement of one mould (lengths in l0)."""

    positions: np.ndarray  # (N, 3) float64 initial (lattice) positions
    fixed: np.ndarray  # (N,) bool, post cells inside tether disks
    bond_i: np.ndarray  # (B,) int64, first cell of each bond, ascending
    bond_j: np.ndarray  # (B,) int64, second cell, > bond_i (energy_gradient sums in this order)
    bond_kbar: np.ndarray  # (B,) float64 dimensionless spring constant
    bond_rest: np.ndarray  # (B,) float64 lattice distance l0_ij
    bond_shell: np.ndarray  # (B,) int8 shell 0-3
    cell_ptr: np.ndarray  # (N+1,) CSR offsets into cell_bonds
    cell_bonds: np.ndarray  # (2B,) bond indices of each cell, grouped by cell
    tets: np.ndarray  # (T, 4) int64 nearest-neighbour tetrahedra, positive reference volume
    region: Region
    n_empty_tethers: int  # tethers that anchor no cell
    n_widened_tethers: int  # tethers narrower than a/2 whose posts were picked within a/2

    @property
    def n_cells(self) -> int:
        return len(self.positions)

    @property
    def n_bonds(self) -> int:
        return len(self.bond_i)


def validate_mould(polygon, tethers, depth: float) -> tuple[Polygon, np.ndarray, float]:
    """Check the inputs of a mould; return (polygon, tethers (n, 3) float64, depth)."""
    if not isinstance(polygon, Polygon):
        raise ValueError(f"polygon must be a shapely Polygon, got {type(polygon).__name__}")
    if polygon.is_empty or not polygon.is_valid or polygon.area <= 0:
        raise ValueError(f"polygon must be valid with positive area, got {polygon.wkt[:80]}")
    depth = float(depth)
    if not np.isfinite(depth) or depth <= 0:
        raise ValueError(f"depth must be positive, got {depth}")
    tethers = np.asarray(tethers, dtype=np.float64)
    if tethers.size == 0:
        tethers = np.zeros((0, 3))
    if tethers.ndim != 2 or tethers.shape[1] != 3:
        raise ValueError(f"tethers must have shape (n, 3), got {tethers.shape}")
    if not np.all(np.isfinite(tethers)) or np.any(tethers[:, 2] <= 0):
        raise ValueError(f"tethers need finite x, y and positive radius, got {tethers.tolist()}")
    return polygon, tethers, depth


def build_lattice(polygon: Polygon, tethers, depth: float) -> Lattice:
    """Fill `polygon` extruded to `depth` (l0) with an FCC lattice; posts in tether disks.

    Raises ValueError for bad input or a mould that holds no mobile cell.
    """
    polygon, tethers, depth = validate_mould(polygon, tethers, depth)
    (p, q, r), (p_lo, p_hi, q_lo, q_hi), n_layers, positions = _sites(polygon, depth)
    fixed, n_empty, n_widened = _post_sites(positions, tethers)
    if np.count_nonzero(~fixed) == 0:
        raise ValueError(f"mould holds no mobile cell (polygon area {polygon.area:.3g} l0^2)")

    # Site index by integer coordinates, for bond and tetrahedron lookup.
    index = -np.ones((p_hi - p_lo + 3, q_hi - q_lo + 3, n_layers + 2), dtype=np.int64)
    ip, iq, ir = p - p_lo, q - q_lo, r
    index[ip, iq, ir] = np.arange(len(positions))

    bond_i, bond_j, bond_shell = _bonds(index, ip, iq, ir)
    kbar = np.asarray(SHELL_KBAR)[bond_shell]
    rest = np.sqrt((bond_shell + 1).astype(np.float64))
    cell_ptr, cell_bonds = _cell_csr(len(positions), bond_i, bond_j)
    tets = _tetrahedra(index, (p_lo + q_lo) % 2, positions, fixed)
    region = build_region(polygon, tethers, depth)
    return Lattice(
        positions=positions,
        fixed=fixed,
        bond_i=bond_i,
        bond_j=bond_j,
        bond_kbar=kbar,
        bond_rest=rest,
        bond_shell=bond_shell.astype(np.int8),
        cell_ptr=cell_ptr,
        cell_bonds=cell_bonds,
        tets=tets,
        region=region,
        n_empty_tethers=n_empty,
        n_widened_tethers=n_widened,
    )


def fcc_layers(depth: float) -> int:
    """FCC (001) layers in a slab of `depth` l0: layers a/2 apart from z = 0."""
    return int(math.floor(depth / HALF + 1e-9)) + 1


def lattice_sites(polygon: Polygon, tethers, depth: float) -> tuple[np.ndarray, np.ndarray]:
    """The initial cells of `build_lattice` alone, without bonds: positions (N, 3) and fixed
    flags (N,), identical to its `positions` and `fixed` (cheap: for the surrogate's inputs)."""
    polygon, tethers, depth = validate_mould(polygon, tethers, depth)
    positions = _sites(polygon, depth)[3]
    return positions, _post_sites(positions, tethers)[0]


def _sites(polygon: Polygon, depth: float):
    """FCC sites in `polygon` x [0, depth]: integer coordinates (p, q, r), their index bounds
    (p_lo, p_hi, q_lo, q_hi), the number of layers and positions (N, 3), origin at the centre
    of the polygon's bounding box."""
    xmin, ymin, xmax, ymax = polygon.bounds
    cx, cy = 0.5 * (xmin + xmax), 0.5 * (ymin + ymax)
    p_lo, p_hi = math.floor((xmin - cx) / HALF) - 1, math.ceil((xmax - cx) / HALF) + 1
    q_lo, q_hi = math.floor((ymin - cy) / HALF) - 1, math.ceil((ymax - cy) / HALF) + 1
    n_layers = fcc_layers(depth)
    p, q, r = np.meshgrid(
        np.arange(p_lo, p_hi + 1), np.arange(q_lo, q_hi + 1), np.arange(n_layers), indexing="ij"
    )
    even = (p + q + r) % 2 == 0
    p, q, r = p[even], q[even], r[even]
    x, y, z = cx + p * HALF, cy + q * HALF, r * HALF
    inside = shapely.contains_xy(polygon, x, y)
    p, q, r, x, y, z = (v[inside] for v in (p, q, r, x, y, z))
    positions = np.column_stack([x, y, z]).astype(np.float64)
    return (p, q, r), (p_lo, p_hi, q_lo, q_hi), n_layers, positions


def _post_sites(positions: np.ndarray, tethers: np.ndarray) -> tuple[np.ndarray, int, int]:
    """Fixed flags of sites inside tether disks (widened to a/2), and counts of odd tethers."""
    fixed = np.zeros(len(positions), dtype=bool)
    n_empty = n_widened = 0
    for tx, ty, radius in tethers:
        d2 = (positions[:, 0] - tx) ** 2 + (positions[:, 1] - ty) ** 2
        pick_radius = radius
        if radius < HALF:
            pick_radius = HALF * (1 + 1e-9)
            n_widened += 1
        in_disk = d2 <= pick_radius**2 * (1 + 1e-12)
        n_empty += not np.any(in_disk)
        fixed |= in_disk
    return fixed, n_empty, n_widened


def _bonds(index, ip, iq, ir) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """All bonds of shells 1-4 between existing sites, each once (i, j, shell)."""
    offsets, shells = _shell_offsets()
    sizes = np.array(index.shape)
    bi, bj, bs = [], [], []
    for (dp, dq, dr), shell in zip(offsets, shells):
        jp, jq, jr = ip + dp, iq + dq, ir + dr
        ok = (jp >= 0) & (jq >= 0) & (jr >= 0) & (jp < sizes[0]) & (jq < sizes[1]) & (jr < sizes[2])
        j = np.full(len(ip), -1, dtype=np.int64)
        j[ok] = index[jp[ok], jq[ok], jr[ok]]
        have = j >= 0
        bi.append(np.nonzero(have)[0])
        bj.append(j[have])
        bs.append(np.full(np.count_nonzero(have), shell))
    bond_i, bond_j, bond_shell = (np.concatenate(v).astype(np.int64) for v in (bi, bj, bs))
    order = np.lexsort((bond_j, bond_i))
    return bond_i[order], bond_j[order], bond_shell[order]


def _cell_csr(n_cells: int, bond_i: np.ndarray, bond_j: np.ndarray):
    """CSR lists of the bonds touching each cell: cell_bonds[cell_ptr[c]:cell_ptr[c+1]]."""
    ends = np.concatenate([bond_i, bond_j])
    bonds = np.concatenate([np.arange(len(bond_i)), np.arange(len(bond_j))])
    order = np.argsort(ends, kind="stable")
    counts = np.bincount(ends, minlength=n_cells)
    cell_ptr = np.concatenate([[0], np.cumsum(counts)]).astype(np.int64)
    return cell_ptr, bonds[order].astype(np.int64)


def _tetrahedra(index: np.ndarray, shift: int, positions: np.ndarray, fixed: np.ndarray):
    """Nearest-neighbour tetrahedra (one per small cube of side a/2), positively oriented.

    The 4 corners with even p + q + r of each cube of side a/2 are mutual nearest neighbours.
    `shift` is the parity of the lattice coordinates of index (0, 0, 0). Tetrahedra of posts
    only are dropped (they never move).
    """
    even_corners = np.array([[0, 0, 0], [1, 1, 0], [1, 0, 1], [0, 1, 1]])
    odd_corners = np.array([[1, 0, 0], [0, 1, 0], [0, 0, 1], [1, 1, 1]])
    sp, sq, sr = index.shape
    p, q, r = np.meshgrid(np.arange(sp - 1), np.arange(sq - 1), np.arange(sr - 1), indexing="ij")
    p, q, r = p.ravel(), q.ravel(), r.ravel()
    lower_even = (p + q + r + shift) % 2 == 0
    corners = np.where(lower_even[:, None, None], even_corners[None], odd_corners[None])
    tets = index[p[:, None] + corners[..., 0], q[:, None] + corners[..., 1], r[:, None] + corners[..., 2]]
    tets = tets[np.all(tets >= 0, axis=1)]
    tets = tets[~np.all(fixed[tets], axis=1)]
    vol = signed_volumes(positions, tets)
    flip = vol < 0
    tets[flip, 0], tets[flip, 1] = tets[flip, 1].copy(), tets[flip, 0].copy()
    return np.ascontiguousarray(tets, dtype=np.int64).reshape(-1, 4)


def signed_volumes(positions: np.ndarray, tets: np.ndarray) -> np.ndarray:
    """Signed volume of each tetrahedron (T, 4), l0^3."""
    a = positions[tets[:, 1]] - positions[tets[:, 0]]
    b = positions[tets[:, 2]] - positions[tets[:, 0]]
    c = positions[tets[:, 3]] - positions[tets[:, 0]]
    return np.einsum("ij,ij->i", a, np.cross(b, c)) / 6.0


def build_region(polygon: Polygon, tethers: np.ndarray, depth: float) -> Region:
    """Signed-distance grid of the polygon and the post disks of the allowed region, l0."""
    xmin, ymin, xmax, ymax = polygon.bounds
    h = PHI_SPACING
    x0, y0 = xmin - PHI_PAD, ymin - PHI_PAD
    nx = int(math.ceil((xmax + PHI_PAD - x0) / h)) + 1
    ny = int(math.ceil((ymax + PHI_PAD - y0) / h)) + 1
    gx = x0 + h * np.arange(nx)
    gy = y0 + h * np.arange(ny)
    segments = _ring_segments(polygon)
    dist = _distance_to_segments(gx, gy, segments)
    xx, yy = np.meshgrid(gx, gy)
    inside = shapely.contains_xy(polygon, xx, yy)
    phi = np.where(inside, dist, -dist)
    posts = np.ascontiguousarray(np.asarray(tethers, dtype=np.float64).reshape(-1, 3))
    return Region(depth=depth, phi=np.ascontiguousarray(phi), phi_x0=x0, phi_y0=y0, phi_h=h,
                  posts=posts)


def _ring_segments(polygon: Polygon) -> np.ndarray:
    """All boundary segments (m, 4): x1, y1, x2, y2 of exterior and interior rings."""
    rings = [polygon.exterior, *polygon.interiors]
    parts = []
    for ring in rings:
        xy = np.asarray(ring.coords, dtype=np.float64)
        parts.append(np.column_stack([xy[:-1], xy[1:]]))
    return np.ascontiguousarray(np.concatenate(parts))


@numba.njit(cache=True)
def _distance_to_segments(gx, gy, segments):
    """Unsigned distance from every grid node (gy, gx) to the nearest segment, l0."""
    out = np.empty((len(gy), len(gx)))
    for iy in range(len(gy)):
        for ix in range(len(gx)):
            best = 1e300
            px, py = gx[ix], gy[iy]
            for s in range(segments.shape[0]):
                ax, ay, bx, by = segments[s, 0], segments[s, 1], segments[s, 2], segments[s, 3]
                dx, dy = bx - ax, by - ay
                len2 = dx * dx + dy * dy
                t = 0.0
                if len2 > 0:
                    t = ((px - ax) * dx + (py - ay) * dy) / len2
                    t = min(1.0, max(0.0, t))
                ex, ey = ax + t * dx - px, ay + t * dy - py
                d2 = ex * ex + ey * ey
                if d2 < best:
                    best = d2
            out[iy, ix] = math.sqrt(best)
    return out


@numba.njit(cache=True)
def phi_at(phi, x0, y0, h, x, y):
    """Bilinear interpolation of the signed distance at (x, y); PHI_OUTSIDE off the grid."""
    fx = (x - x0) / h
    fy = (y - y0) / h
    ix = int(math.floor(fx))
    iy = int(math.floor(fy))
    if ix < 0 or iy < 0 or ix >= phi.shape[1] - 1 or iy >= phi.shape[0] - 1:
        return -1.0e3
    tx = fx - ix
    ty = fy - iy
    return (
        (1 - tx) * (1 - ty) * phi[iy, ix]
        + tx * (1 - ty) * phi[iy, ix + 1]
        + (1 - tx) * ty * phi[iy + 1, ix]
        + tx * ty * phi[iy + 1, ix + 1]
    )


@numba.njit(cache=True)
def phi_grad_at(phi, x0, y0, h, x, y):
    """Bilinear phi and its gradient (phi, dphi/dx, dphi/dy) at (x, y)."""
    fx = (x - x0) / h
    fy = (y - y0) / h
    ix = int(math.floor(fx))
    iy = int(math.floor(fy))
    if ix < 0 or iy < 0 or ix >= phi.shape[1] - 1 or iy >= phi.shape[0] - 1:
        return -1.0e3, 0.0, 0.0
    tx = fx - ix
    ty = fy - iy
    p00, p10 = phi[iy, ix], phi[iy, ix + 1]
    p01, p11 = phi[iy + 1, ix], phi[iy + 1, ix + 1]
    val = (1 - tx) * (1 - ty) * p00 + tx * (1 - ty) * p10 + (1 - tx) * ty * p01 + tx * ty * p11
    gx = ((1 - ty) * (p10 - p00) + ty * (p11 - p01)) / h
    gy = ((1 - tx) * (p01 - p00) + tx * (p11 - p10)) / h
    return val, gx, gy


@numba.njit(cache=True)
def region_distance(phi, x0, y0, h, posts, x, y):
    """Signed distance to the allowed region in the plane, l0 (> 0 inside): the smaller of the
    polygon's (bilinear) and each post's |(x, y) - centre| - radius (exact)."""
    val = phi_at(phi, x0, y0, h, x, y)
    for k in range(posts.shape[0]):
        dx = x - posts[k, 0]
        dy = y - posts[k, 1]
        val = min(val, math.sqrt(dx * dx + dy * dy) - posts[k, 2])
    return val


@numba.njit(cache=True)
def region_distance_grad(phi, x0, y0, h, posts, x, y):
    """region_distance and the gradient of its smallest part (val, d/dx, d/dy)."""
    val, gx, gy = phi_grad_at(phi, x0, y0, h, x, y)
    for k in range(posts.shape[0]):
        dx = x - posts[k, 0]
        dy = y - posts[k, 1]
        r = math.sqrt(dx * dx + dy * dy)
        if r - posts[k, 2] < val:
            val = r - posts[k, 2]
            if r > 0.0:
                gx = dx / r
                gy = dy / r
            else:
                gx = 1.0
                gy = 0.0
    return val, gx, gy
