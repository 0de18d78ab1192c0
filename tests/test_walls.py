"""Tests of the hard confinement: projected forces, projection onto the region, residuals."""

import numpy as np
import pytest
from shapely.geometry import Point, box

from condor.model.lattice import build_lattice
from condor.model.walls import (FLOOR, LAND, LID, ON_WALL, PINNED, SLIDE, place, project_force,
                          project_state, residual_forces)

SQUARE = box(0, 0, 8, 6)
POST = np.array([[4.0, 3.0, 1.0]])
DEPTH = 2.0


@pytest.fixture(scope="module")
def region():
    return build_lattice(SQUARE, POST, DEPTH).region


def _args(r):
    return r.phi, r.phi_x0, r.phi_y0, r.phi_h, r.posts


def _cone_projection(f, normals, n_angles=200_000):
    """Brute force: the nearest point to f of the cone {v : v.n >= 0 for every n}."""
    angles = np.linspace(0, 2 * np.pi, n_angles, endpoint=False)
    u = np.stack([np.cos(angles), np.sin(angles)], axis=1)
    ok = np.all(u @ np.array(normals).T >= -1e-12, axis=1)
    u = u[ok]
    t = np.maximum(u @ f, 0.0)  # best length along each allowed direction
    cand = t[:, None] * u
    cand = np.vstack([cand, [0.0, 0.0]])
    if np.all(np.array(normals) @ f >= 0):
        return f
    return cand[np.argmin(np.linalg.norm(cand - f, axis=1))]


def test_force_on_one_wall_loses_its_outward_part(region):
    # on the post (inward normal = radial direction)
    x, y = 4.0 + 1.0 + 0.5 * LAND, 3.0
    fx, fy, fz, mode, wall, nx, ny = project_force(*_args(region), DEPTH, x, y, 1.0, -0.3, 0.2, 0.1)
    assert mode == SLIDE and wall == 1 and np.allclose([nx, ny], [1, 0])
    assert np.allclose([fx, fy, fz], [0.0, 0.2, 0.1])
    # pulled away from the post: nothing removed
    out = project_force(*_args(region), DEPTH, x, y, 1.0, 0.3, 0.2, 0.1)
    assert out[3] == 0 and np.allclose(out[:3], [0.3, 0.2, 0.1])
    # on the left wall (polygon), pressed into it
    out = project_force(*_args(region), DEPTH, 0.5 * LAND, 2.0, 1.0, -1.0, 0.5, 0.0)
    assert out[3] == SLIDE and out[4] == 0 and np.allclose(out[:3], [0.0, 0.5, 0.0])
    # away from every wall: unchanged
    out = project_force(*_args(region), DEPTH, 1.5, 1.5, 1.0, -1.0, 0.5, 0.2)
    assert out[3] == 0 and np.allclose(out[:3], [-1.0, 0.5, 0.2])


def test_floor_and_lid_hold_z_only_when_pressed(region):
    out = project_force(*_args(region), DEPTH, 1.5, 1.5, 0.0, 0.1, 0.2, -0.4)
    assert out[3] == FLOOR and np.allclose(out[:3], [0.1, 0.2, 0.0])
    out = project_force(*_args(region), DEPTH, 1.5, 1.5, DEPTH, 0.1, 0.2, 0.4)
    assert out[3] == LID and np.allclose(out[:3], [0.1, 0.2, 0.0])
    out = project_force(*_args(region), DEPTH, 1.5, 1.5, 0.0, 0.1, 0.2, 0.4)
    assert out[3] == 0 and np.allclose(out[:3], [0.1, 0.2, 0.4])


def test_corner_of_post_and_wall_projects_onto_the_cone_of_allowed_directions():
    """A post crossing the bottom wall: at the point where its circle meets y = 0 the cell
    touches two walls; the projected force is the nearest allowed force (brute force)."""
    r = build_lattice(SQUARE, np.array([[4.0, 0.5, 1.0]]), DEPTH).region
    x, y = 4.0 + np.sqrt(1.0 - 0.5**2), 0.0  # circle meets y = 0
    n_post = np.array([x - 4.0, y - 0.5])
    normals = [n_post / np.linalg.norm(n_post), np.array([0.0, 1.0])]
    rng = np.random.default_rng([0, 9])
    modes = set()
    for f in rng.normal(size=(200, 2)):
        fx, fy, _, mode, *_ = project_force(*_args(r), DEPTH, x, y, 1.0, f[0], f[1], 0.0)
        modes.add(mode & 3)
        assert np.allclose([fx, fy], _cone_projection(f, normals), atol=2e-4)
    assert modes == {0, SLIDE, PINNED}  # free, sliding along either wall, pinned


