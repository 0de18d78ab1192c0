"""Tests of the FCC lattice, its bonds, posts and confinement geometry."""

import itertools

import numpy as np
import pytest
import shapely
from shapely.geometry import Point, Polygon, box

from condor.model.lattice import HALF, SHELL_KBAR, build_lattice, signed_volumes


def brute_force_pairs(positions, cutoff=2.0 + 1e-6):
    d = np.linalg.norm(positions[:, None] - positions[None], axis=2)
    i, j = np.nonzero(np.triu(d <= cutoff, k=1))
    return set(zip(i.tolist(), j.tolist())), d


def test_bonds_match_brute_force_pairs():
    lat = build_lattice(box(0, 0, 5, 4), np.zeros((0, 3)), 2.0)
    pairs, d = brute_force_pairs(lat.positions)
    bonds = set(zip(lat.bond_i.tolist(), lat.bond_j.tolist()))
    assert bonds == pairs  # each bond once (i < j), every pair within shell 4
    assert np.all(lat.bond_i < lat.bond_j)
    assert np.allclose(lat.bond_rest, d[lat.bond_i, lat.bond_j], atol=1e-12)
    shell_of_rest = np.rint(lat.bond_rest**2).astype(int) - 1
    assert np.array_equal(shell_of_rest, lat.bond_shell)
    assert np.allclose(lat.bond_kbar, np.asarray(SHELL_KBAR)[lat.bond_shell])


def test_bulk_site_has_fcc_shell_counts_and_nn_distance_one():
    lat = build_lattice(box(0, 0, 8, 8), np.zeros((0, 3)), 6.0)
    centre = np.array([4.0, 4.0, 3.0])
    c = int(np.argmin(np.linalg.norm(lat.positions - centre, axis=1)))
    d = np.linalg.norm(lat.positions - lat.positions[c], axis=1)
    assert np.isclose(np.sort(d)[1], 1.0)
    for shell, expected in enumerate((12, 6, 24, 12)):
        assert np.count_nonzero(np.isclose(d, np.sqrt(shell + 1))) == expected
        mine = (lat.bond_shell == shell) & ((lat.bond_i == c) | (lat.bond_j == c))
        assert np.count_nonzero(mine) == expected
    # CSR lists the same bonds
    csr = set(lat.cell_bonds[lat.cell_ptr[c]:lat.cell_ptr[c + 1]].tolist())
    assert csr == set(np.flatnonzero((lat.bond_i == c) | (lat.bond_j == c)).tolist())


def test_layers_and_footprint():
    poly = Polygon([(1, 1), (9, 2), (6, 8)])
    lat = build_lattice(poly, np.zeros((0, 3)), 4.0)
    z_levels = np.unique(np.round(lat.positions[:, 2], 9))
    assert np.allclose(z_levels, HALF * np.arange(6))  # 0 .. 3.54 <= 4
    assert np.all(shapely.contains_xy(poly, lat.positions[:, 0], lat.positions[:, 1]))
    # density of FCC: 4 sites per cube of side sqrt 2 -> sqrt 2 per l0^3 (area x 6 layers x a/2)
    expected = poly.area * 6 * HALF * np.sqrt(2)
    assert abs(lat.n_cells - expected) / expected < 0.1


def test_tetrahedra_are_unit_regular_and_positive():
    lat = build_lattice(box(0, 0, 6, 6), np.zeros((0, 3)), 3.0)
    e = lat.positions[lat.tets]
    for a, b in itertools.combinations(range(4), 2):
        assert np.allclose(np.linalg.norm(e[:, a] - e[:, b], axis=1), 1.0)
    assert np.allclose(signed_volumes(lat.positions, lat.tets), np.sqrt(2) / 12)
    assert 1.0 < len(lat.tets) / lat.n_cells < 2.0  # 2 per site in bulk, fewer at surfaces


