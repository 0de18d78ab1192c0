"""Tests of the Metropolis annealing kernel (condor.model.metropolis) and its driver
(condor.model.anneal)."""

import json

import numpy as np
import pytest
from shapely.geometry import box

import dataclasses

from condor.model.anneal import (
    INIT_AMP_ORI, INIT_AMP_POS, KERNEL, MOVES_PER_SWEEP, T_INIT, AnnealRun, anneal,
)
from condor.model.metropolis import (
    MAX_STEP_ORI, TARGET_ACCEPT, Layout, gather_neighbours, orientation_change, pack_state,
    position_change, trial_energy_change,
)
from condor.model.energy import DELTA, random_orientations, total_energy
from condor.model.lattice import build_lattice


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
    lay = Layout.of(lat)
    state = pack_state(pos, ori)
    slots = (lay.cell_ptr, lay.other, lay.rest_a, lay.rest_b, lay.half_kbar)
    buf = np.empty((8, lay.max_degree))
    e0 = total_energy(pos, ori, *args)  # energy.py's own formula, bond by bond
    for cell in rng.choice(lat.n_cells, size=20, replace=False):
        new_r = pos[cell] + rng.uniform(-0.2, 0.2, 3)
        new_s = ori[cell] + rng.uniform(-0.5, 0.5, 3)
        new_s /= np.linalg.norm(new_s)
        de = trial_energy_change(state, cell, *new_r, *new_s, *slots, buf)
        p2, o2 = pos.copy(), ori.copy()
        p2[cell], o2[cell] = new_r, new_s
        assert de == pytest.approx(total_energy(p2, o2, *args) - e0, rel=1e-9, abs=1e-12)
        # each move of a visit alone
        n = gather_neighbours(state, cell, lay.cell_ptr, lay.other, buf)
        own = slice(lay.cell_ptr[cell], lay.cell_ptr[cell + 1])
        parts = (lay.rest_a[own], lay.rest_b[own], lay.half_kbar[own])
        moved = position_change(buf, n, *parts, *pos[cell], *new_r, *ori[cell])
        p3 = pos.copy()
        p3[cell] = new_r
        assert moved == pytest.approx(total_energy(p3, ori, *args) - e0, rel=1e-9, abs=1e-12)
        turned = orientation_change(buf, n, *parts, *pos[cell], *ori[cell], *new_s)
        o3 = ori.copy()
        o3[cell] = new_s
        assert turned == pytest.approx(total_energy(pos, o3, *args) - e0, rel=1e-9, abs=1e-12)


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
    """Run `sweeps` sweeps at fixed temperature `temp` from (pos, ori) with amplitudes amp,
    all updated in place; returns the orientation moves' acceptance."""
    run = AnnealRun(lat, pos, ori, sweeps * MOVES_PER_SWEEP, [seed], t_init=temp, t_ratio=1.0)
    run.amp[:] = amp
    run.advance()
    pos[...], ori[...], amp[...] = run.pos, run.ori, run.amp
    return run.info()["anneal_accept_ori"]


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


# --- resumable anneals ---------------------------------------------------------------------

def test_anneal_resumed_from_checkpoints_is_bit_identical(mould, tmp_path):
    """Cut into segments, saved and loaded by fresh runs (as a killed process resumes), and
    through anneal(checkpoint=...): the same bits as one uninterrupted anneal."""
    lat, ori = mould
    ref_pos, ref_ori, ref_info = anneal(lat, lat.positions, ori, 400, [5, 0])
    ck = tmp_path / "run.npz"
    for stop in (1, 37, 150):
        run = AnnealRun(lat, lat.positions, ori, 400, [5, 0])
        if ck.exists():
            run.load(ck)
        run.advance(stop - run.sweep)
        run.save(ck)
    pos, o, info = anneal(lat, lat.positions, ori, 400, [5, 0], checkpoint=ck,
                          checkpoint_seconds=0.0)
    assert np.array_equal(pos, ref_pos) and np.array_equal(o, ref_ori)
    same = {k: v for k, v in info.items() if not k.endswith("seconds")}
    assert same == {k: v for k, v in ref_info.items() if not k.endswith("seconds")}
    assert info["anneal_resumed_seconds"] > 0.0
    # a finished checkpoint returns at once, with the same result
    again = anneal(lat, lat.positions, ori, 400, [5, 0], checkpoint=ck)
    assert np.array_equal(again[0], ref_pos)


