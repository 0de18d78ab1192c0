"""L-BFGS minimiser of the CONDOR energy with exact confinement (numba).

Variables: the position r and the unit orientation s of every mobile cell (6 numbers a cell).
The gradient is dE/dr and the tangent part of dE/ds (the sphere's tangent space); a step moves
r and s along the search direction, then puts s back on the sphere (normalisation, the
retraction) and r back into the allowed region (`condor.model.walls.place`).

Walls are an active set (`condor.model.walls`): a cell on a wall whose force pushes outward has the
outward part of its gradient removed, and the search direction of such a cell is restricted to
slide along that wall (or held in a corner, or in z on the floor or lid), so the state always
satisfies the walls, posts and slab exactly and converges to a balance that includes them.

Direction: the two-loop recursion over the last `memory` pairs (s_k = x_{k+1} - x_k,
y_k = g_{k+1} - g_k, wall-free gradients), started from H0 = gamma D^-1. D is the
bond-stiffness diagonal: for positions, the sum of kbar over a cell's bonds; for orientations,
the sum of kbar (l0 Delta)^2 * 2/15 (the mean over isotropic orientations of the Gauss-Newton
curvature kbar (l0 Delta)^2 c^2 (1 - c^2)); gamma = s.y / y.D^-1.y of the newest pair.
A pair with s.y <= 0 is skipped.

Step: Armijo backtracking (halving) from step 1 along the projected path, the step capped so
that no cell moves more than MAX_DISP l0 nor turns more than MAX_TURN (chord); the very first
step moves the most-pushed cell FIRST_DISP l0. Every trial point costs one energy+gradient
evaluation; evaluations, not iterations, are the budget (`max_iter`).

Stops when every mobile cell's residual force (projected position force or tangent
orientation force, the larger) is below `ftol`, at `max_iter` evaluations, on a non-finite
energy, or when a line search fails (then `stalled`; measured: only at forces near round-off).
"""

from __future__ import annotations

import math

import numba
import numpy as np

from condor.model.energy import DELTA, energy_gradient
from condor.model.lattice import region_distance
from condor.model.walls import (LIPSCHITZ, ON_WALL, SLIDE, hold_on_walls, place, project_force,
                          project_state)

FTOL = 3.0e-4  # kappa0 l0, default largest residual force (see docs/model.md)
MAX_ITER = 20000  # default evaluation budget
MEMORY = 10  # stored pairs
MAX_DISP = 0.3  # l0, largest move of a cell in one step
MAX_TURN = 0.5  # largest orientation change (chord) of a cell in one step
FIRST_DISP = 0.1  # l0, the first (steepest-descent) step
ARMIJO = 1.0e-4
REFRESH = 0.05  # l0: a cell whose clearance bound falls below this gets its exact clearance
MAX_BACKTRACK = 30


@numba.njit(cache=True)
def _gradients(pos, ori, mobile, bond_i, bond_j, kbar, rest, delta, phi, x0, y0, h, posts,
               depth, grad_pos, grad_ori, g, gp, mode, wall, normal, clear):
    """Energy; g (nm, 6) the gradient (tangent for s); gp the projected gradient; each mobile
    cell's wall mode, wall and its normal. clear (nm,): a lower bound on each cell's distance
    to the plane walls (made exact where it is small). Returns (E, largest residual force)."""
    e = energy_gradient(pos, ori, bond_i, bond_j, kbar, rest, delta, grad_pos, grad_ori)
    fmax2 = 0.0
    for m in range(len(mobile)):
        c = mobile[m]
        if clear[m] < REFRESH:
            clear[m] = region_distance(phi, x0, y0, h, posts, pos[c, 0], pos[c, 1])
        dot = ori[c, 0] * grad_ori[c, 0] + ori[c, 1] * grad_ori[c, 1] + ori[c, 2] * grad_ori[c, 2]
        for a in range(3):
            g[m, a] = grad_pos[c, a]
            g[m, 3 + a] = grad_ori[c, a] - dot * ori[c, a]
            gp[m, 3 + a] = g[m, 3 + a]
        fx, fy, fz, md, wl, nx, ny = project_force(
            phi, x0, y0, h, posts, depth, pos[c, 0], pos[c, 1], pos[c, 2], -g[m, 0], -g[m, 1],
            -g[m, 2], clear[m] <= ON_WALL)
        gp[m, 0] = -fx
        gp[m, 1] = -fy
        gp[m, 2] = -fz
        mode[m] = md
        wall[m] = wl
        normal[m, 0] = nx
        normal[m, 1] = ny
        fp2 = fx * fx + fy * fy + fz * fz
        fo2 = gp[m, 3] ** 2 + gp[m, 4] ** 2 + gp[m, 5] ** 2
        fmax2 = max(fmax2, fp2, fo2)
    return e, math.sqrt(fmax2)


