"""The CONDOR energy, its analytic gradient and the per-cell tension (numba kernels).

Units: l0 = 1, kappa0 = 1; energies in kappa0 l0^2. For a bond b = (i, j) with
l = r_j - r_i, d = |l|, lhat = l / d, c_i = lhat . s_i, c_j = lhat . s_j:

    L_b = l0_b (1 - (Delta/2) (2 - c_i^2 - c_j^2))      (orientation-modified rest length)
    E   = sum_b (kbar_b / 2) (d - L_b)^2

so a bond parallel to both orientations keeps its lattice length l0_b and one perpendicular to
both wants l0_b (1 - Delta). Gradient, with g = kbar (d - L):

    dE/dl   = g [lhat - (l0 Delta / d) (c_i (s_i - c_i lhat) + c_j (s_j - c_j lhat))]
    dE/dr_j = dE/dl = -dE/dr_i
    dE/ds_i = -g l0 Delta c_i lhat       (the raw gradient; project onto the tangent plane
                                          of the unit sphere with `project_tangent`)

Tension of a cell: tau_i = mean over its bonds of kbar_b (d_b - L_b), > 0 when stretched.
"""

from __future__ import annotations

import math

import numba
import numpy as np

DELTA = 0.3  # strength of the cell-matrix interaction (paper)


@numba.njit(cache=True, inline="always")
def _bond_geometry(pos, ori, i, j):
    """Bond vector l = r_j - r_i, its length, and c_i, c_j (cosines with the orientations)."""
    lx = pos[j, 0] - pos[i, 0]
    ly = pos[j, 1] - pos[i, 1]
    lz = pos[j, 2] - pos[i, 2]
    d = math.sqrt(lx * lx + ly * ly + lz * lz)
    inv = 1.0 / d
    ci = (lx * ori[i, 0] + ly * ori[i, 1] + lz * ori[i, 2]) * inv
    cj = (lx * ori[j, 0] + ly * ori[j, 1] + lz * ori[j, 2]) * inv
    return lx, ly, lz, d, ci, cj


@numba.njit(cache=True, inline="always")
def rest_length(l0, ci, cj, delta):
    """Orientation-modified rest length l0 (1 - (delta/2)(2 - ci^2 - cj^2)), l0."""
    return l0 * (1.0 - 0.5 * delta * (2.0 - ci * ci - cj * cj))


@numba.njit(cache=True)
def total_energy(pos, ori, bond_i, bond_j, kbar, rest, delta):
    """E = sum over bonds of (kbar/2)(|l| - L)^2, kappa0 l0^2."""
    e = 0.0
    for b in range(len(bond_i)):
        lx, ly, lz, d, ci, cj = _bond_geometry(pos, ori, bond_i[b], bond_j[b])
        g = d - rest_length(rest[b], ci, cj, delta)
        e += 0.5 * kbar[b] * g * g
    return e


@numba.njit(cache=True)
def bond_energies(pos, ori, bond_i, bond_j, kbar, rest, delta):
    """Energy of every bond (B,), kappa0 l0^2."""
    out = np.empty(len(bond_i))
    for b in range(len(bond_i)):
        lx, ly, lz, d, ci, cj = _bond_geometry(pos, ori, bond_i[b], bond_j[b])
        g = d - rest_length(rest[b], ci, cj, delta)
        out[b] = 0.5 * kbar[b] * g * g
    return out


GRADIENT_BLOCK = 128  # bonds a block of energy_gradient: its buffers stay in L1 (64-256 alike)


