"""Gradient minimiser of the CONDOR energy over positions and orientations (FIRE, numba).

FIRE (Bitzek et al. 2006) with two changes that the prototype showed are needed:
  * a floor on the mixing parameter alpha (ALPHA_MIN = 0.02); textbook FIRE lets alpha decay
    to 0, turning it into undamped dynamics that stalls;
  * orientations stay on the unit sphere: their force is the tangent-projected -dE/ds, and
    after each step s is renormalised and the component of its velocity along s removed.
Fixed (post) cells neither move nor rotate.

Confinement is a stiff smooth wall: E_wall = (K_WALL / 2) sum over mobile cells of
max(0, -phi(x, y))^2 + max(0, -z)^2 + max(0, z - depth)^2, phi the bilinear signed-distance
field of the allowed region (> 0 inside). A wall force f pushes a cell f / K_WALL outside; after
minimising, cells are projected back onto the region (`project_inside`), and the reported
energy never includes the wall.

Convergence: the largest per-cell force (position and tangent orientation parts, each a
3-vector norm) below `ftol`, or `max_iter` energy+gradient evaluations.
"""

from __future__ import annotations

import math

import numba
import numpy as np

from condor.model.energy import DELTA, energy_gradient
from condor.model.lattice import region_distance_grad

K_WALL = 50.0  # kappa0, wall stiffness
FTOL = 1.0e-3  # kappa0 l0, default force tolerance (energy within ~0.01% of the minimum)
MAX_ITER = 20000  # default evaluation budget
DT_INIT = 0.05
DT_MAX = 0.2
N_MIN = 5
F_INC = 1.1
F_DEC = 0.5
ALPHA_START = 0.1
F_ALPHA = 0.99
ALPHA_MIN = 0.02  # the floor that keeps FIRE damped


@numba.njit(cache=True)
def wall_energy_gradient(pos, mobile, phi, x0, y0, h, posts, depth, k_wall, grad_pos):
    """Add the wall gradient of mobile cells to grad_pos; return the wall energy."""
    e = 0.0
    for m in range(len(mobile)):
        c = mobile[m]
        val, gx, gy = region_distance_grad(phi, x0, y0, h, posts, pos[c, 0], pos[c, 1])
        if val < 0.0:
            e += 0.5 * k_wall * val * val
            grad_pos[c, 0] += k_wall * val * gx  # d/dx (k/2) phi^2 = k phi dphi/dx
            grad_pos[c, 1] += k_wall * val * gy
        z = pos[c, 2]
        if z < 0.0:
            e += 0.5 * k_wall * z * z
            grad_pos[c, 2] += k_wall * z
        elif z > depth:
            dz = z - depth
            e += 0.5 * k_wall * dz * dz
            grad_pos[c, 2] += k_wall * dz
    return e


@numba.njit(cache=True)
def _forces(pos, ori, mobile, bond_i, bond_j, kbar, rest, delta, phi, x0, y0, h, posts, depth,
            k_wall, grad_pos, grad_ori, f_pos, f_ori):
    """Fill f_pos, f_ori (mobile rows only) with -gradient; return (E_bonds, E_wall, fmax)."""
    e = energy_gradient(pos, ori, bond_i, bond_j, kbar, rest, delta, grad_pos, grad_ori)
    ew = wall_energy_gradient(pos, mobile, phi, x0, y0, h, posts, depth, k_wall, grad_pos)
    fmax2 = 0.0
    for m in range(len(mobile)):
        c = mobile[m]
        dot = ori[c, 0] * grad_ori[c, 0] + ori[c, 1] * grad_ori[c, 1] + ori[c, 2] * grad_ori[c, 2]
        fp2 = 0.0
        fo2 = 0.0
        for a in range(3):
            f_pos[m, a] = -grad_pos[c, a]
            f_ori[m, a] = -(grad_ori[c, a] - dot * ori[c, a])
            fp2 += f_pos[m, a] * f_pos[m, a]
            fo2 += f_ori[m, a] * f_ori[m, a]
        fmax2 = max(fmax2, fp2, fo2)
    return e, ew, math.sqrt(fmax2)


