"""Tests of the L-BFGS minimiser with exact walls (condor.model.lbfgs)."""

import numpy as np
import pytest
from shapely.geometry import box

from condor.model.energy import DELTA, energy_gradient, random_orientations, total_energy
from condor.model.lattice import build_lattice
from condor.model.lbfgs import minimise_lbfgs
from condor.model.minimise import minimise

WIDTH, HEIGHT, DEPTH = 8.0, 6.0, 2.0
SQUARE = box(0, 0, WIDTH, HEIGHT)
TWO_POSTS = np.array([[2.0, 3.0, 0.8], [6.0, 3.0, 0.8]])  # the gel presses on these posts
ON = 1e-9  # l0, "touching"


def args(lat):
    return lat.bond_i, lat.bond_j, lat.bond_kbar, lat.bond_rest, DELTA


@pytest.fixture(scope="module")
def lattice():
    return build_lattice(SQUARE, TWO_POSTS, DEPTH)


def balance(lat, pos, ori):
    """Per cell, without condor.model.walls: the force left after the exact walls (box sides,
    post circles, floor, lid) take the outward normal part of pressing cells; the tangent
    orientation force; and the normal force each post takes (> 0 pressing)."""
    gp, go = np.zeros_like(pos), np.zeros_like(pos)
    energy_gradient(pos, ori, *args(lat), gp, go)
    force = -gp
    go -= np.einsum("ij,ij->i", go, ori)[:, None] * ori
    rel = pos[:, None, :2] - TWO_POSTS[None, :, :2]
    dist = np.linalg.norm(rel, axis=2)
    k = np.argmin(dist - TWO_POSTS[:, 2], axis=1)
    rows = np.arange(len(pos))
    normal = rel[rows, k] / dist[rows, k, None]
    on_post = (dist[rows, k] - TWO_POSTS[k, 2] <= ON) & ~lat.fixed
    fn = np.einsum("ij,ij->i", force[:, :2], normal)
    press = on_post & (fn < 0)
    force[press, :2] -= fn[press, None] * normal[press]
    for axis, top in ((0, WIDTH), (1, HEIGHT), (2, DEPTH)):
        low = (pos[:, axis] <= ON) & (force[:, axis] < 0)
        high = (pos[:, axis] >= top - ON) & (force[:, axis] > 0)
        force[low | high, axis] = 0.0
    residual = np.maximum(np.linalg.norm(force, axis=1), np.linalg.norm(go, axis=1))
    residual[lat.fixed] = 0.0
    return residual, np.where(press, -fn, 0.0)


def test_balanced_to_ftol_on_every_cell_including_cells_pressed_on_posts(lattice):
    lat = lattice
    ori = random_orientations(lat.n_cells, np.random.default_rng([0, 5]))
    ftol = 1e-4
    pos, o, info = minimise_lbfgs(lat, lat.positions, ori, max_iter=20000, ftol=ftol)
    assert info["min_converged"] and info["min_max_force"] < ftol
    residual, pressing = balance(lat, pos, o)
    assert (pressing > 10 * ftol).sum() >= 5  # the gel really presses on its posts
    assert residual.max() <= ftol
    assert residual.max() == pytest.approx(info["min_max_force"], rel=1e-6)
    # exactly inside, posts untouched, unit orientations
    assert lat.region.violation(pos[~lat.fixed]).max() == 0.0
    assert np.array_equal(pos[lat.fixed], lat.positions[lat.fixed])
    assert np.allclose(np.linalg.norm(o, axis=1), 1.0, atol=1e-12)
    assert total_energy(pos, o, *args(lat)) < 0.2 * total_energy(lat.positions, ori, *args(lat))


def test_fire_leaves_pressed_cells_unbalanced_where_lbfgs_does_not(lattice):
    """The control: FIRE's soft wall then projection leaves cells on the posts with sideways
    forces far above its tolerance, which the same check flags."""
    lat = lattice
    ori = random_orientations(lat.n_cells, np.random.default_rng([0, 5]))
    pos, o, info = minimise(lat, lat.positions, ori, ftol=1e-4)
    assert info["min_converged"]
    # cells FIRE projected onto a post (to ~1e-9 l0) go exactly onto it
    rel = pos[:, None, :2] - TWO_POSTS[None, :, :2]
    gap = np.linalg.norm(rel, axis=2) - TWO_POSTS[:, 2]
    k = np.argmin(gap, axis=1)
    snap = (gap.min(axis=1) < 1e-6) & ~lat.fixed
    u = rel[snap, k[snap]] / np.linalg.norm(rel[snap, k[snap]], axis=1, keepdims=True)
    pos[snap, :2] = TWO_POSTS[k[snap], :2] + (TWO_POSTS[k[snap], 2:3] + 1e-11) * u
    residual, pressing = balance(lat, pos, o)
    assert snap.sum() >= 3 and residual[snap].max() > 100 * 1e-4


def test_reaches_the_energy_fire_reaches_from_the_same_start(lattice):
    lat = lattice
    for seed in range(3):
        ori = random_orientations(lat.n_cells, np.random.default_rng([seed, 1]))
        p1, o1, _ = minimise_lbfgs(lat, lat.positions, ori, 20000, 1e-5)
        p2, o2, _ = minimise(lat, lat.positions, ori, ftol=1e-5)
        e1, e2 = total_energy(p1, o1, *args(lat)), total_energy(p2, o2, *args(lat))
        assert e1 <= e2 * 1.01  # measured -0.1% to -0.2%: as low or lower


def test_deterministic_and_preconditioning_is_optional(lattice):
    lat = lattice
    ori = random_orientations(lat.n_cells, np.random.default_rng([2, 1]))
    a = minimise_lbfgs(lat, lat.positions, ori, 20000, 1e-4)
    b = minimise_lbfgs(lat, lat.positions, ori, 20000, 1e-4)
    assert np.array_equal(a[0], b[0]) and np.array_equal(a[1], b[1]) and a[2] == b[2]
    c = minimise_lbfgs(lat, lat.positions, ori, 20000, 1e-4, precondition=False, memory=5)
    assert c[2]["min_converged"]


def test_start_outside_is_projected_and_budget_is_respected(lattice):
    lat = lattice
    rng = np.random.default_rng([3, 3])
    start = lat.positions + rng.normal(scale=0.2, size=lat.positions.shape) * ~lat.fixed[:, None]
    assert lat.region.violation(start[~lat.fixed]).max() > 0.1
    ori = random_orientations(lat.n_cells, rng)
    trace = np.full((50, 2), np.nan)
    pos, o, info = minimise_lbfgs(lat, start, ori, max_iter=50, ftol=1e-6, trace=trace)
    assert info["start_projection"] > 0.1
    assert info["min_evaluations"] == 50 and not info["min_converged"]
    assert lat.region.violation(pos[~lat.fixed]).max() == 0.0
    assert np.all(np.isfinite(trace[:, 0]))  # every evaluation traced; [0] is the projected start
    assert total_energy(pos, o, *args(lat)) < 0.5 * trace[0, 0]
    with pytest.raises(ValueError, match="max_iter"):
        minimise_lbfgs(lat, start, ori, max_iter=0, ftol=1e-3)
    with pytest.raises(ValueError, match="memory"):
        minimise_lbfgs(lat, start, ori, max_iter=10, ftol=1e-3, memory=0)
