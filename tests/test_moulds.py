"""Tests for condor.moulds.paper and the contract (condor.moulds.mould): statistics over many moulds, symmetry, contract, files, rasters."""

from __future__ import annotations

import json
import math
from collections import Counter
from dataclasses import replace

import numpy as np
import pytest
import shapely
from shapely import affinity
from shapely.geometry import MultiPolygon, Polygon, box as shapely_box

from condor.model.scenes import get_scene
from condor.moulds import mould as C
from condor.moulds import paper as M
from condor import plots

PAPER = get_scene("paper")
BOX = PAPER.box  # 62.5 l0
N_MOULDS = 2000
SEED = 20240607
# Chi-square critical value, 4 degrees of freedom, p = 0.001 (statistical tables).
CHI2_4DOF_P001 = 18.467


@pytest.fixture(scope="module")
def moulds() -> list[C.Mould]:
    return [M.generate_mould(SEED, i, PAPER) for i in range(N_MOULDS)]


def _tethered(moulds):
    return [m for m in moulds if m.removal != M.NO_TETHERS]


def _binomial_tolerance(p: float, n: int, sigmas: float = 4.0) -> float:
    return sigmas * math.sqrt(p * (1 - p) / n)


# --------------------------------------------------------------------------- statistics


def test_regime_shares_are_equal(moulds):
    counts = Counter(m.symmetry for m in moulds)
    assert set(counts) == set(C.SYMMETRIES)
    for symmetry in C.SYMMETRIES:
        assert abs(counts[symmetry] / N_MOULDS - 0.2) < 0.03, (symmetry, counts)


def test_removal_frequencies_follow_the_table(moulds):
    for symmetry in C.SYMMETRIES:
        removals = [m.removal for m in _tethered(moulds) if m.symmetry == symmetry]
        row = M.REMOVAL_FREQUENCIES[symmetry]
        total = sum(row.values())
        for removal in M.REMOVALS:
            observed = removals.count(removal) / len(removals)
            assert abs(observed - row[removal] / total) < 0.05, (symmetry, removal, observed)
            if row[removal] == 0.0:  # n/a in the paper
                assert observed == 0.0


def test_categorical_draws_match_the_table_closely():
    """The categorical draw alone, 60,000 times (cheap): 4-sigma binomial tolerances."""
    params = M.MouldParams()
    draws = [M._draw_choices(np.random.default_rng([7, i]), params) for i in range(60_000)]
    n = len(draws)
    for symmetry in C.SYMMETRIES:
        chosen = [d for d in draws if d.symmetry == symmetry and not d.no_tethers]
        share = sum(d.symmetry == symmetry for d in draws) / n
        assert abs(share - 0.2) < _binomial_tolerance(0.2, n)
        row = M.REMOVAL_FREQUENCIES[symmetry]
        for removal in M.REMOVALS:
            p = row[removal] / sum(row.values())
            observed = sum(d.removal == removal for d in chosen) / len(chosen)
            assert abs(observed - p) <= _binomial_tolerance(p, len(chosen)), (symmetry, removal)
    for name, p in (("convex", 0.25), ("concave", 0.75), ("no_tethers", 100 / 6500)):
        observed = sum(getattr(d, name) for d in draws) / n
        assert abs(observed - p) < _binomial_tolerance(p, n), name


def test_rotation_orders_are_uniform(moulds):
    orders = [m.order for m in moulds if m.symmetry in ("cyclic", "dihedral")]
    counts = np.array([orders.count(k) for k in range(2, 7)])
    assert counts.sum() == len(orders)  # nothing outside 2..6
    expected = len(orders) / 5
    chi2 = float(((counts - expected) ** 2 / expected).sum())
    assert chi2 < CHI2_4DOF_P001, counts


def test_orders_of_the_other_regimes(moulds):
    for m in moulds:
        if m.symmetry == "single_mirror":
            assert m.order == 2
        elif m.symmetry == "double_mirror":
            assert m.order == 4
        elif m.symmetry == "random_rotation":
            assert 2 <= m.order <= 4


