"""Tests of the lab mould families (condor.data.lab)."""

import numpy as np
import pytest
import shapely

from condor.model.scenes import get_scene
from condor.moulds.composite import COMPOSITE, COMPOSITE_FAMILY
from condor.moulds.lab import (
    AREA_RANGE, CLEARANCE, FAMILIES, FAMILY_NAMES, MAX_EXTENT, family_geometry, lab_geometry,
    lab_mould,
)

EVERY = {**FAMILIES, COMPOSITE: COMPOSITE_FAMILY}  # the lab families and the training source
from condor.moulds.mould import PAPER, Mould, check_mould, load_json, save_json


@pytest.mark.parametrize("family", tuple(EVERY))
def test_every_family_draws_valid_moulds_within_its_ranges(family):
    """40 moulds a family at the default box: the mould contract (check_mould: inside the
    box, posts inside and apart, room for cells), the area and extent rules, the posts'
    clearance and radii, each measured on the geometry itself."""
    box = 31.25
    low, high = EVERY[family].ranges["post radius"]
    counts, holes = set(), 0
    for i in range(40):
        polygon, tethers = family_geometry(7, i, EVERY[family], box)
        check_mould(Mould(box=box, polygon=polygon, tethers=tethers))
        fraction = polygon.area / box**2
        assert AREA_RANGE[0] - 1e-9 <= fraction <= AREA_RANGE[1] + 1e-9
        xmin, ymin, xmax, ymax = polygon.bounds
        assert max(xmax - xmin, ymax - ymin) <= MAX_EXTENT * box * (1 + 1e-9)
        assert 1 <= len(tethers) <= 8
        r = tethers[:, 2] / box
        assert np.all((r >= low - 1e-12) & (r <= high + 1e-12))
        walls = shapely.boundary(polygon)
        gaps = shapely.distance(walls, shapely.points(tethers[:, :2])) - tethers[:, 2]
        assert gaps.min() >= CLEARANCE * box * (1 - 1e-9)
        counts.add(len(tethers))
        holes += len(polygon.interiors) > 0
    if family == COMPOSITE:  # what the paper's generator never makes: 1-2 posts, holes
        assert {1, 2} <= counts and len(counts) >= 6 and 4 <= holes <= 24
    if family == "ring":
        assert counts == {1}
    if family in ("strip", "dogbone"):
        assert counts == {2}


def test_a_lab_mould_is_a_pure_function_of_seed_and_id():
    a = lab_geometry(3, 11, "dogbone", 31.25)
    b = lab_geometry(3, 11, "dogbone", 31.25)
    c = lab_geometry(3, 12, "dogbone", 31.25)
    assert a[0].equals_exact(b[0], 0) and np.array_equal(a[1], b[1])
    assert not a[0].equals_exact(c[0], 1e-6)
    # the box only scales: the same mould at half the box is the same shape, halved
    half = lab_geometry(3, 11, "dogbone", 31.25 / 2)
    assert np.allclose(np.asarray(half[0].exterior.coords) * 2, np.asarray(a[0].exterior.coords))


def test_shapes_with_holes_have_holes_and_an_unknown_family_is_refused():
    for family in ("annulus", "frame"):
        polygon, _ = lab_geometry(1, 0, family, 31.25)
        assert len(polygon.interiors) >= 1
    with pytest.raises(ValueError, match="unknown lab family 'star'.*choose one of"):
        lab_geometry(1, 0, "star", 31.25)


def test_a_lab_mould_carries_its_family_through_json(tmp_path):
    scene = get_scene("default")
    mould = lab_mould(2026, 5, "frame", scene)
    assert mould.family == "frame" and mould.seed == 2026 and not mould.is_generated
    save_json(mould, tmp_path / "m.json")
    back = load_json(tmp_path / "m.json")
    assert back.family == "frame" and back.polygon.equals_exact(mould.polygon, 0)
    # a mould file written before families existed reads as the generator's or a user's
    plain = Mould(box=scene.box, polygon=mould.polygon, tethers=mould.tethers)
    assert plain.family == "user"
    d = mould.to_dict()
    d.pop("family")
    d["symmetry"] = "cyclic"
    assert Mould.from_dict(d).family == PAPER