def test_posts_inside_tether_disks_and_tiny_tether_widened():
    tethers = np.array([[3.0, 3.0, 1.2], [7.3, 6.9, 0.2]])
    lat = build_lattice(box(0, 0, 10, 10), tethers, 4.0)
    xy = lat.positions[:, :2]
    big = np.hypot(*(xy - tethers[0, :2]).T) <= 1.2
    tiny = np.hypot(*(xy - tethers[1, :2]).T) <= HALF * (1 + 1e-9)
    assert np.array_equal(lat.fixed, big | tiny)
    assert lat.n_widened_tethers == 1
    n_layers = len(np.unique(np.round(lat.positions[:, 2], 9)))
    layers_with_post = np.unique(np.round(lat.positions[tiny, 2], 9))
    assert len(layers_with_post) == n_layers  # the tiny post anchors every layer


def test_lattice_mirror_symmetric_for_symmetric_mould():
    poly = Polygon([(2, 2), (12, 2), (10, 9), (4, 9)])  # mirror about x = 7
    lat = build_lattice(poly, np.array([[4.5, 4, 1.0], [9.5, 4, 1.0]]), 2.0)
    mirrored = lat.positions * [-1, 1, 1] + [14, 0, 0]
    key = lambda p: set(map(tuple, np.round(p, 9)))
    assert key(mirrored) == key(lat.positions)
    assert key(mirrored[lat.fixed]) == key(lat.positions[lat.fixed])


def test_signed_distance_matches_shapely():
    poly = Polygon([(1, 1), (11, 1), (11, 9), (6, 5), (1, 9)])
    tethers = np.array([[4.0, 3.0, 1.0]])
    lat = build_lattice(poly, tethers, 2.0)
    region = poly.difference(Point(4, 3).buffer(1.0, quad_segs=256))
    rng = np.random.default_rng([0, 1])
    pts = rng.uniform([-0.9, -0.9], [12.9, 10.9], size=(400, 2))  # grid: polygon bounds + 2 l0
    phi = lat.region.signed_distance(pts)
    exact = np.array([(1 if region.contains(Point(p)) else -1) * region.boundary.distance(Point(p))
                      for p in pts])
    # bilinear interpolation at spacing 0.1: exact on straight walls, ~h/2 near corners (medial axis)
    assert np.abs(phi - exact).max() < 0.06
    assert np.all(np.sign(phi[np.abs(exact) > 0.06]) == np.sign(exact[np.abs(exact) > 0.06]))
    assert lat.region.signed_distance([[40.0, 40.0]])[0] < -100  # off the grid: far outside


@pytest.mark.parametrize(
    "polygon, tethers, depth, match",
    [
        # a frame 0.1 l0 wide holds no site
        (box(0, 0, 5, 5).difference(box(0.1, 0.1, 4.9, 4.9)), np.zeros((0, 3)), 2.0, "no mobile cell"),
        (box(0, 0, 3, 3), np.array([[1.5, 1.5, 5.0]]), 2.0, "no mobile cell"),
        (box(0, 0, 3, 3), np.zeros((0, 3)), 0.0, "depth"),
        (box(0, 0, 3, 3), np.zeros((0, 3)), -1.0, "depth"),
        (box(0, 0, 3, 3), np.ones((2, 2)), 1.0, "tethers"),
        (box(0, 0, 3, 3), np.array([[1.0, 1.0, -1.0]]), 1.0, "radius"),
        ("square", np.zeros((0, 3)), 1.0, "Polygon"),
    ],
)
def test_bad_input_raises(polygon, tethers, depth, match):
    with pytest.raises(ValueError, match=match):
        build_lattice(polygon, tethers, depth)


def test_posts_are_exact_circles_in_the_signed_distance():
    """The posts' part of the distance is computed, not sampled: exact to round-off, where a
    0.1 l0 grid would be off by ~h^2 / (8 r) and kinked at every grid line."""
    tethers = np.array([[4.0, 3.0, 0.5]])
    lat = build_lattice(box(0, 0, 8, 6), tethers, 2.0)
    angle = np.random.default_rng([0, 2]).uniform(0, 2 * np.pi, 200)
    radius = np.random.default_rng([0, 3]).uniform(0.3, 0.9, 200)
    pts = np.stack([4 + radius * np.cos(angle), 3 + radius * np.sin(angle)], axis=1)
    assert np.allclose(lat.region.signed_distance(pts), radius - 0.5, atol=1e-12)
    np.testing.assert_array_equal(lat.region.posts, tethers)
