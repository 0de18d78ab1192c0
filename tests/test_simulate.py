"""Tests of simulate(): input errors, failure detection, stability cases, symmetry, I/O."""

import numpy as np
import pytest
from shapely.geometry import Polygon, box

from condor.energy import DELTA, total_energy
from condor.lattice import build_lattice
from condor.simulate import SOLVERS, SimResult, diagnose, simulate

SQUARE = box(0, 0, 8, 6)
TWO_POSTS = np.array([[2.0, 3.0, 0.8], [6.0, 3.0, 0.8]])


def inside(result, polygon, tethers, depth, tol=1e-6):
    lat = build_lattice(polygon, tethers, depth)
    return lat.region.violation(result.positions[~result.fixed]).max() <= tol


@pytest.mark.parametrize("solver", SOLVERS)
def test_each_solver_lowers_energy_and_stays_inside(solver):
    r = simulate(SQUARE, TWO_POSTS, 2.0, solver, budget=None if solver != "anneal" else 200, seed=1)
    assert r.status == "ok"
    assert r.energy < 0.5 * r.info["start_energy"]
    assert inside(r, SQUARE, TWO_POSTS, 2.0)
    lat = build_lattice(SQUARE, TWO_POSTS, 2.0)
    assert r.energy == pytest.approx(total_energy(r.positions, r.orientations, lat.bond_i, lat.bond_j,
                                                  lat.bond_kbar, lat.bond_rest, DELTA), rel=1e-12)
    assert r.seconds > 0 and r.n_cells == lat.n_cells and r.fixed.sum() > 0


def test_bad_input_raises_naming_the_value():
    with pytest.raises(ValueError, match="'annealing'"):
        simulate(SQUARE, TWO_POSTS, 2.0, solver="annealing")
    with pytest.raises(ValueError, match="-1"):
        simulate(SQUARE, TWO_POSTS, -1.0)
    with pytest.raises(ValueError, match="no mobile cell"):
        simulate(box(0, 0, 4, 4), np.array([[2.0, 2.0, 4.0]]), 2.0)
    with pytest.raises(ValueError, match="budget"):
        simulate(SQUARE, TWO_POSTS, 2.0, budget=-3)


def test_save_load_roundtrip(tmp_path):
    r = simulate(SQUARE, TWO_POSTS, 2.0, "minimise", seed=3)
    r.save(tmp_path / "r.npz")
    back = SimResult.load(tmp_path / "r.npz")
    for name in ("positions", "orientations", "fixed", "tension"):
        assert np.array_equal(getattr(back, name), getattr(r, name))
    for name in ("energy", "solver", "budget", "seed", "seconds", "status", "info"):
        assert getattr(back, name) == getattr(r, name)


def test_schedule_far_too_fast_is_valid_but_far_from_the_minimum():
    fast = simulate(SQUARE, TWO_POSTS, 2.0, "anneal", budget=1, seed=0)
    good = simulate(SQUARE, TWO_POSTS, 2.0, "minimise", seed=0)
    assert fast.status == "ok"  # a quench leaves a valid, unrelaxed network
    assert fast.energy > 10 * good.energy


def test_mould_without_tethers_contracts_freely():
    r = simulate(SQUARE, np.zeros((0, 3)), 2.0, "minimise", seed=0)
    assert r.status == "ok" and not r.fixed.any()
    # nothing holds the network, so it reaches a nearly stress-free state (measured 5.8e-4 per
    # cell against 0.14 at the start) and is in mean contracted (tension ~ 0)
    assert r.energy_per_cell < 0.02 * r.info["start_energy"] / r.n_cells
    assert np.abs(r.tension).mean() < 0.02
    assert inside(r, SQUARE, np.zeros((0, 3)), 2.0)


def test_thin_neck_stays_inside():
    neck = box(0, 0, 5, 5).union(box(9, 0, 14, 5)).union(box(5, 2.2, 9, 2.8))  # 0.6 l0 neck
    tethers = np.array([[2.5, 2.5, 0.8], [11.5, 2.5, 0.8]])
    r = simulate(neck, tethers, 2.0, "hybrid", seed=0)
    assert r.status == "ok", r.status
    assert inside(r, neck, tethers, 2.0)
    assert r.info["inverted_fraction"] < 0.01


def test_tether_touching_the_wall():
    tethers = np.array([[1.0, 3.0, 1.0], [7.5, 3.0, 1.0]])  # one tangent, one crossing the wall
    r = simulate(SQUARE, tethers, 2.0, "hybrid", seed=0)
    assert r.status == "ok", r.status
    assert inside(r, SQUARE, tethers, 2.0)


def test_failure_detection():
    lat = build_lattice(SQUARE, TWO_POSTS, 2.0)
    ori = np.tile([0.0, 0.0, 1.0], (lat.n_cells, 1))
    e0 = total_energy(lat.positions, ori, lat.bond_i, lat.bond_j, lat.bond_kbar, lat.bond_rest, DELTA)
    bad = lat.positions.copy()
    bad[0, 0] = np.nan
    assert diagnose(lat, bad, ori, np.nan, e0, {})["status_reason"].startswith("nonfinite")
    assert diagnose(lat, lat.positions, ori, 2 * e0, e0, {})["status_reason"].startswith("runaway")
    out = lat.positions.copy()
    out[~lat.fixed, 2] += 3.0  # lifted out of the mould
    assert diagnose(lat, out, ori, e0, e0, {})["status_reason"].startswith("escaped")
    folded = lat.positions.copy()
    upper = folded[:, 2] > 1.0
    folded[upper, 2] = 2.0 - folded[upper, 2]  # fold the top layers back through z = 1
    assert diagnose(lat, folded, ori, e0, e0, {})["status_reason"].startswith("folded")
    assert diagnose(lat, lat.positions, ori, e0, e0, {})["status_reason"] == "ok"


def test_mirror_symmetric_mould_gives_mirror_symmetric_density():
    """Orientation domains break the symmetry in each run; over seeds the density is symmetric.

    Measured: one run's 6x4-bin density differs from its mirror image by 12-22% (L1); the
    mean over 6 seeds by ~5-8%. Tolerance 12% for the mean, and asymmetry must shrink.
    """
    poly = Polygon([(0, 0), (12, 0), (10, 8), (2, 8)])
    tethers = np.array([[3.0, 2.0, 0.8], [9.0, 2.0, 0.8], [6.0, 6.0, 0.8]])
    edges = (np.linspace(0, 12, 7), np.linspace(0, 8, 5))
    hists = []
    for seed in range(6):
        r = simulate(poly, tethers, 2.0, "minimise", seed=seed)
        assert r.status == "ok"
        hists.append(np.histogram2d(r.positions[:, 0], r.positions[:, 1], edges)[0])
    asym = lambda h: np.abs(h - h[::-1]).sum() / h.sum()
    mean = np.mean(hists, axis=0)
    print("single-run asymmetry", [round(asym(h), 3) for h in hists], "mean", round(asym(mean), 3))
    assert asym(mean) < 0.12
    assert asym(mean) < np.mean([asym(h) for h in hists])