@numba.njit(cache=True)
def fire_kernel(pos, ori, mobile, bond_i, bond_j, kbar, rest, delta, phi, x0, y0, h, posts,
                depth, k_wall, max_iter, ftol, alpha_min, dt_max, trace):
    """FIRE in place on pos, ori. Returns (E_bonds, E_wall, max force, evaluations).

    trace (K, 2): bond energy and max force of evaluation k for k < K (K = 0: no trace).
    """
    n = pos.shape[0]
    nm = len(mobile)
    grad_pos = np.zeros((n, 3))
    grad_ori = np.zeros((n, 3))
    f_pos = np.zeros((nm, 3))
    f_ori = np.zeros((nm, 3))
    v_pos = np.zeros((nm, 3))
    v_ori = np.zeros((nm, 3))
    dt = DT_INIT
    alpha = ALPHA_START
    n_positive = 0
    e = ew = fmax = 0.0
    it = 0
    while True:
        e, ew, fmax = _forces(pos, ori, mobile, bond_i, bond_j, kbar, rest, delta, phi, x0,
                              y0, h, posts, depth, k_wall, grad_pos, grad_ori, f_pos, f_ori)
        if it < trace.shape[0]:
            trace[it, 0] = e
            trace[it, 1] = fmax
        it += 1
        if fmax < ftol or it >= max_iter or not math.isfinite(e):
            break
        power = 0.0
        v2 = 0.0
        f2 = 0.0
        for m in range(nm):
            for a in range(3):
                power += f_pos[m, a] * v_pos[m, a] + f_ori[m, a] * v_ori[m, a]
                v2 += v_pos[m, a] * v_pos[m, a] + v_ori[m, a] * v_ori[m, a]
                f2 += f_pos[m, a] * f_pos[m, a] + f_ori[m, a] * f_ori[m, a]
        if power > 0.0:
            scale = alpha * math.sqrt(v2) / math.sqrt(f2) if f2 > 0 else 0.0
            for m in range(nm):
                for a in range(3):
                    v_pos[m, a] = (1.0 - alpha) * v_pos[m, a] + scale * f_pos[m, a]
                    v_ori[m, a] = (1.0 - alpha) * v_ori[m, a] + scale * f_ori[m, a]
            n_positive += 1
            if n_positive > N_MIN:
                dt = min(dt * F_INC, dt_max)
                alpha = max(alpha * F_ALPHA, alpha_min)
        else:
            v_pos[:] = 0.0
            v_ori[:] = 0.0
            dt *= F_DEC
            alpha = ALPHA_START
            n_positive = 0
        # Semi-implicit Euler; orientations renormalised, their velocity kept tangent.
        for m in range(nm):
            c = mobile[m]
            for a in range(3):
                v_pos[m, a] += dt * f_pos[m, a]
                v_ori[m, a] += dt * f_ori[m, a]
                pos[c, a] += dt * v_pos[m, a]
                ori[c, a] += dt * v_ori[m, a]
            norm = math.sqrt(ori[c, 0] ** 2 + ori[c, 1] ** 2 + ori[c, 2] ** 2)
            dot = 0.0
            for a in range(3):
                ori[c, a] /= norm
                dot += ori[c, a] * v_ori[m, a]
            for a in range(3):
                v_ori[m, a] -= dot * ori[c, a]
    return e, ew, fmax, it


@numba.njit(cache=True)
def project_inside(pos, mobile, phi, x0, y0, h, posts, depth):
    """Move mobile cells that lie outside back onto the region; return the largest move, l0."""
    worst = 0.0
    for m in range(len(mobile)):
        c = mobile[m]
        moved = 0.0
        for _ in range(20):  # Newton steps along grad phi: phi is near-linear close to a wall
            val, gx, gy = region_distance_grad(phi, x0, y0, h, posts, pos[c, 0], pos[c, 1])
            if val >= 0.0:
                break
            g2 = gx * gx + gy * gy
            if g2 == 0.0:
                break
            step = (-val + 1e-9) / g2
            pos[c, 0] += step * gx
            pos[c, 1] += step * gy
            moved += abs(step) * math.sqrt(g2)
        if pos[c, 2] < 0.0:
            moved += -pos[c, 2]
            pos[c, 2] = 0.0
        elif pos[c, 2] > depth:
            moved += pos[c, 2] - depth
            pos[c, 2] = depth
        worst = max(worst, moved)
    return worst


def minimise(lattice, positions, orientations, max_iter: int = MAX_ITER, ftol: float = FTOL,
             k_wall: float = K_WALL, alpha_min: float = ALPHA_MIN, delta: float = DELTA,
             dt_max: float = DT_MAX, trace: np.ndarray | None = None):
    """Minimise copies of (positions, orientations) with FIRE; return (pos, ori, info).

    max_iter: energy+gradient evaluations; ftol: largest per-cell force, kappa0 l0.
    trace: optional float64 (K, 2) filled with (bond energy, max force) per evaluation.
    info: JSON-safe (iterations, max_force, wall penetration before projection, ...).
    """
    if max_iter < 1:
        raise ValueError(f"max_iter must be >= 1, got {max_iter}")
    pos = np.array(positions, dtype=np.float64, order="C")
    ori = np.array(orientations, dtype=np.float64, order="C")
    mobile = np.flatnonzero(~lattice.fixed).astype(np.int64)
    r = lattice.region
    e, ew, fmax, iters = fire_kernel(
        pos, ori, mobile, lattice.bond_i, lattice.bond_j, lattice.bond_kbar, lattice.bond_rest,
        delta, r.phi, r.phi_x0, r.phi_y0, r.phi_h, r.posts, r.depth, float(k_wall), int(max_iter),
        float(ftol), float(alpha_min), float(dt_max),
        np.zeros((0, 2)) if trace is None else trace,
    )
    penetration = float(project_inside(pos, mobile, r.phi, r.phi_x0, r.phi_y0, r.phi_h, r.posts, r.depth))
    info = {
        "min_iterations": int(iters),
        "min_max_force": float(fmax),
        "min_converged": bool(fmax < ftol),
        "min_wall_energy": float(ew),
        "min_wall_penetration": penetration,
    }
    return pos, ori, info