def test_rounding_and_no_tether_fractions(moulds):
    n = len(moulds)
    for attribute, p in (("convex_rounded", 0.25), ("concave_rounded", 0.75)):
        observed = sum(getattr(m, attribute) for m in moulds) / n
        assert abs(observed - p) < _binomial_tolerance(p, n), attribute
    free = [m for m in moulds if m.removal == M.NO_TETHERS]
    p = M.MouldParams().no_tether_fraction
    assert abs(len(free) - p * n) < 4 * math.sqrt(n * p * (1 - p))
    assert all(m.n_tethers == 0 for m in free)


# --------------------------------------------------------------------------- geometry


def test_area_fraction_and_extent(moulds):
    for m in moulds:
        assert abs(m.polygon.area / BOX**2 - 0.40) < 0.005
        xmin, ymin, xmax, ymax = m.polygon.bounds
        assert max(xmax - xmin, ymax - ymin) <= 0.9 * BOX + 1e-9
        # centred: bounding-box centre at the box centre
        assert abs(0.5 * (xmin + xmax) - BOX / 2) < 1e-9 * BOX
        assert abs(0.5 * (ymin + ymax) - BOX / 2) < 1e-9 * BOX


def test_every_mould_is_a_single_valid_polygon(moulds):
    for m in moulds:
        assert isinstance(m.polygon, Polygon)
        assert m.polygon.is_valid
        C.check_mould(m)


def test_tethers_count_inside_and_apart(moulds):
    """Independent check: 90 points on each tether's rim lie in the polygon; centres are
    farther apart than the sum of radii."""
    theta = np.linspace(0, 2 * np.pi, 90, endpoint=False)
    for m in _tethered(moulds):
        assert m.n_tethers >= 4
        t = m.tethers
        assert (t[:, 2] > 0).all()
        rim_x = (t[:, 0:1] + t[:, 2:3] * np.cos(theta)).ravel()
        rim_y = (t[:, 1:2] + t[:, 2:3] * np.sin(theta)).ravel()
        assert shapely.contains_xy(m.polygon, rim_x, rim_y).all()
        assert shapely.contains_xy(m.polygon, t[:, 0], t[:, 1]).all()
        d = np.hypot(t[:, None, 0] - t[None, :, 0], t[:, None, 1] - t[None, :, 1])
        sums = t[:, None, 2] + t[None, :, 2]
        np.fill_diagonal(d, np.inf)
        assert (d > sums).all()


def test_tether_radii_scale_with_the_canvas(moulds):
    """Radii are 0.02-0.065 canvas widths; the canvas maps to the box by one similarity per
    mould, so the ratio of radii within a mould is at most 0.065/0.02."""
    for m in moulds:
        if len(m.unpruned_tethers):
            r = m.unpruned_tethers[:, 2]
            assert r.max() / r.min() <= 0.065 / 0.02 + 1e-9


def test_pruned_tethers_come_from_unpruned(moulds):
    for m in _tethered(moulds):
        for t in m.tethers:
            assert np.isclose(m.unpruned_tethers, t, rtol=0, atol=1e-12).all(axis=1).any()


def _reflect(geometry_or_xy, origin, axis):
    ox, oy = origin
    if axis == "vertical":
        matrix = [-1, 0, 0, 1, 2 * ox, 0]
    else:
        matrix = [1, 0, 0, -1, 0, 2 * oy]
    if isinstance(geometry_or_xy, np.ndarray):
        a, b, d, e, x0, y0 = matrix
        xy = geometry_or_xy
        return np.column_stack([a * xy[:, 0] + b * xy[:, 1] + x0, d * xy[:, 0] + e * xy[:, 1] + y0])
    return affinity.affine_transform(geometry_or_xy, matrix)


def _rotate_xy(xy, origin, angle):
    c, s = math.cos(angle), math.sin(angle)
    rel = xy - np.asarray(origin)
    return np.column_stack([c * rel[:, 0] - s * rel[:, 1], s * rel[:, 0] + c * rel[:, 1]]) + origin


def _same_tether_set(a: np.ndarray, b: np.ndarray, tol: float) -> bool:
    if a.shape != b.shape:
        return False
    for t in a:
        if not (np.abs(b - t).max(axis=1) < tol).any():
            return False
    return True


