"""The allowed region as a hard constraint: walls a cell touches, projected forces, projection.

A mobile cell must satisfy, in the plane, phi(x, y) >= 0 (the polygon's bilinear signed
distance, `condor.model.lattice`) and |(x, y) - c_k| >= r_k for every post k (exact circles), and
0 <= z <= depth. Each is one constraint; a cell is *on* a constraint when its value is at most
ON_WALL (l0). Projection lands a cell within [0, LAND] of the wall it crossed.

Force balance at a wall (the projected force): the force f = -dE/dr of a cell on walls whose
inward unit normals are n_1, n_2 may push outward; the walls answer with a reaction along
-n, so what is left is the projection of f onto the cone of allowed directions
{v : v.n_1 >= 0, v.n_2 >= 0}. One wall: f minus its outward normal part. Two walls (a post
meeting a wall, or two posts): f, its slide along either wall, or 0 (the cell is pinned in the
corner), whichever is nearest f. z is its own coordinate: a cell on the floor keeps
max(f_z, 0), on the lid min(f_z, 0). The orientation part is the tangent force on the sphere.

A cell's residual force is the larger of the norms of its projected position force and its
tangent orientation force (kappa0 l0); a state is balanced to ftol when every mobile cell's
residual is below ftol, including cells pressed on walls and posts.

Cell modes (what a minimiser may move): plane part 0 free, 1 slides along wall `wall_a`,
2 pinned in a corner; bit 4 on the floor, bit 8 on the lid (z held).
"""

from __future__ import annotations

import math

import numba
import numpy as np

from condor.model.energy import DELTA, energy_gradient
from condor.model.lattice import phi_grad_at, region_distance

ON_WALL = 1.0e-9  # l0: a cell this close to a wall touches it
# A bound on |grad| of the plane distance: 1 for a post, sqrt 2 for the bilinear interpolant
# of a distance (each axis derivative is a difference quotient of a 1-Lipschitz function), so a
# cell that moves by u in the plane changes its distance by at most LIPSCHITZ u.
LIPSCHITZ = 1.5
LAND = 1.0e-10  # l0: projection lands a cell within [0, LAND] of the wall it crossed
SLIDE = 1
PINNED = 2
FLOOR = 4
LID = 8
_NEWTON_STEPS = 30
_BRACKET_STEPS = 100


@numba.njit(cache=True)
def constraint(phi, x0, y0, h, posts, j, x, y):
    """Constraint j at (x, y): (value, d/dx, d/dy); j = 0 the polygon, j = k + 1 post k.

    Values are signed distances, l0 (>= 0 allowed)."""
    if j == 0:
        return phi_grad_at(phi, x0, y0, h, x, y)
    dx = x - posts[j - 1, 0]
    dy = y - posts[j - 1, 1]
    r = math.sqrt(dx * dx + dy * dy)
    if r == 0.0:
        return -posts[j - 1, 2], 1.0, 0.0
    return r - posts[j - 1, 2], dx / r, dy / r


@numba.njit(cache=True)
def touching(phi, x0, y0, h, posts, x, y):
    """The (at most two) plane constraints a point touches: (count, j_a, j_b), smallest first."""
    count = 0
    ja = -1
    jb = -1
    va = 1e300
    vb = 1e300
    for j in range(posts.shape[0] + 1):
        v = constraint(phi, x0, y0, h, posts, j, x, y)[0]
        if v <= ON_WALL:
            count += 1
            if v < va:
                jb, vb = ja, va
                ja, va = j, v
            elif v < vb:
                jb, vb = j, v
    return min(count, 2), ja, jb


@numba.njit(cache=True)
def _unit_normal(phi, x0, y0, h, posts, j, x, y):
    val, gx, gy = constraint(phi, x0, y0, h, posts, j, x, y)
    norm = math.sqrt(gx * gx + gy * gy)
    if norm == 0.0:
        return 0.0, 0.0
    return gx / norm, gy / norm


