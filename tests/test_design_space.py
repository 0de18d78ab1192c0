"""The design space: every vector gives a mould the simulator accepts (condor.design.space)."""

import math

import numpy as np
import pytest
import shapely
from shapely import affinity

from condor.design.objectives import parse_objective
from condor.design.space import DesignSpace, default_space, symmetry_group
from condor.model.lattice import build_lattice
from condor.moulds.mould import check_mould
from condor.model.scenes import get_scene
from condor.model.simulate import simulate

SCENE = get_scene("default")
SYMMETRIES = ["none", "single_mirror", "double_mirror", "cyclic:3", "dihedral:4"]


def check_fabrication_limits(space: DesignSpace, mould):
    """The limits, recomputed from the mould alone."""
    check_mould(mould)
    box = space.box
    assert mould.polygon.area == pytest.approx(space.area_fraction * box**2, rel=1e-9)
    xmin, ymin, xmax, ymax = mould.polygon.bounds
    assert max(xmax - xmin, ymax - ymin) <= space.max_extent * box * (1 + 1e-9)
    assert (xmin + xmax) / 2 == pytest.approx(box / 2) and (ymin + ymax) / 2 == pytest.approx(box / 2)
    assert not mould.polygon.buffer(-space.min_neck_box * box / 2 * 0.999).is_empty
    assert mould.polygon.buffer(-space.min_neck_box * box / 2 * 0.999).geom_type == "Polygon"
    t = mould.tethers
    if len(t):
        assert t[:, 2].min() >= space.min_tether_radius - 1e-12
        assert t[:, 2].max() <= space.max_tether_radius + 1e-12
        assert shapely.contains_xy(mould.polygon, t[:, 0], t[:, 1]).all()
        wall = shapely.distance(mould.polygon.exterior, shapely.points(t[:, :2]))
        assert (wall - t[:, 2] >= space.min_gap - 1e-9).all()
        gaps = np.hypot(*(t[:, None, :2] - t[None, :, :2]).transpose(2, 0, 1)) \
            - t[:, None, 2] - t[None, :, 2]
        np.fill_diagonal(gaps, np.inf)
        assert gaps.min() >= space.min_gap - 1e-9


@pytest.mark.parametrize("symmetry", SYMMETRIES)
def test_random_vectors_always_give_valid_moulds_within_the_limits(symmetry):
    space = DesignSpace.from_scene(SCENE, symmetry=symmetry, n_tethers=5)
    rng = np.random.default_rng(7)
    # standard normal (the search's probe) and three times wider (far outside the family)
    vectors = np.concatenate([space.random_vectors(rng, 60), 3 * space.random_vectors(rng, 40)])
    repaired = 0
    for i, x in enumerate(vectors):
        decoded = space.decode(x, mould_id=i)
        check_fabrication_limits(space, decoded.mould)
        repaired += decoded.repair > 0
    assert repaired > 0  # the wide draws needed repair and still gave valid moulds


def test_moulds_have_the_spaces_symmetry():
    rng = np.random.default_rng(3)
    for symmetry in SYMMETRIES[1:]:
        space = DesignSpace.from_scene(SCENE, symmetry=symmetry, symmetry_angle=0.3)
        _, _, maps = symmetry_group(symmetry, 0.3)
        for x in space.random_vectors(rng, 5):
            mould = space.mould(x)
            ox, oy = mould.origin
            for m in maps:
                image = affinity.affine_transform(
                    mould.polygon, [*m[0], *m[1], ox - m[0] @ (ox, oy), oy - m[1] @ (ox, oy)])
                assert image.symmetric_difference(mould.polygon).area < 1e-3 * mould.polygon.area
                if len(mould.tethers):
                    moved = (mould.tethers[:, :2] - (ox, oy)) @ m.T + (ox, oy)
                    distance = np.hypot(*(moved[:, None] - mould.tethers[None, :, :2]).T)
                    assert distance.min(axis=0).max() < 1e-6


def test_decoding_is_deterministic_and_checks_the_vector():
    space = DesignSpace.from_scene(SCENE)
    x = np.random.default_rng(0).standard_normal(space.dim)
    a, b = space.mould(x, 4, 9), space.mould(x, 4, 9)
    assert a.polygon.equals_exact(b.polygon, 0) and np.array_equal(a.tethers, b.tethers)
    assert (a.mould_id, a.seed, a.symmetry, a.order) == (4, 9, "double_mirror", 4)
    with pytest.raises(ValueError, match="shape"):
        space.decode(np.zeros(space.dim + 1))
    with pytest.raises(ValueError, match="NaN"):
        space.decode(np.full(space.dim, np.nan))


def test_an_over_elongated_shape_is_shrunk_towards_a_circle_with_a_repair_cost():
    space = DesignSpace.from_scene(SCENE, symmetry="double_mirror", n_tethers=0)
    x = np.zeros(space.dim)
    x[0] = 12.0  # the cos 2 theta mode: far longer than the box allows
    decoded = space.decode(x)
    assert 0 < decoded.shrink < 1 and decoded.repair > 0
    xmin, _, xmax, _ = decoded.mould.polygon.bounds
    assert xmax - xmin == pytest.approx(space.max_extent * space.box, rel=2e-3)  # at the limit
    assert space.decode(np.zeros(space.dim)).repair == 0  # a circle needs none