def _raster_symmetric(polygon, origin, transform_xy, box, pixels=128) -> None:
    """Rasterise on a grid centred on `origin`; pixels whose image under the symmetry
    disagrees must lie within one pixel of the boundary."""
    ps = box / pixels
    offsets = (np.arange(pixels) - pixels / 2 + 0.5) * ps
    x, y = np.meshgrid(origin[0] + offsets, origin[1] + offsets)
    xy = np.column_stack([x.ravel(), y.ravel()])
    mask = shapely.contains_xy(polygon, xy[:, 0], xy[:, 1])
    image = transform_xy(xy)
    mask_image = shapely.contains_xy(polygon, image[:, 0], image[:, 1])
    differ = xy[mask != mask_image]
    if len(differ):
        distance = shapely.distance(polygon.boundary, shapely.points(differ))
        assert (distance < ps).all()
    assert mask.sum() > 0.3 * pixels**2 * 0.4  # the mould is actually on the grid


def _symmetries(m: C.Mould):
    """Independent description of each regime's symmetry operations (point maps)."""
    o = np.asarray(m.origin)
    if m.symmetry == "single_mirror":
        # the axis is vertical or horizontal; accept whichever the footprint has
        return "mirror_either", [lambda xy, a=a: _reflect(xy, o, a) for a in M.MIRROR_AXES]
    if m.symmetry == "double_mirror":
        return "all", [lambda xy, a=a: _reflect(xy, o, a) for a in M.MIRROR_AXES]
    k = m.order
    ops = [lambda xy: _rotate_xy(xy, o, 2 * math.pi / k)]
    if m.symmetry == "dihedral":  # reflect first across the vertical line through the origin
        ops.append(lambda xy: _reflect(xy, o, "vertical"))
    return "all", ops


def _tether_image(tethers, op):
    return np.column_stack([op(tethers[:, :2]), tethers[:, 2]])


def _image_mismatch(polygon, op) -> float:
    """Area of the symmetric difference between `polygon` and its image under `op`."""
    image = Polygon(op(np.asarray(polygon.exterior.coords)),
                    [op(np.asarray(r.coords)) for r in polygon.interiors])
    return polygon.symmetric_difference(image).area


def test_symmetric_regimes_are_symmetric(moulds):
    checked = Counter()
    for m in moulds:
        if m.symmetry == "random_rotation" or checked[m.symmetry] >= 40:
            continue
        mode, ops = _symmetries(m)
        tol = 1e-7 * m.box
        if mode == "mirror_either":  # the axis is whichever maps the footprint best
            ops = [min(ops, key=lambda op: _image_mismatch(m.polygon, op))]
        for op in ops:
            _raster_symmetric(m.polygon, m.origin, op, m.box)
            image = _tether_image(m.unpruned_tethers, op)
            assert _same_tether_set(image, m.unpruned_tethers, tol), m.mould_id
            area_off = _image_mismatch(m.polygon, op)
            assert area_off < 1e-3 * m.polygon.area, (m.mould_id, area_off)
        checked[m.symmetry] += 1
    assert min(checked.values()) >= 20, checked


def test_symmetric_removals_keep_the_tether_symmetry(moulds):
    """Circular exclusion, symmetric bars and no removal are centred on the symmetry origin,
    so the kept tethers keep the mould's symmetry; rotated bars keep rotations only."""
    kept_rotation = broken_mirror = 0
    for m in _tethered(moulds):
        if m.symmetry == "random_rotation":
            continue
        mode, ops = _symmetries(m)
        tol = 1e-7 * m.box
        if m.removal in ("none", "circular", "symmetric_bars"):
            results = [_same_tether_set(_tether_image(m.tethers, op), m.tethers, tol) for op in ops]
            assert any(results) if mode == "mirror_either" else all(results), m.mould_id
        elif m.removal == "rotated_bars" and m.symmetry in ("cyclic", "dihedral"):
            rotation = ops[0]
            assert _same_tether_set(_tether_image(m.tethers, rotation), m.tethers, tol)
            kept_rotation += 1
        elif m.removal == "rotated_bars":
            mirrored = [_same_tether_set(_tether_image(m.tethers, op), m.tethers, tol)
                        for op in ops]
            broken_mirror += not all(mirrored)
    assert kept_rotation > 20
    assert broken_mirror > 0  # a rotational offset does break mirror symmetry of tethers


