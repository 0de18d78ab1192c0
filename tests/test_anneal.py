"""Tests of the Metropolis annealing kernel."""

import numpy as np
import pytest
from shapely.geometry import box

from condor.anneal import (
    INIT_AMP_ORI, INIT_AMP_POS, MAX_STEP_ORI, T_INIT, TARGET_ACCEPT, anneal, anneal_kernel,
    neighbour_lists, trial_energy_change,
)
from condor.energy import DELTA, bond_energies, random_orientations, total_energy
from condor.lattice import build_lattice


@pytest.fixture(scope="module")
def mould():
    lat = build_lattice(box(0, 0, 6, 5), np.array([[1.5, 2.5, 0.8], [4.5, 2.5, 0.8]]), 2.0)
    ori = random_orientations(lat.n_cells, np.random.default_rng([0, 3]))
    return lat, ori


def test_incremental_energy_change_equals_full_difference(mould):
    lat, ori = mould
    rng = np.random.default_rng([0, 4])
    pos = lat.positions + rng.normal(scale=0.05, size=lat.positions.shape)
    args = (lat.bond_i, lat.bond_j, lat.bond_kbar, lat.bond_rest, DELTA)
    bond_e = bond_energies(pos, ori, *args)
    other, rest, kbar, twin = neighbour_lists(lat)
    slot_e = bond_e[lat.cell_bonds]
    assert np.array_equal(slot_e, slot_e[twin]) and np.all(twin != np.arange(len(twin)))
    scratch = np.empty(64)
    e0 = total_energy(pos, ori, *args)
    for cell in rng.choice(lat.n_cells, size=20, replace=False):
        new_r = pos[cell] + rng.uniform(-0.2, 0.2, 3)
        new_s = ori[cell] + rng.uniform(-0.5, 0.5, 3)
        new_s /= np.linalg.norm(new_s)
        de = trial_energy_change(pos, ori, cell, new_r, new_s, lat.cell_ptr, other, rest, kbar,
                                 DELTA, slot_e, scratch)
        p2, o2 = pos.copy(), ori.copy()
        p2[cell], o2[cell] = new_r, new_s
        assert de == pytest.approx(total_energy(p2, o2, *args) - e0, rel=1e-9, abs=1e-12)


def test_running_energy_matches_final_state_and_is_deterministic(mould):
    lat, ori = mould
    p1, o1, info1 = anneal(lat, lat.positions, ori, 200, [5, 0])
    p2, o2, info2 = anneal(lat, lat.positions, ori, 200, [5, 0])
    p3, _, _ = anneal(lat, lat.positions, ori, 200, [6, 0])
    e = total_energy(p1, o1, lat.bond_i, lat.bond_j, lat.bond_kbar, lat.bond_rest, DELTA)
    assert info1["anneal_running_energy"] == pytest.approx(e, rel=1e-9)
    assert np.array_equal(p1, p2) and np.array_equal(o1, o2)
    assert not np.array_equal(p1, p3)
    assert np.array_equal(p1[lat.fixed], lat.positions[lat.fixed])  # posts never move
    assert np.array_equal(o1[lat.fixed], ori[lat.fixed])
    assert np.allclose(np.linalg.norm(o1, axis=1), 1.0)


def test_cells_never_leave_the_region(mould):
    lat, ori = mould
    pos, _, info = anneal(lat, lat.positions, ori, 300, [1, 0])
    assert info["anneal_rejected_outside"] > 0  # the walls were tried
    assert lat.region.violation(pos[~lat.fixed]).max() == 0.0


def test_longer_schedule_reaches_lower_energy(mould):
    lat, ori = mould
    args = (lat.bond_i, lat.bond_j, lat.bond_kbar, lat.bond_rest, DELTA)
    energies = []
    for budget in (3, 30, 3000):
        pos, o, _ = anneal(lat, lat.positions, ori, budget, [2, 0])
        energies.append(total_energy(pos, o, *args))
    assert energies[0] > energies[1] > energies[2]
    assert energies[0] < total_energy(lat.positions, ori, *args)