def test_place_lands_exactly_on_the_crossed_wall(region):
    rng = np.random.default_rng([1, 2])
    # outside the left wall: lands at x in [0, LAND] with the same y (straight wall: exact)
    for y in rng.uniform(1, 5, 20):
        x_new, y_new = place(*_args(region), -0.3, y, -1, 0.5, y)
        assert 0.0 <= x_new <= LAND and y_new == pytest.approx(y, abs=1e-12)
    # inside the post: lands on its circle along the radius
    for angle in rng.uniform(0, 2 * np.pi, 20):
        u = np.array([np.cos(angle), np.sin(angle)])
        x_new, y_new = place(*_args(region), *(POST[0, :2] + 0.6 * u), -1, *(POST[0, :2] + 2 * u))
        d = np.hypot(x_new - 4.0, y_new - 3.0) - 1.0
        assert 0.0 <= d <= LAND
        assert np.allclose((np.array([x_new, y_new]) - POST[0, :2]), u, atol=1e-9)
    # a sliding cell moved off its wall into the region comes back onto it
    x_new, y_new = place(*_args(region), 5.3, 3.2, 1, 5.0, 3.0)
    assert 0.0 <= np.hypot(x_new - 4, y_new - 3) - 1 <= LAND


def test_project_state_puts_every_cell_inside(region):
    lat = build_lattice(SQUARE, POST, DEPTH)
    rng = np.random.default_rng([3, 4])
    pos = lat.positions + rng.normal(scale=0.4, size=lat.positions.shape)
    mobile = np.flatnonzero(~lat.fixed)
    moved = project_state(pos, mobile, *_args(lat.region), DEPTH)
    assert moved > 0.1
    assert lat.region.violation(pos[mobile]).max() == 0.0
    inside_poly = SQUARE.buffer(1e-9).contains
    assert all(inside_poly(Point(p)) for p in pos[mobile, :2])


def test_residual_forces_match_an_independent_computation():
    """FIRE's final state (soft walls, then projected onto the region) leaves cells on the
    posts, pressed into them: the residual equals the force minus its outward normal part,
    with the normal of the exact circle, computed here without condor.model.walls."""
    from condor.model.energy import DELTA, energy_gradient
    from condor.model.simulate import simulate

    posts = np.array([[2.0, 3.0, 0.8], [6.0, 3.0, 0.8]])
    lat = build_lattice(SQUARE, posts, DEPTH)
    r = simulate(SQUARE, posts, DEPTH, "minimise", seed=4)
    pos, ori = r.positions.copy(), r.orientations
    # cells the projection left within 1e-6 l0 of a post go exactly onto it
    k = np.argmin(np.hypot(pos[:, :1] - posts[:, 0], pos[:, 1:2] - posts[:, 1]), axis=1)
    centre, radius = posts[k, :2], posts[k, 2]
    rel = pos[:, :2] - centre
    dist = np.linalg.norm(rel, axis=1)
    normal = rel / dist[:, None]
    on_post = (dist - radius < 1e-6) & ~lat.fixed
    pos[on_post, :2] = centre[on_post] + (radius[on_post, None] + 0.5 * LAND) * normal[on_post]
    res = residual_forces(lat, pos, ori)
    gp, go = np.zeros_like(pos), np.zeros_like(pos)
    energy_gradient(pos, ori, lat.bond_i, lat.bond_j, lat.bond_kbar, lat.bond_rest, DELTA, gp, go)
    expect = -gp
    go -= np.einsum("ij,ij->i", go, ori)[:, None] * ori
    fn = np.einsum("ij,ij->i", expect[:, :2], normal)
    push = on_post & (fn < 0)
    expect[push, :2] -= fn[push, None] * normal[push]
    for axis, top in ((0, 8.0), (1, 6.0)):  # the box walls: straight, so the grid is exact
        low = (pos[:, axis] <= ON_WALL) & (expect[:, axis] < 0)
        high = (pos[:, axis] >= top - ON_WALL) & (expect[:, axis] > 0)
        expect[low | high, axis] = 0.0
    floor = (pos[:, 2] <= ON_WALL) & (expect[:, 2] < 0)
    lid = (pos[:, 2] >= DEPTH - ON_WALL) & (expect[:, 2] > 0)
    expect[floor | lid, 2] = 0.0
    want = np.maximum(np.linalg.norm(expect, axis=1), np.linalg.norm(go, axis=1))
    want[lat.fixed] = 0.0
    assert push.sum() >= 5 and (-fn[push]).max() > 0.05  # cells really press on the post
    assert np.allclose(res, want, atol=1e-9)