def test_random_rotation_copies_are_not_symmetric(moulds):
    """Sanity check of the test helpers: random rotations mostly fail a mirror test."""
    symmetric = 0
    rr = [m for m in moulds if m.symmetry == "random_rotation"][:30]
    for m in rr:
        image = _reflect(m.polygon, m.origin, "vertical")
        symmetric += m.polygon.symmetric_difference(image).area < 1e-3 * m.polygon.area
    assert symmetric < 3


# --------------------------------------------------------------------------- determinism


def test_deterministic_and_ids_differ():
    a = M.generate_mould(5, 11, PAPER).to_dict()
    b = M.generate_mould(5, 11, PAPER).to_dict()
    assert a == b
    assert M.generate_mould(5, 12, PAPER).to_dict() != a
    assert M.generate_mould(6, 11, PAPER).to_dict() != a


def test_box_only_scales_the_mould():
    small = M.generate_mould(3, 4, replace(PAPER, box=1.0))
    big = M.generate_mould(3, 4, replace(PAPER, box=31.25))
    assert small.symmetry == big.symmetry and small.removal == big.removal
    scaled = affinity.scale(small.polygon, 31.25, 31.25, origin=(0, 0))
    assert scaled.symmetric_difference(big.polygon).area < 1e-9 * big.polygon.area
    np.testing.assert_allclose(small.tethers * 31.25, big.tethers, rtol=1e-12, atol=1e-12)


@pytest.mark.parametrize("seed, mould_id, name", [
    (-1, 0, "seed"), (1.5, 0, "seed"), ("3", 0, "seed"), (True, 0, "seed"),
    (0, -2, "mould_id"), (0, 2.0, "mould_id"),
])
def test_bad_ids_raise(seed, mould_id, name):
    with pytest.raises(ValueError, match=name):
        M.generate_mould(seed, mould_id, PAPER)


def test_numpy_integer_ids_are_accepted():
    a = M.generate_mould(np.int64(2), np.uint32(3), PAPER)
    assert a.to_dict() == M.generate_mould(2, 3, PAPER).to_dict()


def test_bad_arguments_raise():
    with pytest.raises(ValueError, match="box"):
        M.generate_mould(0, 0, replace(PAPER, box=-1.0))
    with pytest.raises(ValueError, match="area_fraction"):
        M.generate_mould(0, 0, replace(PAPER, area_fraction=1.2))
    with pytest.raises(ValueError, match="max_extent"):
        M.generate_mould(0, 0, replace(PAPER, max_extent=0.0))


@pytest.mark.parametrize("field, value", [
    ("no_tether_fraction", 1.5), ("convex_rounding", -0.1), ("min_tethers", -1),
    ("circle_min", 0.0), ("bar_width_max", 0.05), ("order_min", 1), ("max_attempts", 0),
    ("min_points", 2.5),
])
def test_params_validate_names_the_field(field, value):
    with pytest.raises(ValueError, match=field):
        replace(M.MouldParams(), **{field: value}).validate()


def test_exhausted_attempts_raise_runtime_error():
    params = M.MouldParams(no_tether_fraction=0.0, min_tethers=1000, max_attempts=3)
    with pytest.raises(RuntimeError, match="3 attempts"):
        M.generate_mould(0, 0, PAPER, params=params)


def test_no_tether_fraction_one_gives_tether_free_moulds():
    params = M.MouldParams(no_tether_fraction=1.0)
    m = M.generate_mould(1, 1, PAPER, params=params)
    assert m.removal == M.NO_TETHERS and m.n_tethers == 0
    assert m.cell_region().equals(m.polygon)
    C.check_mould(m)


# --------------------------------------------------------------------------- validation


def _valid_mould() -> C.Mould:
    return M.generate_mould(9, 0, PAPER)


def test_validate_rejects_bow_tie():
    m = _valid_mould()
    side = math.sqrt(0.4) * BOX
    bow = Polygon([(10, 10), (10 + side, 10 + side), (10 + side, 10), (10, 10 + side)])
    with pytest.raises(C.InvalidMouldError, match="(?i)self-intersection|invalid"):
        C.check_mould(replace(m, polygon=bow, tethers=np.zeros((0, 3))))