@numba.njit(cache=True)
def project_force(phi, x0, y0, h, posts, depth, x, y, z, fx, fy, fz, plane=True):
    """Projected force of a cell at (x, y, z) under force (fx, fy, fz) (see the module text).
    plane False: the caller knows the cell touches no plane wall (only z is checked).

    Returns (fx, fy, fz, mode, wall, nx, ny): the projected force, the cell's mode, and for
    a sliding cell the wall it slides on and that wall's inward unit normal."""
    mode = 0
    wall = -1
    nx = 0.0
    ny = 0.0
    count = 0
    ja = jb = -1
    if plane:
        count, ja, jb = touching(phi, x0, y0, h, posts, x, y)
    if count >= 1:
        ax, ay = _unit_normal(phi, x0, y0, h, posts, ja, x, y)
        fa = fx * ax + fy * ay
        if count == 1:
            if fa < 0.0:
                fx -= fa * ax
                fy -= fa * ay
                mode = SLIDE
                wall, nx, ny = ja, ax, ay
        else:
            bx, by = _unit_normal(phi, x0, y0, h, posts, jb, x, y)
            fb = fx * bx + fy * by
            if fa < 0.0 or fb < 0.0:
                # nearest point of the wedge {v.a >= 0, v.b >= 0}: its edges or its apex
                best = fx * fx + fy * fy  # distance^2 to the apex (pinned)
                px = 0.0
                py = 0.0
                mode = PINNED
                sx = fx - fa * ax
                sy = fy - fa * ay
                if sx * bx + sy * by >= 0.0 and fa * fa < best:
                    best = fa * fa
                    px, py, mode, wall, nx, ny = sx, sy, SLIDE, ja, ax, ay
                sx = fx - fb * bx
                sy = fy - fb * by
                if sx * ax + sy * ay >= 0.0 and fb * fb < best:
                    best = fb * fb
                    px, py, mode, wall, nx, ny = sx, sy, SLIDE, jb, bx, by
                fx, fy = px, py
    if z <= ON_WALL and fz < 0.0:
        fz = 0.0
        mode |= FLOOR
    elif z >= depth - ON_WALL and fz > 0.0:
        fz = 0.0
        mode |= LID
    return fx, fy, fz, mode, wall, nx, ny


@numba.njit(cache=True)
def hold_on_walls(vec, mode, normal):
    """Remove, in place, the parts of per-cell moves vec (nm, >= 3; positions first) that
    would take a held cell off its walls: the normal part on a wall it slides along, all of
    the plane part in a corner, z on the floor or lid (`mode`, `normal` of the active set)."""
    for m in range(len(mode)):
        md = mode[m]
        if md & 3 == SLIDE:
            vn = vec[m, 0] * normal[m, 0] + vec[m, 1] * normal[m, 1]
            vec[m, 0] -= vn * normal[m, 0]
            vec[m, 1] -= vn * normal[m, 1]
        elif md & 3 == PINNED:
            vec[m, 0] = 0.0
            vec[m, 1] = 0.0
        if md & (FLOOR | LID):
            vec[m, 2] = 0.0


@numba.njit(cache=True)
def _regula_falsi(phi, x0, y0, h, posts, j, ox, oy, ov, ix, iy, iv):
    """Shrink the segment from (ox, oy) (value ov < 0) to (ix, iy) (iv >= 0) until its inside
    end is within [0, LAND] of wall j (j < 0: of the whole region); return that end."""
    for _ in range(_BRACKET_STEPS):
        t = min(max(ov / (ov - iv), 0.01), 0.99)
        mx = ox + t * (ix - ox)
        my = oy + t * (iy - oy)
        if j >= 0:
            mv = constraint(phi, x0, y0, h, posts, j, mx, my)[0]
        else:
            mv = region_distance(phi, x0, y0, h, posts, mx, my)
        if mv >= 0.0:
            ix, iy, iv = mx, my, mv
            if iv <= LAND:
                break
        else:
            ox, oy, ov = mx, my, mv
    return ix, iy


@numba.njit(cache=True)
def land(phi, x0, y0, h, posts, j, x, y, onto):
    """Move (x, y) along the gradient of constraint j until it is satisfied (onto: until it is
    within [0, LAND]); Newton steps, then regula falsi on a bracketing segment.

    Returns (x, y, ok); ok False when no point with a value >= 0 was found."""
    v, gx, gy = constraint(phi, x0, y0, h, posts, j, x, y)
    if v >= 0.0 and (not onto or v <= LAND):
        return x, y, True
    have_in = v >= 0.0
    have_out = not have_in
    ix, iy, iv = x, y, v
    ox, oy, ov = x, y, v
    for _ in range(_NEWTON_STEPS):
        g2 = gx * gx + gy * gy
        if g2 == 0.0:
            break
        # aim at LAND / 2 so that round-off keeps the landing point inside
        x -= (v - 0.5 * LAND) * gx / g2
        y -= (v - 0.5 * LAND) * gy / g2
        v, gx, gy = constraint(phi, x0, y0, h, posts, j, x, y)
        if 0.0 <= v <= LAND:
            return x, y, True
        if v >= 0.0:
            ix, iy, iv = x, y, v
            have_in = True
            if not onto:
                return x, y, True
        else:
            ox, oy, ov = x, y, v
            have_out = True
        if have_in and have_out:
            break
    if not have_in:
        return x, y, False
    if have_out:
        ix, iy = _regula_falsi(phi, x0, y0, h, posts, j, ox, oy, ov, ix, iy, iv)
    return ix, iy, True


