"""Tests of simulate(): input errors, failure detection, symmetry, I/O (hard cases: test_stability)."""

import numpy as np
import pytest
from shapely.geometry import Polygon, box

from condor.model.energy import DELTA, total_energy
from condor.data.fields import cell_fields, normalise
from condor.model.lattice import build_lattice
from condor.model.simulate import (DEFAULT_FTOL, DEFAULT_SOLVER, SOLVERS, SimResult, diagnose, simulate,
                             simulate_lattice)

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


def _mirror_asymmetry(fields):
    """Per channel: L1 norm of (f - f mirrored in x) / L1 norm of f."""
    return np.abs(fields - fields[..., ::-1]).sum(axis=(-2, -1)) / np.abs(fields).sum(axis=(-2, -1))


def _trapezoid_fields(tethers, seeds):
    """Normalised fields on a 24 px grid over [0, 12]^2, symmetric about x = 6 (pixel edges
    at multiples of 0.5 l0), of the trapezoid mould for each seed."""
    poly = Polygon([(0, 0), (12, 0), (10, 8), (2, 8)])
    out = []
    for seed in seeds:
        r = simulate(poly, tethers, 2.0, "minimise", seed=seed)
        assert r.status == "ok", r.status
        f = cell_fields(r.positions, r.orientations, r.tension, 12.0, 24)
        out.append(normalise(f.astype(np.float64), r.n_cells))
    return np.array(out)


def test_mirror_symmetric_mould_gives_mirror_symmetric_fields():
    """Equilibrium respects the mirror symmetry up to noise: orientation domains break it in
    each run, so the tolerance is stated for one run (P, T) and for the mean over 8 seeds
    (P, T, and the sign-invariant Sx2, Sy2). Measured (8 seeds, minimise): one run P 4%
    (max 9%), T 4% (max 10%), Sx2/Sy2 20% (max 59%); mean of 8 seeds P 1.5%, T 2.3%, Sx2/Sy2
    9%. A control mould with one tether moved 1.5 l0 off the axis: P 12%, T 69%, Sx2 36%,
    Sy2 57% (mean of 4 seeds)."""
    tethers = np.array([[3.0, 2.0, 0.8], [9.0, 2.0, 0.8], [6.0, 6.0, 0.8]])
    fields = _trapezoid_fields(tethers, range(8))
    single = np.array([_mirror_asymmetry(f) for f in fields])
    mean = _mirror_asymmetry(fields.mean(axis=0))
    print("single-run P, T:", single[:, :2].round(3).tolist(), "mean of 8:", mean[:4].round(3))
    p, t, sx2, sy2 = range(4)
    assert single[:, [p, t]].max() < 0.15
    assert mean[p] < 0.04 and mean[t] < 0.05
    assert mean[sx2] < 0.15 and mean[sy2] < 0.15
    # the tolerance can fail: the same mould with its top tether moved off the axis
    moved = tethers.copy()
    moved[2, 0] = 7.5
    control = _mirror_asymmetry(_trapezoid_fields(moved, range(4)).mean(axis=0))
    assert control[p] > 0.06 and control[t] > 0.2 and min(control[sx2], control[sy2]) > 0.2


def test_simulate_lattice_checks_the_start_state():
    lat = build_lattice(SQUARE, TWO_POSTS, 2.0)
    ori = np.tile([0.0, 0.6, 0.8], (lat.n_cells, 1))
    with pytest.raises(ValueError, match="shapes"):
        simulate_lattice(lat, lat.positions[:-1], ori[:-1], "minimise")
    bad = ori.copy()
    bad[3, 1] = np.inf
    with pytest.raises(ValueError, match="inf"):
        simulate_lattice(lat, lat.positions, bad, "minimise")
    same = lat.positions.copy()
    same[lat.bond_i[0]] = same[lat.bond_j[0]]
    with pytest.raises(ValueError, match="same point"):
        simulate_lattice(lat, same, ori, "anneal", 1)
    with pytest.raises(ValueError, match="ftol"):
        simulate(SQUARE, TWO_POSTS, 2.0, "minimise", ftol=0.0)