def test_threads_give_the_same_bits_and_strips_never_bond_across_a_colour(tmp_path):
    """The strips of one colour share no bond, so they run in parallel; the result is the
    same bits on one thread or two, and resumes across thread counts."""
    lat = build_lattice(box(0, 0, 14, 5), np.array([[2.0, 2.5, 0.8], [12.0, 2.5, 0.8]]), 2.0)
    ori = random_orientations(lat.n_cells, np.random.default_rng([0, 3]))
    lay = Layout.of(lat)
    assert lay.n_strips >= 5
    strip = np.full(lat.n_cells, -1)
    for s in range(lay.n_strips):
        strip[lay.strip_cells[lay.strip_ptr[s]:lay.strip_ptr[s + 1]]] = s
    mobile = ~lat.fixed
    assert np.array_equal(np.sort(np.flatnonzero(strip >= 0)), np.flatnonzero(mobile))
    both = mobile[lat.bond_i] & mobile[lat.bond_j]
    si, sj = strip[lat.bond_i[both]], strip[lat.bond_j[both]]
    assert np.all((si == sj) | (si % 2 != sj % 2))  # never two strips of one colour
    with pytest.raises(ValueError, match="wider than any bond"):
        Layout.of(lat, strip_width=1.0)
    one = anneal(lat, lat.positions, ori, 100, [5, 0], threads=1)
    two = anneal(lat, lat.positions, ori, 100, [5, 0], threads=2)
    assert np.array_equal(one[0], two[0]) and np.array_equal(one[1], two[1])
    run = AnnealRun(lat, lat.positions, ori, 100, [5, 0], threads=2)
    run.advance(20)
    run.save(tmp_path / "ck.npz")
    back = AnnealRun(lat, lat.positions, ori, 100, [5, 0], threads=1)
    back.load(tmp_path / "ck.npz")
    back.advance()
    assert np.array_equal(back.pos, one[0])


def test_checkpoint_of_another_run_or_corrupt_is_refused(mould, tmp_path):
    lat, ori = mould
    ck = tmp_path / "run.npz"
    run = AnnealRun(lat, lat.positions, ori, 50, [5, 0])
    run.advance(10)
    run.save(ck)
    with pytest.raises(ValueError, match="its seed is"):
        AnnealRun(lat, lat.positions, ori, 50, [6, 0]).load(ck)
    with pytest.raises(ValueError, match="its n_sweeps is"):
        anneal(lat, lat.positions, ori, 60, [5, 0], checkpoint=ck)
    other_kernel = tmp_path / "old.npz"
    with np.load(ck) as data:
        saved = dict(data)
    saved["key"] = np.array(json.dumps({**json.loads(str(saved["key"])),
                                        "kernel": "ball-2026-12"}))
    np.savez(other_kernel, **saved)
    with pytest.raises(ValueError, match=f"kernel 'ball-2026-12', not this one.*{KERNEL}"):
        anneal(lat, lat.positions, ori, 50, [5, 0], checkpoint=other_kernel)
    ck.write_bytes(ck.read_bytes()[:200])  # truncated by a crash of the disk
    with pytest.raises(ValueError, match="not a readable anneal checkpoint.*delete it"):
        anneal(lat, lat.positions, ori, 50, [5, 0], checkpoint=ck)


# --- the sampler samples Boltzmann (fixed T, fixed steps) ----------------------------------