@numba.njit(cache=True)
def place(phi, x0, y0, h, posts, x, y, wall, old_x, old_y):
    """Put a moved cell (x, y) back into the plane region; a cell sliding on `wall` (>= 0)
    lands on it again. (old_x, old_y): where it came from, inside the region, the fallback
    bracket. Returns (x, y)."""
    if wall >= 0:
        x, y, ok = land(phi, x0, y0, h, posts, wall, x, y, True)
    for _ in range(20):  # alternate over violated walls (converges to a corner)
        worst = 0.0
        jw = -1
        for j in range(posts.shape[0] + 1):
            v = constraint(phi, x0, y0, h, posts, j, x, y)[0]
            if v < worst:
                worst, jw = v, j
        if jw < 0:
            return x, y
        x, y, ok = land(phi, x0, y0, h, posts, jw, x, y, True)
        if not ok:
            break
    # Last resort: the crossing of the straight move from the old point with the region.
    ix, iy = old_x, old_y
    iv = region_distance(phi, x0, y0, h, posts, ix, iy)
    ov = region_distance(phi, x0, y0, h, posts, x, y)
    if ov >= 0.0:
        return x, y
    return _regula_falsi(phi, x0, y0, h, posts, -1, x, y, ov, ix, iy, iv)


@numba.njit(cache=True)
def project_state(pos, mobile, phi, x0, y0, h, posts, depth):
    """Project every mobile cell into the region (plane part by `place`, z clamped); return
    the largest distance moved, l0."""
    worst = 0.0
    for m in range(len(mobile)):
        c = mobile[m]
        x, y = place(phi, x0, y0, h, posts, pos[c, 0], pos[c, 1], -1, pos[c, 0], pos[c, 1])
        moved = math.sqrt((x - pos[c, 0]) ** 2 + (y - pos[c, 1]) ** 2)
        pos[c, 0] = x
        pos[c, 1] = y
        if pos[c, 2] < 0.0:
            moved = max(moved, -pos[c, 2])
            pos[c, 2] = 0.0
        elif pos[c, 2] > depth:
            moved = max(moved, pos[c, 2] - depth)
            pos[c, 2] = depth
        worst = max(worst, moved)
    return worst


@numba.njit(cache=True)
def residual_kernel(pos, ori, mobile, bond_i, bond_j, kbar, rest, delta, phi, x0, y0, h, posts,
                    depth, out):
    """Residual force of every mobile cell into out[m] (kappa0 l0); returns the energy."""
    n = pos.shape[0]
    grad_pos = np.zeros((n, 3))
    grad_ori = np.zeros((n, 3))
    e = energy_gradient(pos, ori, bond_i, bond_j, kbar, rest, delta, grad_pos, grad_ori)
    for m in range(len(mobile)):
        c = mobile[m]
        fx, fy, fz, mode, wall, nx, ny = project_force(
            phi, x0, y0, h, posts, depth, pos[c, 0], pos[c, 1], pos[c, 2],
            -grad_pos[c, 0], -grad_pos[c, 1], -grad_pos[c, 2])
        dot = ori[c, 0] * grad_ori[c, 0] + ori[c, 1] * grad_ori[c, 1] + ori[c, 2] * grad_ori[c, 2]
        fo2 = 0.0
        for a in range(3):
            t = grad_ori[c, a] - dot * ori[c, a]
            fo2 += t * t
        out[m] = math.sqrt(max(fx * fx + fy * fy + fz * fz, fo2))
    return e


def residual_forces(lattice, positions, orientations, delta: float = DELTA) -> np.ndarray:
    """Residual force of every cell (N,), kappa0 l0: projected position force or tangent
    orientation force, whichever is larger (0 for post cells). Positions must lie in the
    region (cells outside are treated as free)."""
    pos = np.ascontiguousarray(positions, dtype=np.float64)
    ori = np.ascontiguousarray(orientations, dtype=np.float64)
    mobile = np.flatnonzero(~lattice.fixed).astype(np.int64)
    r = lattice.region
    out = np.zeros(len(mobile))
    residual_kernel(pos, ori, mobile, lattice.bond_i, lattice.bond_j, lattice.bond_kbar,
                    lattice.bond_rest, delta, r.phi, r.phi_x0, r.phi_y0, r.phi_h, r.posts,
                    r.depth, out)
    full = np.zeros(lattice.n_cells)
    full[mobile] = out
    return full
