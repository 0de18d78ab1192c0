"""Tests of the CONDOR energy, gradient and tension against independent numpy computations."""

import numpy as np
import pytest
from shapely.geometry import box

from condor.model.energy import (DELTA, bond_energies, cell_tension, energy_gradient, project_tangent,
                           random_orientations, total_energy)
from condor.model.lattice import build_lattice


def brute_force_energy(pos, ori, lat, delta=DELTA):
    """Direct transcription of the paper's formula over all pairs within the 4th shell."""
    e = 0.0
    n = len(pos)
    for i in range(n):
        for j in range(i + 1, n):
            d0 = np.linalg.norm(lat.positions[j] - lat.positions[i])
            if d0 > 2.0 + 1e-9:
                continue
            kbar = {1: 1.0, 2: 0.4, 3: 0.2, 4: 0.2}[int(round(d0**2))]
            l = pos[j] - pos[i]
            lhat = l / np.linalg.norm(l)
            rest = d0 * (1 - delta / 2 * (2 - abs(lhat @ ori[i]) ** 2 - abs(lhat @ ori[j]) ** 2))
            e += kbar / 2 * (np.linalg.norm(l) - rest) ** 2
    return e


@pytest.fixture(scope="module")
def perturbed():
    lat = build_lattice(box(0, 0, 4, 3.5), np.array([[1.0, 1.0, 0.5]]), 2.0)
    rng = np.random.default_rng([0, 7])
    pos = lat.positions + rng.normal(scale=0.1, size=lat.positions.shape)
    ori = random_orientations(lat.n_cells, rng)
    return lat, pos, ori


def args(lat):
    return lat.bond_i, lat.bond_j, lat.bond_kbar, lat.bond_rest


def test_energy_equals_brute_force(perturbed):
    lat, pos, ori = perturbed
    e = total_energy(pos, ori, *args(lat), DELTA)
    ref = brute_force_energy(pos, ori, lat)
    assert e > 0
    assert abs(e - ref) <= 1e-9 * abs(ref)
    assert np.isclose(bond_energies(pos, ori, *args(lat), DELTA).sum(), e, rtol=1e-12)


def test_gradient_equals_finite_differences(perturbed):
    lat, pos, ori = perturbed
    gp, go = np.zeros_like(pos), np.zeros_like(ori)
    e = energy_gradient(pos, ori, *args(lat), DELTA, gp, go)
    assert np.isclose(e, total_energy(pos, ori, *args(lat), DELTA), rtol=1e-13)
    h = 1e-6
    rng = np.random.default_rng([0, 8])
    for cell in rng.choice(lat.n_cells, size=6, replace=False):
        for a in range(3):
            for arr, grad in ((pos, gp), (ori, go)):  # raw dE/ds: s treated as a free 3-vector
                plus, minus = arr.copy(), arr.copy()
                plus[cell, a] += h
                minus[cell, a] -= h
                pp = (plus, ori) if arr is pos else (pos, plus)
                mm = (minus, ori) if arr is pos else (pos, minus)
                fd = (total_energy(*pp, *args(lat), DELTA) - total_energy(*mm, *args(lat), DELTA)) / (2 * h)
                assert abs(fd - grad[cell, a]) < 1e-6 * max(1.0, abs(fd))