def test_validate_rejects_tether_outside():
    m = _valid_mould()
    outside = np.vstack([m.tethers, [[0.5, 0.5, 0.3]]])  # the box corner is off the mould
    assert not m.polygon.contains(shapely.Point(0.5, 0.5))
    with pytest.raises(C.InvalidMouldError, match="not fully inside"):
        C.check_mould(replace(m, tethers=outside))
    # a tether whose centre is inside but whose disk crosses the wall
    boundary_point = np.asarray(m.polygon.exterior.coords[0])
    inner = m.polygon.centroid
    direction = np.asarray(inner.coords[0]) - boundary_point
    centre = boundary_point + 0.01 * direction / np.linalg.norm(direction) * 5
    crossing = np.array([[*centre, 1.0]])
    with pytest.raises(C.InvalidMouldError, match="not fully inside"):
        C.check_mould(replace(m, tethers=crossing))


def test_validate_rejects_other_faults():
    m = _valid_mould()
    t = m.tethers
    cases = {
        "MultiPolygon": replace(m, polygon=MultiPolygon([m.polygon, shapely_box(0, 0, 1, 1)])),
        "overlaps": replace(m, tethers=np.vstack([t, t[:1] + [[0.1, 0, 0]]])),
        "not positive": replace(m, tethers=np.vstack([t[:1] * [1, 1, 0], t[1:]])),
        "NaN": replace(m, tethers=np.vstack([t, [[np.nan, 1, 1]]])),
        "area fraction": replace(m, polygon=affinity.scale(m.polygon, 0.9, 0.9)),
        "shape": replace(m, tethers=t[:, :2]),
        "leave": replace(m, polygon=affinity.translate(m.polygon, BOX)),
    }
    for message, broken in cases.items():
        with pytest.raises(C.InvalidMouldError, match=message):
            C.check_mould(broken)


# --------------------------------------------------------------------------- files


def test_dict_and_json_round_trip(tmp_path, moulds):
    for m in moulds[:40]:
        d = m.to_dict()
        assert json.loads(json.dumps(d)) == d  # JSON-safe
        again = C.Mould.from_dict(d)
        assert again.to_dict() == d
        assert again.polygon.equals_exact(m.polygon, 0.0)
        path = tmp_path / f"m{m.mould_id}.json"
        C.save_json(m, path)
        loaded = C.load_json(path)
        assert loaded.to_dict() == d
        np.testing.assert_array_equal(loaded.tethers, m.tethers)


def test_load_json_names_the_file(tmp_path):
    m = _valid_mould()
    d = m.to_dict()
    d["tethers"].append([0.5, 0.5, 0.3])
    path = tmp_path / "broken.json"
    path.write_text(json.dumps(d))
    with pytest.raises(C.InvalidMouldError, match="broken.json"):
        C.load_json(path)
    garbage = tmp_path / "garbage.json"
    garbage.write_text("{not json")
    with pytest.raises(C.InvalidMouldError, match="garbage.json"):
        C.load_json(garbage)


# --------------------------------------------------------------------------- rasters


@pytest.mark.parametrize("pixels", [64, 256])
def test_input_channels(moulds, pixels):
    ps = BOX / pixels
    for m in _tethered(moulds)[:10]:
        channels = C.input_channels(m, pixels)
        assert channels.dtype == np.uint8 and channels.shape == (2, pixels, pixels)
        mould, tether = channels.astype(bool)
        assert not (mould & tether).any()
        # independent brute force for the tether channel: pixel (iy, ix) centre distances
        iy, ix = np.nonzero(tether)
        x, y = (ix + 0.5) * ps, (iy + 0.5) * ps
        d = np.hypot(x[:, None] - m.tethers[:, 0], y[:, None] - m.tethers[:, 1])
        assert (d < m.tethers[:, 2]).any(axis=1).all()
        assert abs(tether.sum() * ps**2 - np.pi * (m.tethers[:, 2] ** 2).sum()) < (
            2 * np.pi * m.tethers[:, 2].sum() * ps + m.n_tethers * ps**2)
        # mould pixel area approximates the cell region; error bounded by perimeter x pixel
        region = m.cell_region()
        error = abs(mould.sum() * ps**2 - region.area)
        assert error < 0.5 * region.length * ps + 4 * ps**2, (m.mould_id, pixels, error)