@numba.njit(cache=True, fastmath=True)
def _dot(a, b):
    """a . b of two (nm, 6) arrays (fastmath: a vectorised reduction; deterministic)."""
    a1 = a.ravel()
    b1 = b.ravel()
    s = 0.0
    for k in range(a1.shape[0]):
        s += a1[k] * b1[k]
    return s


@numba.njit(cache=True, fastmath=True)
def _axpy(alpha, x, y):
    """y += alpha x on (nm, 6) arrays."""
    x1 = x.ravel()
    y1 = y.ravel()
    for k in range(x1.shape[0]):
        y1[k] += alpha * x1[k]


@numba.njit(cache=True)
def lbfgs_kernel(pos, ori, mobile, bond_i, bond_j, kbar, rest, delta, phi, x0, y0, h, posts,
                 depth, max_eval, ftol, memory, inv_diag, max_disp, max_turn, trace):
    """L-BFGS in place on pos, ori. inv_diag (nm, 6): D^-1 (ones: no preconditioning);
    max_disp, max_turn: the step caps (MAX_DISP, MAX_TURN).

    trace (K, 2): energy and largest residual force of evaluation k < K.
    Returns (E, max residual force, evaluations, iterations, stalled)."""
    n = pos.shape[0]
    nm = len(mobile)
    grad_pos = np.zeros((n, 3))
    grad_ori = np.zeros((n, 3))
    g = np.zeros((nm, 6))
    gp = np.zeros((nm, 6))
    g_new = np.zeros((nm, 6))
    gp_new = np.zeros((nm, 6))
    mode = np.zeros(nm, np.int64)
    wall = np.zeros(nm, np.int64)
    normal = np.zeros((nm, 2))
    mode_new = np.zeros(nm, np.int64)
    wall_new = np.zeros(nm, np.int64)
    normal_new = np.zeros((nm, 2))
    clear = np.empty(nm)
    clear_new = np.empty(nm)
    for m in range(nm):
        clear[m] = region_distance(phi, x0, y0, h, posts, pos[mobile[m], 0], pos[mobile[m], 1])
    s_mem = np.zeros((memory, nm, 6))
    y_mem = np.zeros((memory, nm, 6))
    rho = np.zeros(memory)
    alpha = np.zeros(memory)
    d = np.zeros((nm, 6))
    x_old = np.zeros((nm, 6))

    e, fmax = _gradients(pos, ori, mobile, bond_i, bond_j, kbar, rest, delta, phi, x0, y0, h,
                         posts, depth, grad_pos, grad_ori, g, gp, mode, wall, normal, clear)
    evals = 1
    if trace.shape[0] > 0:
        trace[0, 0] = e
        trace[0, 1] = fmax
    stored = 0
    head = 0
    gamma = 1.0
    iters = 0
    stalled = False
    while fmax >= ftol and evals < max_eval and math.isfinite(e):
        iters += 1
        # Two-loop recursion: d = -H gp.
        for m in range(nm):
            for a in range(6):
                d[m, a] = -gp[m, a]
        for j in range(stored):
            idx = (head - 1 - j) % memory
            alpha[idx] = rho[idx] * _dot(s_mem[idx], d)
            _axpy(-alpha[idx], y_mem[idx], d)
        for m in range(nm):
            for a in range(6):
                d[m, a] *= gamma * inv_diag[m, a]
        for j in range(stored - 1, -1, -1):
            idx = (head - 1 - j) % memory
            beta = rho[idx] * _dot(y_mem[idx], d)
            _axpy(alpha[idx] - beta, s_mem[idx], d)
        # Keep held cells on their walls and orientations in the tangent plane.
        hold_on_walls(d, mode, normal)
        for m in range(nm):
            c = mobile[m]
            dot = ori[c, 0] * d[m, 3] + ori[c, 1] * d[m, 4] + ori[c, 2] * d[m, 5]
            for a in range(3):
                d[m, 3 + a] -= dot * ori[c, a]
        if _dot(gp, d) >= 0.0:  # not a descent direction: forget the pairs
            stored = 0
            for m in range(nm):
                for a in range(6):
                    d[m, a] = -gp[m, a]
        disp = 0.0
        turn = 0.0
        for m in range(nm):
            disp = max(disp, math.sqrt(d[m, 0] ** 2 + d[m, 1] ** 2 + d[m, 2] ** 2))
            turn = max(turn, math.sqrt(d[m, 3] ** 2 + d[m, 4] ** 2 + d[m, 5] ** 2))
        step = 1.0
        if stored == 0:
            step = FIRST_DISP / max(disp, turn, 1e-300)
        if step * disp > max_disp:
            step = max_disp / disp
        if step * turn > max_turn:
            step = max_turn / turn
        for m in range(nm):
            c = mobile[m]
            for a in range(3):
                x_old[m, a] = pos[c, a]
                x_old[m, 3 + a] = ori[c, a]
        accepted = False
        e_new = e
        fmax_new = fmax
        for _ in range(MAX_BACKTRACK):
            decrease = 0.0  # gp . (x_trial - x): the first-order change along the projected path
            for m in range(nm):
                c = mobile[m]
                x = x_old[m, 0] + step * d[m, 0]
                y = x_old[m, 1] + step * d[m, 1]
                reach = LIPSCHITZ * step * math.sqrt(d[m, 0] ** 2 + d[m, 1] ** 2)
                if reach < clear[m] and mode[m] & 3 != SLIDE:  # cannot have left the region
                    clear_new[m] = clear[m] - reach
                else:
                    x, y = place(phi, x0, y0, h, posts, x, y,
                                 wall[m] if mode[m] & 3 == SLIDE else -1, x_old[m, 0], x_old[m, 1])
                    clear_new[m] = region_distance(phi, x0, y0, h, posts, x, y)
                pos[c, 0] = x
                pos[c, 1] = y
                pos[c, 2] = min(max(x_old[m, 2] + step * d[m, 2], 0.0), depth)
                norm2 = 0.0
                for a in range(3):
                    ori[c, a] = x_old[m, 3 + a] + step * d[m, 3 + a]
                    norm2 += ori[c, a] * ori[c, a]
                inv = 1.0 / math.sqrt(norm2)
                for a in range(3):
                    ori[c, a] *= inv
                    decrease += gp[m, a] * (pos[c, a] - x_old[m, a])
                    decrease += gp[m, 3 + a] * (ori[c, a] - x_old[m, 3 + a])
            e_new, fmax_new = _gradients(pos, ori, mobile, bond_i, bond_j, kbar, rest, delta,
                                         phi, x0, y0, h, posts, depth, grad_pos, grad_ori, g_new,
                                         gp_new, mode_new, wall_new, normal_new, clear_new)
            if evals < trace.shape[0]:
                trace[evals, 0] = e_new
                trace[evals, 1] = fmax_new
            evals += 1
            if math.isfinite(e_new) and e_new <= e + ARMIJO * decrease:
                accepted = True
                break
            if evals >= max_eval:
                break
            step *= 0.5
        if not accepted:
            for m in range(nm):
                c = mobile[m]
                for a in range(3):
                    pos[c, a] = x_old[m, a]
                    ori[c, a] = x_old[m, 3 + a]
            stalled = evals < max_eval
            break
        sy = 0.0
        yhy = 0.0
        for m in range(nm):
            c = mobile[m]
            for a in range(3):
                s_mem[head, m, a] = pos[c, a] - x_old[m, a]
                s_mem[head, m, 3 + a] = ori[c, a] - x_old[m, 3 + a]
            for a in range(6):
                y_mem[head, m, a] = g_new[m, a] - g[m, a]
                sy += s_mem[head, m, a] * y_mem[head, m, a]
                yhy += y_mem[head, m, a] * y_mem[head, m, a] * inv_diag[m, a]
        if sy > 0.0 and yhy > 0.0:
            rho[head] = 1.0 / sy
            gamma = sy / yhy
            head = (head + 1) % memory
            stored = min(stored + 1, memory)
        e = e_new
        fmax = fmax_new
        for m in range(nm):
            clear[m] = clear_new[m]
            mode[m] = mode_new[m]
            wall[m] = wall_new[m]
            normal[m, 0] = normal_new[m, 0]
            normal[m, 1] = normal_new[m, 1]
            for a in range(6):
                g[m, a] = g_new[m, a]
                gp[m, a] = gp_new[m, a]
    return e, fmax, evals, iters, stalled