def test_metropolis_samples_boltzmann_at_fixed_temperature():
    """One free cell bonded to two posts along x at T fixed (ratio 1): <dx^2> = T / k_eff."""
    lat = build_lattice(box(0, 0, 4.0, 0.5), np.array([[0.0, 0.0, 0.6], [2.83, 0.0, 0.6]]), 0.1)
    assert np.count_nonzero(~lat.fixed) == 1
    ori = np.tile([0.0, 0.0, 1.0], (lat.n_cells, 1))
    # Harmonic check: sample positions with a tiny temperature so the well is quadratic.
    samples = []
    for s in range(40):
        pos, _, _ = anneal(lat, lat.positions, ori, 2000, [s, 9], t_init=1e-4, t_ratio=1.0)
        samples.append(pos[~lat.fixed][0])
    samples = np.array(samples)
    assert np.all(np.isfinite(samples))
    # finite-difference Hessian of the energy in x at the minimum of this symmetric chain
    cell = int(np.flatnonzero(~lat.fixed)[0])
    args = (lat.bond_i, lat.bond_j, lat.bond_kbar, lat.bond_rest, DELTA)
    def e(dx):
        p = lat.positions.copy()
        p[cell, 0] += dx
        return total_energy(p, ori, *args)
    h = 1e-4
    k_xx = (e(h) - 2 * e(0) + e(-h)) / h**2
    var = np.var(samples[:, 0] - lat.positions[cell, 0])
    assert var == pytest.approx(1e-4 / k_xx, rel=0.5)  # 40 samples: ~22% standard error


def _kernel_run(lat, pos, ori, sweeps, temp, amp, seed):
    """Run anneal_kernel in place for `sweeps` sweeps at fixed temperature `temp`."""
    mobile = np.flatnonzero(~lat.fixed).astype(np.int64)
    r = lat.region
    _, _, acc_ori, _, _ = anneal_kernel(
        pos, ori, mobile, lat.bond_i, lat.bond_j, lat.bond_kbar, lat.bond_rest, lat.cell_ptr,
        lat.cell_bonds, *neighbour_lists(lat), DELTA, r.phi, r.phi_x0, r.phi_y0, r.phi_h,
        r.posts, r.depth, sweeps * len(mobile), temp, 1.0, seed, amp)
    return acc_ori / (sweeps * len(mobile) / 2)


def test_step_amplitude_does_not_wind_up_at_its_cap():
    """Hot: the orientation acceptance exceeds the target even at the step cap ds = 1, so the
    amplitude rises; it must stop at the cap (1 / sqrt(T)), or it needs as many cold sweeps to
    come back down, during which ds = 1 is almost always rejected."""
    lat = build_lattice(box(0, 0, 4, 3), np.array([[1.0, 1.5, 0.6]]), 1.5)
    pos = lat.positions.copy()
    ori = random_orientations(lat.n_cells, np.random.default_rng([0, 3]))
    amp = np.array([INIT_AMP_POS, INIT_AMP_ORI])
    hot, cold = T_INIT, T_INIT * 1e-3
    assert _kernel_run(lat, pos, ori, 200, hot, amp, 11) > TARGET_ACCEPT  # the cap binds
    assert amp[1] * np.sqrt(hot) <= MAX_STEP_ORI * (1 + 1e-12)
    # Cold: the step must shrink to the acceptance target within a few sweeps.
    _kernel_run(lat, pos, ori, 20, cold, amp, 12)
    assert amp[1] * np.sqrt(cold) < 0.5 * MAX_STEP_ORI
    assert _kernel_run(lat, pos, ori, 50, cold, amp, 13) == pytest.approx(TARGET_ACCEPT, abs=0.1)


def test_long_anneal_keeps_adapting_its_orientation_step():
    """Regression: beyond ~4e4 moves per cell the wound-up amplitude overflowed to inf, which
    froze ds at its cap and the orientation acceptance at ~0 for the rest of the anneal."""
    lat = build_lattice(box(0, 0, 4, 3), np.array([[1.0, 1.5, 0.6]]), 1.5)
    ori = random_orientations(lat.n_cells, np.random.default_rng([0, 3]))
    _, _, info = anneal(lat, lat.positions, ori, 6e4, [1, 0])
    # The target is met in every sweep but the hot start (acceptance > 40% at the cap).
    assert info["anneal_accept_ori"] == pytest.approx(TARGET_ACCEPT, abs=0.06)
    assert info["anneal_final_step_ori"] < 0.01 * MAX_STEP_ORI