def plain_gradient(pos, ori, lat, delta=DELTA):
    """energy_gradient as one numpy pass over the bonds: the same per-bond expressions, then
    every bond's j end added and every i end subtracted, cell by cell in bond order."""
    i, j, kbar, l0 = lat.bond_i, lat.bond_j, lat.bond_kbar, lat.bond_rest
    l = pos[j] - pos[i]
    d = np.sqrt(l[:, 0] * l[:, 0] + l[:, 1] * l[:, 1] + l[:, 2] * l[:, 2])
    inv = 1.0 / d
    ci = (l[:, 0] * ori[i, 0] + l[:, 1] * ori[i, 1] + l[:, 2] * ori[i, 2]) * inv
    cj = (l[:, 0] * ori[j, 0] + l[:, 1] * ori[j, 1] + l[:, 2] * ori[j, 2]) * inv
    stretch = d - l0 * (1.0 - 0.5 * delta * (2.0 - ci * ci - cj * cj))
    g = kbar * stretch
    a = l0 * delta * inv
    coef_u, coef_i, coef_j = g * (1.0 + a * (ci * ci + cj * cj)), -g * a * ci, -g * a * cj
    u = l * inv[:, None]
    f = coef_u[:, None] * u + coef_i[:, None] * ori[i] + coef_j[:, None] * ori[j]
    gp, go = np.zeros_like(pos), np.zeros_like(ori)
    np.add.at(gp, j, f)
    np.subtract.at(gp, i, f)
    np.add.at(go, j, (-g * l0 * delta * cj)[:, None] * u)
    np.add.at(go, i, (-g * l0 * delta * ci)[:, None] * u)
    e = 0.0
    for eb in 0.5 * kbar * stretch * stretch:
        e += eb
    return e, gp, go


def test_blocked_gradient_is_the_plain_loop_to_the_bit():
    # several blocks of energy_gradient and a partial last one; the lattice's bond order
    lat = build_lattice(box(0, 0, 9, 7), np.array([[3.0, 3.0, 0.5]]), 3.0)
    assert lat.n_bonds > 10 * 128 and lat.n_bonds % 128
    assert np.all(np.diff(lat.bond_i) >= 0) and np.all(lat.bond_j > lat.bond_i)
    rng = np.random.default_rng([0, 9])
    pos = lat.positions + rng.normal(scale=0.1, size=lat.positions.shape)
    ori = random_orientations(lat.n_cells, rng)
    gp, go = np.zeros_like(pos), np.zeros_like(ori)
    e = energy_gradient(pos, ori, *args(lat), DELTA, gp, go)
    e_ref, gp_ref, go_ref = plain_gradient(pos, ori, lat)
    assert e == e_ref and np.array_equal(gp, gp_ref) and np.array_equal(go, go_ref)
    # bonds in any other order: the same sums up to round-off
    order = rng.permutation(lat.n_bonds)
    gp2, go2 = np.zeros_like(pos), np.zeros_like(ori)
    e2 = energy_gradient(pos, ori, lat.bond_i[order], lat.bond_j[order], lat.bond_kbar[order],
                         lat.bond_rest[order], DELTA, gp2, go2)
    assert e2 == pytest.approx(e, rel=1e-12)
    assert np.allclose(gp2, gp, rtol=0, atol=1e-12) and np.allclose(go2, go, rtol=0, atol=1e-12)


def test_tangent_gradient_is_derivative_along_the_sphere(perturbed):
    lat, pos, ori = perturbed
    gp, go = np.zeros_like(pos), np.zeros_like(ori)
    energy_gradient(pos, ori, *args(lat), DELTA, gp, go)
    project_tangent(ori, go)
    assert np.allclose(np.einsum("ij,ij->i", go, ori), 0, atol=1e-12)
    cell, h = 3, 1e-6
    axis = np.cross(ori[cell], [0.3, -0.5, 0.8])
    axis /= np.linalg.norm(axis)  # rotate s about an axis perpendicular to it: s(t) = cos t s + sin t axis
    def e_at(t):
        o = ori.copy()
        o[cell] = np.cos(t) * ori[cell] + np.sin(t) * axis
        return total_energy(pos, o, *args(lat), DELTA)
    fd = (e_at(h) - e_at(-h)) / (2 * h)
    assert abs(fd - go[cell] @ axis) < 1e-6