def test_input_channels_orientation():
    """Row iy covers y in [iy ps, (iy+1) ps): a mould in the lower half fills low rows."""
    m = _valid_mould()
    ps = BOX / 8
    tether = np.array([[6.5 * ps, 1.5 * ps, 0.4 * ps]])  # covers pixel (iy=1, ix=6) only
    low = replace(m, polygon=shapely_box(0, 0, BOX, BOX / 2), tethers=tether)
    channels = C.input_channels(low, 8)
    assert channels[0, :4].sum() == 4 * 8 - 1 and channels[0, 4:].sum() == 0
    assert channels[1].sum() == 1 and channels[1, 1, 6] == 1


def test_input_channels_bad_pixels():
    with pytest.raises(ValueError, match="pixels"):
        C.input_channels(_valid_mould(), 0)


# --------------------------------------------------------------------------- figures, tables


def test_regime_table(moulds):
    table = M.regime_table(moulds)
    assert list(table.index) == list(C.SYMMETRIES)
    assert table["n"].sum() == len(moulds)
    assert np.isclose(table["share"].sum(), 1.0)
    for symmetry in C.SYMMETRIES:
        row = table.loc[symmetry]
        assert np.isclose(sum(row[r] for r in M.REMOVALS), 1.0)
        assert row["circular_paper"] == pytest.approx(
            M.REMOVAL_FREQUENCIES[symmetry]["circular"]
            / sum(M.REMOVAL_FREQUENCIES[symmetry].values()))


def test_gallery_writes_png(tmp_path, moulds):
    path = tmp_path / "gallery.png"
    plots.mould_gallery(moulds[:8], path, ncols=4)
    assert path.read_bytes()[:8] == b"\x89PNG\r\n\x1a\n"


# --------------------------------------------------------------------------- user moulds


def _user_dict(polygon, tethers, box=BOX) -> dict:
    """What a user writes by hand: box, polygon and tethers, nothing of the generator."""
    return {"box": box, "polygon": shapely.geometry.mapping(polygon),
            "tethers": np.asarray(tethers, float).reshape(-1, 3).tolist()}


def test_a_hand_made_mould_needs_only_box_polygon_and_tethers(tmp_path):
    """The issue's case: a square of area fraction 0.262144 (not 0.4) with two tethers."""
    side = math.sqrt(0.262144) * BOX
    square = shapely_box(10, 10, 10 + side, 10 + side)
    tethers = [[20, 20, 1.5], [30, 30, 2.0]]
    path = tmp_path / "hand.json"
    path.write_text(json.dumps(_user_dict(square, tethers)))
    m = C.load_json(path)
    assert not m.is_generated and m.symmetry == C.USER and m.removal == C.USER
    assert m.seed is None and m.origin is None and m.unpruned_tethers is None
    assert m.area_fraction is None and m.order == 1 and m.mould_id == 0
    assert m.polygon.area / BOX**2 == pytest.approx(0.262144)
    # exact round trip of a user mould too
    d = m.to_dict()
    assert json.loads(json.dumps(d)) == d
    assert C.Mould.from_dict(d).to_dict() == d


def test_generated_mould_json_is_unchanged():
    """Every key a generated mould wrote before is written the same way (no nulls), and its
    source beside them (`family`, "paper" for the generator's: store format 6)."""
    d = M.generate_mould(4, 2, PAPER).to_dict()
    assert set(d) == {"mould_id", "seed", "symmetry", "order", "removal", "box", "polygon",
                      "tethers", "origin", "unpruned_tethers", "area_fraction",
                      "convex_rounded", "concave_rounded", "outline", "family"}
    assert d["family"] == "paper"
    assert None not in d.values()
    assert isinstance(d["seed"], int) and d["area_fraction"] == 0.4