def test_ftol_sets_the_final_force():
    loose = simulate(SQUARE, TWO_POSTS, 2.0, "minimise", seed=2, ftol=1e-3)
    tight = simulate(SQUARE, TWO_POSTS, 2.0, "minimise", seed=2, ftol=1e-6)
    assert loose.info["min_max_force"] < 1e-3 and tight.info["min_max_force"] < 1e-6
    assert loose.info["min_iterations"] < tight.info["min_iterations"]
    assert tight.energy <= loose.energy
    # both from the same start reach the same minimum to a small fraction of its energy
    assert loose.energy == pytest.approx(tight.energy, rel=1e-3)


def test_a_bond_collapsing_during_the_solve_is_flagged_nonfinite(monkeypatch):
    import condor.model.simulate as sim

    def collapse(*args, **kwargs):
        raise ZeroDivisionError("division by zero")

    monkeypatch.setattr(sim, "_solve", collapse)
    r = simulate(SQUARE, TWO_POSTS, 2.0, "minimise", seed=0)
    assert r.status.startswith("nonfinite")


def test_every_result_reports_its_residual_force_and_cost():
    from condor.model.walls import residual_forces

    lat = build_lattice(SQUARE, TWO_POSTS, 2.0)
    for solver in SOLVERS:
        r = simulate(SQUARE, TWO_POSTS, 2.0, solver, budget=50 if solver == "anneal" else None,
                     seed=1)
        assert r.info["max_force"] == pytest.approx(
            residual_forces(lat, r.positions, r.orientations).max(), rel=1e-12)
        assert r.info["evaluations"] > 0
    default = simulate(SQUARE, TWO_POSTS, 2.0, seed=1)
    assert default.solver == DEFAULT_SOLVER
    assert default.info["max_force"] <= DEFAULT_FTOL[DEFAULT_SOLVER]
    # the relaxed anneal's cost: its trials' bonds, its relaxations and the final L-BFGS
    info = simulate(SQUARE, TWO_POSTS, 2.0, "relaxed_anneal", seed=1).info
    assert info["evaluations"] == pytest.approx(info["anneal_bonds_evaluated"] / lat.n_bonds
                                                + info["relax_evaluations"]
                                                + info["min_evaluations"])
    assert info["relax_evaluations"] > 0 and info["min_evaluations"] > 0
    quench = simulate(SQUARE, TWO_POSTS, 2.0, "lbfgs", seed=1)
    assert quench.info["evaluations"] == quench.info["min_evaluations"]


def test_anneal_cost_counts_the_bonds_its_trials_evaluated():
    """One evaluation-equivalent = n_bonds bond energies; a trial evaluates the bonds of its
    cell (none when the move leaves the region), so the count per evaluated trial is the
    mean bond count of the mobile cells, and the hybrid adds FIRE's evaluations."""
    lat = build_lattice(SQUARE, TWO_POSTS, 2.0)
    r = simulate(SQUARE, TWO_POSTS, 2.0, "anneal", budget=200, seed=2)
    info = r.info
    degree = np.diff(lat.cell_ptr)[~lat.fixed]
    evaluated_trials = info["anneal_trials"] - info["anneal_rejected_outside"]
    per_trial = info["anneal_bonds_evaluated"] / evaluated_trials
    assert per_trial == pytest.approx(degree.mean(), rel=0.03)
    assert info["evaluations"] == pytest.approx(info["anneal_bonds_evaluated"] / lat.n_bonds)
    h = simulate(SQUARE, TWO_POSTS, 2.0, "hybrid", seed=2)
    assert h.info["evaluations"] == pytest.approx(h.info["anneal_evaluations"]
                                                  + h.info["min_iterations"])