@pytest.mark.parametrize("d0, kbar", [(1.0, 1.0), (np.sqrt(2), 0.4), (2.0, 0.2)])
def test_single_bond_rest_length(d0, kbar):
    """Rest length d0 (1 - Delta/2 (2 - c_i^2 - c_j^2)): d0 for s parallel to the bond, d0 (1 - Delta)
    for both perpendicular, d0 (1 - Delta/2) for one of each."""
    bi, bj = np.array([0]), np.array([1])
    k, rest = np.array([kbar]), np.array([d0])
    along, across = np.array([1.0, 0, 0]), np.array([0, 0.6, 0.8])
    cases = [(along, along, d0), (across, across, d0 * (1 - DELTA)), (along, across, d0 * (1 - DELTA / 2))]
    for si, sj, expected_rest in cases:
        for d in (0.5, expected_rest, 1.7):
            pos = np.array([[0.0, 0, 0], [d, 0, 0]])
            e = total_energy(pos, np.array([si, sj]), bi, bj, k, rest, DELTA)
            assert np.isclose(e, kbar / 2 * (d - expected_rest) ** 2, rtol=1e-12, atol=1e-15)
        pos = np.array([[0.0, 0, 0], [expected_rest, 0, 0]])
        assert cell_tension(pos, np.array([si, sj]), bi, bj, k, rest, DELTA)[0] == pytest.approx(0, abs=1e-14)


def test_delta_zero_lattice_is_at_zero_energy_and_force():
    lat = build_lattice(box(0, 0, 5, 5), np.array([[2.5, 2.5, 0.8]]), 3.0)
    ori = random_orientations(lat.n_cells, np.random.default_rng([1, 1]))
    gp, go = np.zeros_like(lat.positions), np.zeros_like(ori)
    e = energy_gradient(lat.positions, ori, *args(lat), 0.0, gp, go)
    assert e == pytest.approx(0, abs=1e-24)
    assert np.abs(gp).max() < 1e-12 and np.abs(go).max() < 1e-12
    # with Delta > 0 the same lattice is under tension: cells want shorter bonds
    tau = cell_tension(lat.positions, ori, *args(lat), DELTA)
    assert np.all(tau > 0)


def test_energy_invariant_under_rigid_rotation(perturbed):
    lat, pos, ori = perturbed
    rng = np.random.default_rng([2, 2])
    q, _ = np.linalg.qr(rng.normal(size=(3, 3)))
    e0 = total_energy(pos, ori, *args(lat), DELTA)
    e1 = total_energy(pos @ q.T + [3.0, -1.0, 2.0], ori @ q.T, *args(lat), DELTA)
    assert np.isclose(e0, e1, rtol=1e-12)
    # flipping the sign of any orientation changes nothing (the energy is even in s)
    flipped = ori.copy()
    flipped[::2] *= -1
    assert np.isclose(total_energy(pos, flipped, *args(lat), DELTA), e0, rtol=1e-13)


def test_tension_is_mean_bond_tension_and_positive_when_stretched(perturbed):
    lat, pos, ori = perturbed
    tau = cell_tension(pos, ori, *args(lat), DELTA)
    for cell in (0, 5, lat.n_cells - 1):
        terms = []
        for b in np.flatnonzero((lat.bond_i == cell) | (lat.bond_j == cell)):
            i, j = lat.bond_i[b], lat.bond_j[b]
            l = pos[j] - pos[i]
            u = l / np.linalg.norm(l)
            rest = lat.bond_rest[b] * (1 - DELTA / 2 * (2 - (u @ ori[i]) ** 2 - (u @ ori[j]) ** 2))
            terms.append(lat.bond_kbar[b] * (np.linalg.norm(l) - rest))
        assert np.isclose(tau[cell], np.mean(terms), rtol=1e-12)
    stretched = cell_tension(lat.positions * 1.1, ori, *args(lat), 0.0)
    squeezed = cell_tension(lat.positions * 0.9, ori, *args(lat), 0.0)
    assert np.all(stretched > 0) and np.all(squeezed < 0)