def test_generated_moulds_keep_the_exact_area_rule_with_a_hint():
    m = _valid_mould()
    d = m.to_dict()
    d["polygon"] = shapely.geometry.mapping(affinity.scale(m.polygon, 0.9, 0.9))
    with pytest.raises(C.InvalidMouldError, match="area fraction .* is not 0.4 .*leaves out"):
        C.check_mould(C.Mould.from_dict(d))
    # the same geometry as a user mould (no symmetry, no area_fraction) is accepted
    user = C.Mould.from_dict({k: d[k] for k in ("box", "polygon", "tethers")})
    C.check_mould(user)
    # a user mould that states an area fraction must state the true one
    with pytest.raises(C.InvalidMouldError, match="area_fraction is the generator's target"):
        C.check_mould(replace(user, area_fraction=0.4))


def test_from_dict_names_missing_and_unknown_fields():
    square = shapely_box(10, 10, 30, 30)
    with pytest.raises(C.InvalidMouldError, match=r"missing mould field\(s\) \['tethers'\]"):
        C.Mould.from_dict({"box": BOX, "polygon": shapely.geometry.mapping(square)})
    with pytest.raises(C.InvalidMouldError, match="unknown mould field.*'tether'"):
        C.Mould.from_dict({**_user_dict(square, []), "tether": []})


@pytest.mark.parametrize("polygon, tethers, message", [
    (shapely_box(10, 10, 10.9, 40), [], "narrower than a cell"),
    # two 10 x 10 squares joined by a 0.8 l0 wide corridor
    (shapely.union_all([shapely_box(5, 5, 15, 15), shapely_box(15, 9.6, 20, 10.4),
                        shapely_box(20, 5, 30, 15)]), [], "neck narrower than a cell"),
    # one post filling a 3 x 3 square but for its corners
    (shapely_box(10, 10, 13, 13), [[11.5, 11.5, 1.49]], "no room for a mobile cell"),
    (shapely_box(10, 10, 30, 30), [[20, 20, 1], [21.5, 20, 1]], "overlaps"),
    (shapely_box(10, 10, 30, 30), [[10.5, 20, 1]], "not fully inside"),
    (shapely_box(10, 10, 30, 30), [[20, 20, 0]], "not positive"),
    (shapely_box(-1, 10, 30, 30), [], "leave the box"),
])
def test_user_moulds_are_refused_by_geometry(polygon, tethers, message):
    m = C.Mould.from_dict(_user_dict(polygon, tethers))
    with pytest.raises(C.InvalidMouldError, match=message):
        C.check_mould(m)


def test_accepted_user_moulds_always_hold_mobile_cells():
    """Brute force against condor.model.lattice: rotated strips near the one-cell limit, half of
    them with a post of random size; every mould check_mould accepts builds a lattice
    with mobile cells (the check is conservative: it refuses some that would too)."""
    from condor.model.lattice import build_lattice

    rng = np.random.default_rng(11)
    accepted = refused = 0
    for _ in range(300):
        x0, y0 = rng.uniform(5, 40, size=2)
        w, h = rng.uniform(0.8, 2.2), rng.uniform(0.8, 6.0)
        polygon = affinity.rotate(shapely_box(x0, y0, x0 + w, y0 + h), rng.uniform(0, 90))
        cx, cy = polygon.centroid.coords[0]
        tethers = [[cx, cy, rng.uniform(0.05, 0.5 * min(w, h))]] if rng.random() < 0.5 else []
        m = C.Mould.from_dict(_user_dict(polygon, tethers))
        try:
            C.check_mould(m)
        except C.InvalidMouldError:
            refused += 1
            continue
        accepted += 1
        lattice = build_lattice(m.polygon, m.tethers, depth=2.0)
        assert (~lattice.fixed).any()
    assert accepted > 50 and refused > 50


def test_is_tether_free_is_the_generators_own_choice():
    """The config sizes replicas from is_tether_free before any mould exists: it must agree
    with the generated moulds (a high fraction makes both kinds common)."""
    params = M.MouldParams(no_tether_fraction=0.4)
    answers = [(M.is_tether_free(7, i, params), M.generate_mould(7, i, PAPER, params=params).n_tethers == 0)
               for i in range(40)]
    assert all(a == b for a, b in answers)
    assert 5 < sum(a for a, _ in answers) < 35