def _one_free_cell():
    """A lattice whose only mobile cell is the most central one, with no wall in reach."""
    lat0 = build_lattice(box(0, 0, 5, 4), np.zeros((0, 3)), 3.0)
    cell = int(np.argmin(np.linalg.norm(lat0.positions - lat0.positions.mean(0), axis=1)))
    fixed = np.ones(lat0.n_cells, bool)
    fixed[cell] = False
    ori = random_orientations(lat0.n_cells, np.random.default_rng(1))
    return dataclasses.replace(lat0, fixed=fixed), cell, ori


def _cell_energy(lat, ori, cell, r, s):
    """The free cell's bond energies at positions r and orientations s (..., 3; either may be
    one (3,) vector): the model's formula written again in numpy, independent of the kernels."""
    b = lat.cell_bonds[lat.cell_ptr[cell]:lat.cell_ptr[cell + 1]]
    other = np.where(lat.bond_i[b] == cell, lat.bond_j[b], lat.bond_i[b])
    l = lat.positions[other] - r[..., None, :]
    d = np.linalg.norm(l, axis=-1)
    lhat = l / d[..., None]
    ci = np.einsum("...bk,...k->...b", lhat, s)
    cj = np.einsum("...bk,bk->...b", lhat, ori[other])
    rest = lat.bond_rest[b] * (1 - DELTA / 2 * (2 - ci**2 - cj**2))
    return 0.5 * np.sum(lat.bond_kbar[b] * (d - rest) ** 2, axis=-1)


def _fixed_t_samples(lat, ori, temp, steps, n_samples, thin, seed, start=None):
    """States of a Metropolis chain at `temp` with fixed steps (dr, ds), every `thin` sweeps."""
    pos = lat.positions if start is None else start
    run = AnnealRun(lat, pos, ori, 1e9, [seed], t_init=temp, t_ratio=1.0, adapt=False)
    run.amp[:] = np.asarray(steps) / np.sqrt(temp)
    out_pos, out_ori = [], []
    for _ in range(n_samples):
        run.advance(thin)
        out_pos.append(run.pos[~lat.fixed].copy())
        out_ori.append(run.ori[~lat.fixed].copy())
    return np.array(out_pos), np.array(out_ori)


