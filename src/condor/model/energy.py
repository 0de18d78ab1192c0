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


@numba.njit(cache=True)
def energy_gradient(pos, ori, bond_i, bond_j, kbar, rest, delta, grad_pos, grad_ori):
    """Return E and write dE/dr into grad_pos (N, 3) and the raw dE/ds into grad_ori (N, 3)."""
    grad_pos[:] = 0.0
    grad_ori[:] = 0.0
    e = 0.0
    for b in range(len(bond_i)):
        i = bond_i[b]
        j = bond_j[b]
        lx, ly, lz, d, ci, cj = _bond_geometry(pos, ori, i, j)
        l0 = rest[b]
        stretch = d - rest_length(l0, ci, cj, delta)
        e += 0.5 * kbar[b] * stretch * stretch
        g = kbar[b] * stretch
        inv = 1.0 / d
        ux, uy, uz = lx * inv, ly * inv, lz * inv
        a = l0 * delta * inv
        # dE/dl = g [u - a (ci (s_i - ci u) + cj (s_j - cj u))]
        coef_u = g * (1.0 + a * (ci * ci + cj * cj))
        coef_i = -g * a * ci
        coef_j = -g * a * cj
        fx = coef_u * ux + coef_i * ori[i, 0] + coef_j * ori[j, 0]
        fy = coef_u * uy + coef_i * ori[i, 1] + coef_j * ori[j, 1]
        fz = coef_u * uz + coef_i * ori[i, 2] + coef_j * ori[j, 2]
        grad_pos[j, 0] += fx
        grad_pos[j, 1] += fy
        grad_pos[j, 2] += fz
        grad_pos[i, 0] -= fx
        grad_pos[i, 1] -= fy
        grad_pos[i, 2] -= fz
        # dE/ds_i = -g l0 delta c_i u
        si = -g * l0 * delta * ci
        sj = -g * l0 * delta * cj
        grad_ori[i, 0] += si * ux
        grad_ori[i, 1] += si * uy
        grad_ori[i, 2] += si * uz
        grad_ori[j, 0] += sj * ux
        grad_ori[j, 1] += sj * uy
        grad_ori[j, 2] += sj * uz
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