def test_fewer_tethers_than_the_minimum_cost_repair():
    space = DesignSpace.from_scene(SCENE, symmetry="none", n_tethers=2, min_tethers=3)
    x = np.zeros(space.dim)
    x[space.n_shape + 3] = x[space.n_shape + 7] = 1.0  # both present
    assert space.decode(x).repair >= 1  # two tethers, three wanted


def test_the_symmetric_basis_has_only_the_modes_the_group_allows():
    # double mirror keeps cos(2k theta): modes 2, 4, 6 of 6; cyclic:3 keeps m = 3, 6 (2 each)
    assert DesignSpace.from_scene(SCENE, symmetry="double_mirror").n_shape == 3
    assert DesignSpace.from_scene(SCENE, symmetry="cyclic:3").n_shape == 4
    assert DesignSpace.from_scene(SCENE, symmetry="none").n_shape == 12


def test_bad_settings_are_named():
    with pytest.raises(ValueError, match="symmetry 'cyclic'"):
        DesignSpace.from_scene(SCENE, symmetry="cyclic")
    with pytest.raises(ValueError, match="unknown symmetry 'spiral'"):
        DesignSpace.from_scene(SCENE, symmetry="spiral")
    with pytest.raises(ValueError, match="max_extent"):
        DesignSpace.from_scene(SCENE, max_extent=0.5)
    with pytest.raises(ValueError, match="min_tether_radius"):
        DesignSpace.from_scene(SCENE, min_tether_radius=5.0)


def test_default_space_turns_its_mirrors_to_the_alignment_direction():
    assert default_space(SCENE, parse_objective("alignment:x")).symmetry_angle == 0
    turned = default_space(SCENE, parse_objective("alignment:30deg+uniformity"))
    assert turned.symmetry == "double_mirror"
    assert turned.symmetry_angle == pytest.approx(math.radians(30))
    assert default_space(SCENE, parse_objective("alignment:x+alignment:30deg")).symmetry == "none"
    assert default_space(SCENE, parse_objective("-max_tension")).symmetry == "double_mirror"


def test_the_simulator_accepts_design_moulds():
    scene = get_scene("tiny")
    space = DesignSpace.from_scene(scene, symmetry="none", n_tethers=4)
    rng = np.random.default_rng(11)
    moulds = [space.mould(x) for x in space.random_vectors(rng, 20)]
    for mould in moulds:
        lattice = build_lattice(mould.polygon, mould.tethers, scene.depth)
        assert (~lattice.fixed).sum() > 0
    with_tethers = next(m for m in moulds if m.n_tethers)
    result = simulate(with_tethers.polygon, with_tethers.tethers, scene.depth, budget=2, seed=1)
    assert result.status == "ok"


def test_design_moulds_round_trip_through_the_mould_file_that_condor_simulate_reads(tmp_path):
    from condor.moulds.mould import load_json, save_json

    space = DesignSpace.from_scene(SCENE, symmetry="none")
    for i, x in enumerate(space.random_vectors(np.random.default_rng(5), 5)):
        mould = space.mould(x, mould_id=i, seed=3)
        save_json(mould, tmp_path / f"{i}.json")
        back = load_json(tmp_path / f"{i}.json")  # validates, as `condor simulate` does
        assert back.polygon.equals_exact(mould.polygon, 0)
        assert np.array_equal(back.tethers, mould.tethers) and back.symmetry == "none"


def test_constrained_space_keeps_your_footprint_and_post_count():
    """design --mould --keep footprint,posts (issue 32): every decoded mould has exactly the
    user's outline, and --keep posts gives the user's number of posts wherever they fit."""
    from shapely.geometry import Point, box as shapely_box

    from condor.design import constrained_space
    from condor.moulds.place import place_mould
    from condor.model.scenes import get_scene

    scene = get_scene("default")
    lobes = Point(0, 0).buffer(6, 64).union(Point(14, 0).buffer(6, 64))
    outline = lobes.union(shapely_box(0, -2, 14, 2))  # a dog-bone, 26 x 12 l0
    user = place_mould(outline, [[0, 0, 1.5], [14, 0, 1.5]], scene)
    rng = np.random.default_rng(4)
    both = constrained_space(scene, user, ["footprint", "posts"])
    counts = []
    for vector in both.random_vectors(rng, 30):
        mould = both.mould(vector)
        assert mould.polygon.equals(user.polygon)
        assert all(mould.polygon.contains(Point(x, y).buffer(r)) for x, y, r in mould.tethers)
        counts.append(mould.n_tethers)
    assert max(counts) == 2  # never more posts than yours
    # the search's starting point (genes 0) puts one post into each lobe, along the axis
    start = both.mould(np.zeros(both.dim))
    assert start.n_tethers == 2
    assert sorted(np.sign(start.tethers[:, 0] - user.polygon.centroid.x)) == [-1, 1]
    posts = constrained_space(scene, user, ["posts"])
    assert posts.footprint is None and posts.n_tethers == 2 and posts.all_present
    shapes = [posts.mould(v).polygon.area for v in posts.random_vectors(rng, 5)]
    assert np.ptp(shapes) < 1e-9 * scene.box**2  # the training area, searched outline
    with pytest.raises(ValueError, match="--keep"):
        constrained_space(scene, user, ["outline"])