@numba.njit(cache=True, error_model="numpy")
def energy_gradient(pos, ori, bond_i, bond_j, kbar, rest, delta, grad_pos, grad_ori):
    """Return E and write dE/dr into grad_pos (N, 3) and the raw dE/ds into grad_ori (N, 3).

    Bonds go in blocks of GRADIENT_BLOCK, three passes a block: gather each bond's vector,
    orientations and constants into contiguous rows; compute its energy and forces there (a
    loop without indirection, which the compiler vectorises: sqrt and division several bonds
    at a time); scatter them onto the cells. The scatter adds the j ends, then the i ends,
    keeping the running sum of a cell in registers while consecutive bonds share their i.
    The lattice's bonds are sorted by i with j > i (`condor.model.lattice`), so every cell
    receives its terms in the order of a plain loop over the bonds: the result is that
    loop's to the bit (tests/test_energy.py), about 1.6x faster (benchmarks/bench_simulator.py).
    Any other order gives the same sums up to round-off. error_model="numpy": no check for a
    zero bond length in the vectorised loop; a collapsed bond gives a non-finite energy.
    """
    grad_pos[:] = 0.0
    grad_ori[:] = 0.0
    nb = len(bond_i)
    inp = np.empty((11, GRADIENT_BLOCK))
    out = np.empty((10, GRADIENT_BLOCK))
    e = 0.0
    for start in range(0, nb, GRADIENT_BLOCK):
        k = min(GRADIENT_BLOCK, nb - start)
        for q in range(k):  # gather
            b = start + q
            i = bond_i[b]
            j = bond_j[b]
            inp[0, q] = pos[j, 0] - pos[i, 0]
            inp[1, q] = pos[j, 1] - pos[i, 1]
            inp[2, q] = pos[j, 2] - pos[i, 2]
            inp[3, q] = ori[i, 0]
            inp[4, q] = ori[i, 1]
            inp[5, q] = ori[i, 2]
            inp[6, q] = ori[j, 0]
            inp[7, q] = ori[j, 1]
            inp[8, q] = ori[j, 2]
            inp[9, q] = rest[b]
            inp[10, q] = kbar[b]
        for q in range(k):  # compute (vectorised)
            lx = inp[0, q]
            ly = inp[1, q]
            lz = inp[2, q]
            d = math.sqrt(lx * lx + ly * ly + lz * lz)
            inv = 1.0 / d
            ci = (lx * inp[3, q] + ly * inp[4, q] + lz * inp[5, q]) * inv
            cj = (lx * inp[6, q] + ly * inp[7, q] + lz * inp[8, q]) * inv
            l0 = inp[9, q]
            stretch = d - rest_length(l0, ci, cj, delta)
            out[9, q] = 0.5 * inp[10, q] * stretch * stretch
            g = inp[10, q] * stretch
            ux, uy, uz = lx * inv, ly * inv, lz * inv
            a = l0 * delta * inv
            # dE/dl = g [u - a (ci (s_i - ci u) + cj (s_j - cj u))]
            coef_u = g * (1.0 + a * (ci * ci + cj * cj))
            coef_i = -g * a * ci
            coef_j = -g * a * cj
            out[0, q] = coef_u * ux + coef_i * inp[3, q] + coef_j * inp[6, q]
            out[1, q] = coef_u * uy + coef_i * inp[4, q] + coef_j * inp[7, q]
            out[2, q] = coef_u * uz + coef_i * inp[5, q] + coef_j * inp[8, q]
            # dE/ds_i = -g l0 delta c_i u
            si = -g * l0 * delta * ci
            sj = -g * l0 * delta * cj
            out[3, q] = si * ux
            out[4, q] = si * uy
            out[5, q] = si * uz
            out[6, q] = sj * ux
            out[7, q] = sj * uy
            out[8, q] = sj * uz
        for q in range(k):  # scatter the j ends
            j = bond_j[start + q]
            e += out[9, q]
            grad_pos[j, 0] += out[0, q]
            grad_pos[j, 1] += out[1, q]
            grad_pos[j, 2] += out[2, q]
            grad_ori[j, 0] += out[6, q]
            grad_ori[j, 1] += out[7, q]
            grad_ori[j, 2] += out[8, q]
        c = bond_i[start]  # scatter the i ends, a run of equal i in registers
        p0, p1, p2 = grad_pos[c, 0], grad_pos[c, 1], grad_pos[c, 2]
        o0, o1, o2 = grad_ori[c, 0], grad_ori[c, 1], grad_ori[c, 2]
        for q in range(k):
            i = bond_i[start + q]
            if i != c:
                grad_pos[c, 0], grad_pos[c, 1], grad_pos[c, 2] = p0, p1, p2
                grad_ori[c, 0], grad_ori[c, 1], grad_ori[c, 2] = o0, o1, o2
                c = i
                p0, p1, p2 = grad_pos[c, 0], grad_pos[c, 1], grad_pos[c, 2]
                o0, o1, o2 = grad_ori[c, 0], grad_ori[c, 1], grad_ori[c, 2]
            p0 -= out[0, q]
            p1 -= out[1, q]
            p2 -= out[2, q]
            o0 += out[3, q]
            o1 += out[4, q]
            o2 += out[5, q]
        grad_pos[c, 0], grad_pos[c, 1], grad_pos[c, 2] = p0, p1, p2
        grad_ori[c, 0], grad_ori[c, 1], grad_ori[c, 2] = o0, o1, o2
    return e


@numba.njit(cache=True)
def project_tangent(ori, grad_ori):
    """Remove from each grad_ori row its component along the unit orientation (in place)."""
    for n in range(ori.shape[0]):
        dot = ori[n, 0] * grad_ori[n, 0] + ori[n, 1] * grad_ori[n, 1] + ori[n, 2] * grad_ori[n, 2]
        grad_ori[n, 0] -= dot * ori[n, 0]
        grad_ori[n, 1] -= dot * ori[n, 1]
        grad_ori[n, 2] -= dot * ori[n, 2]


@numba.njit(cache=True)
def cell_tension(pos, ori, bond_i, bond_j, kbar, rest, delta):
    """tau_i = mean over the bonds of cell i of kbar (|l| - L) (N,), > 0 stretched."""
    n = pos.shape[0]
    total = np.zeros(n)
    count = np.zeros(n)
    for b in range(len(bond_i)):
        i = bond_i[b]
        j = bond_j[b]
        lx, ly, lz, d, ci, cj = _bond_geometry(pos, ori, i, j)
        t = kbar[b] * (d - rest_length(rest[b], ci, cj, delta))
        total[i] += t
        total[j] += t
        count[i] += 1.0
        count[j] += 1.0
    for c in range(n):
        if count[c] > 0:
            total[c] /= count[c]
    return total


def random_orientations(n: int, rng: np.random.Generator) -> np.ndarray:
    """n isotropic random unit vectors (n, 3).

    Isotropic draws are never exactly along a lattice axis (a saddle of zero tangent
    gradient), so no further jitter is needed.
    """
    v = rng.normal(size=(n, 3))
    norm = np.linalg.norm(v, axis=1, keepdims=True)
    norm[norm == 0] = 1.0
    return v / norm


def lattice_energy(lattice, positions, orientations, delta: float = DELTA) -> float:
    """Convenience: total_energy over the bonds of a `condor.model.lattice.Lattice`."""
    return total_energy(
        np.ascontiguousarray(positions, dtype=np.float64),
        np.ascontiguousarray(orientations, dtype=np.float64),
        lattice.bond_i,
        lattice.bond_j,
        lattice.bond_kbar,
        lattice.bond_rest,
        delta,
    )