def _batch_se(values, batches=50):
    """Standard error of the mean of correlated samples (n, ...) by batch means."""
    b = values[: len(values) // batches * batches].reshape((batches, -1) + values.shape[1:])
    return b.mean(axis=1).std(axis=0, ddof=1) / np.sqrt(batches)


def test_orientation_moves_sample_boltzmann_against_quadrature():
    """One cell, positions frozen: its orientation's second moments <s s^T> under
    exp(-E(s)/T) by quadrature over the sphere, against the chain at a large step (ds 0.8,
    where the former cube proposal missed <sx^2> by 8 standard errors)."""
    lat, cell, ori = _one_free_cell()
    temp = 0.003
    n = 400  # quadrature: midpoints in cos(theta) and phi
    cos_t = (np.arange(n) + 0.5) / n * 2 - 1
    phi = (np.arange(2 * n) + 0.5) / (2 * n) * 2 * np.pi
    c, p = np.meshgrid(cos_t, phi, indexing="ij")
    sin_t = np.sqrt(1 - c**2)
    s = np.stack([sin_t * np.cos(p), sin_t * np.sin(p), c], axis=-1)
    e = np.array([_cell_energy(lat, ori, cell, lat.positions[cell], row) for row in s])
    w = np.exp(-(e - e.min()) / temp)
    expected = np.einsum("ij,ija,ijb->ab", w / w.sum(), s, s)
    assert expected[0, 0] - expected[2, 2] > 0.3  # far from isotropic: a real test
    _, samples = _fixed_t_samples(lat, ori, temp, (0.0, 0.8), 100_000, 10, 3)
    ss = samples[:, 0, :, None] * samples[:, 0, None, :]
    got, se = ss.mean(axis=0), _batch_se(ss)
    assert np.all(np.abs(got - expected) < 4 * se + 1e-4), (got, expected, se)


def test_position_moves_sample_boltzmann_against_quadrature():
    """One cell, orientations frozen: the mean and covariance of its position under
    exp(-E(r)/T) by quadrature on a 3D grid, against the chain."""
    lat, cell, ori = _one_free_cell()
    temp = 0.003
    r0 = lat.positions[cell]
    g = np.linspace(-0.17, 0.17, 69)
    grid = r0 + np.stack(np.meshgrid(g, g, g, indexing="ij"), axis=-1)
    e = np.array([_cell_energy(lat, ori, cell, plane, ori[cell]) for plane in grid])
    w = np.exp(-(e - e.min()) / temp)
    w /= w.sum()
    mean = np.einsum("ijk,ijka->a", w, grid)
    d = grid - mean
    cov = np.einsum("ijk,ijka,ijkb->ab", w, d, d)
    assert w[0].sum() + w[-1].sum() < 1e-8  # the grid holds the whole distribution
    samples, _ = _fixed_t_samples(lat, ori, temp, (0.03, 0.0), 100_000, 10, 4)
    x = samples[:, 0]
    assert np.all(np.abs(x.mean(axis=0) - mean) < 4 * _batch_se(x) + 1e-5)
    dx = (x - mean)[:, :, None] * (x - mean)[:, None, :]
    assert np.all(np.abs(dx.mean(axis=0) - cov) < 4 * _batch_se(dx) + 2e-6 * cov.trace())


def test_equipartition_of_the_harmonic_network():
    """Cells deep inside a network with its rim held (no wall in reach): near the minimum
    the energy is harmonic in 5 degrees of freedom a cell (3 position, 2 orientation), so
    <E>(T2) - <E>(T1) = 5 N (T2 - T1) / 2."""
    lat0 = build_lattice(box(0, 0, 6, 5), np.zeros((0, 3)), 3.0)
    p = lat0.positions
    inner = ((p[:, 0] > 1.2) & (p[:, 0] < 4.8) & (p[:, 1] > 1.2) & (p[:, 1] < 3.8)
             & (p[:, 2] > 0.9) & (p[:, 2] < 2.1))
    lat = dataclasses.replace(lat0, fixed=~inner)
    ori = random_orientations(lat.n_cells, np.random.default_rng(1))
    pos, ori, _ = anneal(lat, lat.positions, ori, 3000, [0])  # to a minimum
    n = int(inner.sum())
    means = {}
    for temp in (1e-6, 3e-6):
        run = AnnealRun(lat, pos, ori, 1e12, [1], t_init=temp, t_ratio=1.0)
        run.advance(1000)  # adapt the steps, then fix them
        run.adapt = False
        energies = []
        for _ in range(4000):
            run.advance(3)
            energies.append(run.temp_energy[1])
        means[temp] = np.mean(energies)
    dof = 2 * (means[3e-6] - means[1e-6]) / 2e-6
    assert dof == pytest.approx(5 * n, rel=0.15)


def test_zero_energy_samples_uniform_orientations_and_positions():
    """With every spring removed, every move inside the region is accepted: the orientations
    must be isotropic (<s s^T> = I / 3) and the heights uniform on [0, depth]."""
    lat0 = build_lattice(box(0, 0, 4, 3), np.zeros((0, 3)), 2.0)
    lat = dataclasses.replace(lat0, bond_kbar=np.zeros_like(lat0.bond_kbar))
    ori = np.tile([0.0, 0.0, 1.0], (lat.n_cells, 1))  # far from isotropic at the start
    pos, o = _fixed_t_samples(lat, ori, 1e-3, (0.3, 1.0), 400, 10, 5)
    pos, o = pos[100:].reshape(-1, 3), o[100:].reshape(-1, 3)
    assert np.allclose(o.T @ o / len(o), np.eye(3) / 3, atol=0.01)
    z = pos[:, 2]
    assert np.all((z >= 0) & (z <= 2.0))
    assert z.mean() == pytest.approx(1.0, abs=0.02)
    assert z.var() == pytest.approx(2.0**2 / 12, rel=0.05)


# --- the relaxed anneal: Metropolis with the positions relaxed between segments ---------------

def test_set_state_keeps_the_running_energy_exact(mould):
    lat, ori = mould
    run = AnnealRun(lat, lat.positions, ori, 20, [3, 0])
    run.advance(run.n_sweeps // 2)
    moved = run.pos + 0.01 * np.random.default_rng(0).standard_normal(run.pos.shape)
    moved[lat.fixed] = lat.positions[lat.fixed]
    run.set_state(moved, run.ori.copy())
    run.advance()
    args = (lat.bond_i, lat.bond_j, lat.bond_kbar, lat.bond_rest, DELTA)
    assert run.temp_energy[1] == pytest.approx(total_energy(run.pos, run.ori, *args), rel=1e-9)


def test_positions_only_relaxation_turns_no_cell_and_lowers_the_energy(mould):
    from condor.model.lbfgs import minimise_lbfgs
    lat, ori = mould
    args = (lat.bond_i, lat.bond_j, lat.bond_kbar, lat.bond_rest, DELTA)
    pos, o, info = minimise_lbfgs(lat, lat.positions, ori, 50, 0.0, positions_only=True)
    assert np.abs(o - ori).max() < 1e-12  # renormalised, never turned
    assert info["min_evaluations"] == 50  # orientation torques remain: it runs to its budget
    assert total_energy(pos, o, *args) < 0.5 * total_energy(lat.positions, ori, *args)
    assert lat.region.violation(pos[~lat.fixed]).max() == 0.0


def test_relaxed_anneal_is_deterministic_and_counts_its_relaxations(mould):
    from condor.model.anneal import relaxed_anneal
    lat, ori = mould
    a = relaxed_anneal(lat, lat.positions, ori, [4, 2], 0.03, 0.001, 5, 4, 10)
    b = relaxed_anneal(lat, lat.positions, ori, [4, 2], 0.03, 0.001, 5, 4, 10)
    assert np.array_equal(a[0], b[0]) and np.array_equal(a[1], b[1])
    assert a[2]["relax_evaluations"] == 50
    assert a[2]["anneal_trials"] == 20 * int((~lat.fixed).sum())
    assert np.allclose(np.linalg.norm(a[1], axis=1), 1.0)
    assert lat.region.violation(a[0][~lat.fixed]).max() == 0.0
    args = (lat.bond_i, lat.bond_j, lat.bond_kbar, lat.bond_rest, DELTA)
    assert a[2]["anneal_running_energy"] == pytest.approx(total_energy(a[0], a[1], *args),
                                                          rel=1e-9)


def test_relaxed_anneal_takes_a_relaxation_budget_a_segment(mould):
    from condor.model.anneal import relaxed_anneal
    lat, ori = mould
    same = relaxed_anneal(lat, lat.positions, ori, [4, 2], 0.03, 0.001, 5, 4, [10] * 5)
    scalar = relaxed_anneal(lat, lat.positions, ori, [4, 2], 0.03, 0.001, 5, 4, 10)
    assert np.array_equal(same[0], scalar[0]) and np.array_equal(same[1], scalar[1])
    front = relaxed_anneal(lat, lat.positions, ori, [4, 2], 0.03, 0.001, 5, 4, [30, 5, 5, 5, 0])
    assert front[2]["relax_evaluations"] == 45  # ftol 0: every relaxation spends its budget
    assert not np.array_equal(front[0], scalar[0])
    with pytest.raises(ValueError, match="one a segment"):
        relaxed_anneal(lat, lat.positions, ori, [4, 2], 0.03, 0.001, 5, 4, [30, 5])