def test_rim_posts_stand_at_their_inset_from_one_wall_equally_spaced():
    """Composite moulds' wall-following posts (as in a frame's bars or along a strip's sides):
    each at `inset` from the wall it follows, the other wall farther, equally spaced along it."""
    from shapely.geometry import Polygon

    from condor.moulds.composite import _rim_posts

    frame = Polygon([(0, 0), (3, 0), (3, 2), (0, 2)], [[(0.6, 0.6), (2.4, 0.6), (2.4, 1.4),
                                                       (0.6, 1.4)]])
    walls = [frame.exterior, frame.interiors[0]]
    seen = set()
    for seed in range(12):
        posts = _rim_posts(np.random.default_rng(seed), frame, 5, inset=0.2)  # bars of 0.6
        assert posts is not None and posts.shape == (5, 2)
        d = np.array([[w.distance(shapely.Point(p)) for w in walls] for p in posts])
        nearest = d.argmin(axis=1)
        assert len(set(nearest)) == 1  # one wall followed
        assert np.allclose(d.min(axis=1), 0.2, atol=0.01)
        seen.add(int(nearest[0]))
        # equal spacing along the offset curve: the gaps between neighbours along it agree
        ring = Polygon(walls[nearest[0]]).buffer(0.2 if nearest[0] else -0.2)
        along = np.sort([ring.exterior.project(shapely.Point(p), normalized=True) for p in posts])
        gaps = np.diff(np.append(along, along[0] + 1))
        assert np.allclose(gaps, 0.2, atol=0.01)
    assert seen == {0, 1}  # the outer wall and the hole's, each chosen sometimes
    # an inset that leaves the mould (past the bar) places nothing
    assert _rim_posts(np.random.default_rng(0), frame, 4, inset=0.7) is None


def test_tip_posts_stand_at_the_ends_of_arms_and_a_disk_has_none():
    """Composite moulds' tip posts (as labs anchor a strip, a cross or a T at its arms' ends):
    on a T of bars 1 wide, one post in each arm's end, within reach of the tip and centred
    across the arm; the farthest tips first when fewer posts are asked; a disk has no tip."""
    from shapely.geometry import LineString, Point

    from condor.moulds.composite import TIP_REACH, _tip_posts

    def bar(p, q):
        return LineString([p, q]).buffer(0.5, cap_style="flat")

    tee = shapely.union_all([bar((-3, 0), (3, 0)), bar((0, 0), (0, -2))])
    posts = _tip_posts(tee, 8)
    assert posts is not None and len(posts) == 3
    ends = {(-3, 0): 1, (3, 0): 1, (0, -2): 0}  # the tip and the axis across its arm
    for end, axis in ends.items():
        d = np.linalg.norm(posts - np.array(end), axis=1)
        p = posts[int(np.argmin(d))]
        assert d.min() <= TIP_REACH + 0.5  # within reach of the arm's end
        assert abs(p[axis]) < 0.05  # on the arm's midline
    two = _tip_posts(tee, 2)  # the two farthest tips from the pole: the crossbar's ends
    assert len(two) == 2 and np.allclose(np.sort(np.abs(two[:, 0])), [2.75, 2.75], atol=0.3)
    assert _tip_posts(Point(0, 0).buffer(2, quad_segs=32), 3) is None


def test_random_posts_leave_a_sliver_of_an_inner_region_for_the_whole_outline(monkeypatch):
    """A band whose half-width is a hair over random_posts' wall margin leaves an inner region
    of ~1e-9 of its bounds (a composite mould of the default drew one: 2 CPU minutes of
    candidates). The posts then come from the whole band, after EMPTY_BATCHES misses."""
    from shapely.geometry import Point

    import condor.moulds.lab as lab

    band = Point(0, 0).buffer(1, quad_segs=64).difference(
        Point(0, 0).buffer(1 - 0.4 - 2e-7, quad_segs=64))
    margin = 0.2 * 2.0 / 2  # the margin random_posts keeps from the wall: a fifth of half 2
    assert 0 < band.buffer(-margin).area < 1e-8 * 4  # the sliver
    calls = []
    inside = shapely.contains_xy

    def counted(*a):
        calls.append(1)
        if len(calls) > 25_000:  # a draw that never ends fails here rather than hangs
            raise AssertionError("random_posts kept drawing")
        return inside(*a)

    monkeypatch.setattr(lab.shapely, "contains_xy", counted)
    posts = lab.random_posts(np.random.default_rng(3), band, 4)
    assert posts.shape == (4, 2)
    assert shapely.contains_xy(band, posts[:, 0], posts[:, 1]).all()
    assert lab.EMPTY_BATCHES <= len(calls) < lab.EMPTY_BATCHES + 100
    # a disk's inner region holds every post at the margin from its wall, at once
    calls.clear()
    disk = Point(0, 0).buffer(1, quad_segs=64)
    posts = lab.random_posts(np.random.default_rng(3), disk, 4)
    assert (np.hypot(*posts.T) < 1 - margin + 1e-9).all() and len(calls) < 20