def stiffness_diagonal(lattice, delta: float = DELTA) -> np.ndarray:
    """The preconditioner's D (N, 2): per cell, sum of kbar over its bonds (positions) and
    sum of kbar (l0 Delta)^2 2/15 (orientations)."""
    diag = np.zeros((lattice.n_cells, 2))
    for ends in (lattice.bond_i, lattice.bond_j):
        np.add.at(diag[:, 0], ends, lattice.bond_kbar)
        np.add.at(diag[:, 1], ends, lattice.bond_kbar * (lattice.bond_rest * delta) ** 2 * 2 / 15)
    return diag


def minimise_lbfgs(lattice, positions, orientations, max_iter: int, ftol: float,
                   memory: int = MEMORY, precondition: bool = True, delta: float = DELTA,
                   max_disp: float = MAX_DISP, max_turn: float = MAX_TURN,
                   trace: np.ndarray | None = None, positions_only: bool = False):
    """Minimise copies of (positions, orientations) with L-BFGS; return (pos, ori, info).

    The start is first projected into the region (info `start_projection`, l0).
    max_iter: energy+gradient evaluations; ftol: largest residual force, kappa0 l0.
    trace: optional float64 (K, 2) filled with (energy, max residual force) per evaluation.
    positions_only: the orientations stay as they are (their part of the preconditioner is 0,
    so no search direction turns them); the residual force still counts their torques, so
    such a run stops at max_iter.
    info: iterations, evaluations, max_force, converged, stalled."""
    if max_iter < 1:
        raise ValueError(f"max_iter must be >= 1, got {max_iter}")
    if memory < 1:
        raise ValueError(f"memory must be >= 1 pair, got {memory}")
    pos = np.array(positions, dtype=np.float64, order="C")
    ori = np.array(orientations, dtype=np.float64, order="C")
    ori /= np.linalg.norm(ori, axis=1, keepdims=True)
    mobile = np.flatnonzero(~lattice.fixed).astype(np.int64)
    r = lattice.region
    moved = project_state(pos, mobile, r.phi, r.phi_x0, r.phi_y0, r.phi_h, r.posts, r.depth)
    inv_diag = np.ones((len(mobile), 6))
    if precondition:
        diag = stiffness_diagonal(lattice, delta)[mobile]
        inv_diag[:, :3] = 1.0 / diag[:, :1]
        inv_diag[:, 3:] = 1.0 / diag[:, 1:]
        inv_diag /= inv_diag.mean()
    if positions_only:
        inv_diag[:, 3:] = 0.0
    e, fmax, evals, iters, stalled = lbfgs_kernel(
        pos, ori, mobile, lattice.bond_i, lattice.bond_j, lattice.bond_kbar, lattice.bond_rest,
        delta, r.phi, r.phi_x0, r.phi_y0, r.phi_h, r.posts, r.depth, int(max_iter), float(ftol),
        int(memory), inv_diag, float(max_disp), float(max_turn),
        np.zeros((0, 2)) if trace is None else trace)
    info = {
        "min_iterations": int(iters),
        "min_evaluations": int(evals),
        "min_max_force": float(fmax),
        "min_converged": bool(fmax < ftol),
        "min_stalled": bool(stalled),
        "start_projection": float(moved),
    }
    return pos, ori, info
