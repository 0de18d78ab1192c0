"""Design objectives on synthetic fields with known answers (condor.design.objectives)."""

import math

import numpy as np
import pytest

from condor.design.objectives import (EmptyRegionError, InfeasibleConstraintError, Objective,
                                      ObjectiveError, UnknownObjectiveError, parse_objective)
from condor.data.fields import cell_fields, normalise

BOX, PIXELS = 16.0, 32


def cells_fields(xy, orientations, tension, box=BOX, pixels=PIXELS):
    """Normalised fields of explicit cells, through the real rasteriser."""
    positions = np.column_stack([xy, np.zeros(len(xy))])
    raw = cell_fields(positions, orientations, tension, box, pixels)
    return normalise(raw.astype(np.float64), len(xy))


def random_cells(rng, n, centre, half, tilt=0.6):
    """n cells uniformly in a square (away from the border), random 3-D orientations biased
    towards the plane."""
    xy = centre + rng.uniform(-half, half, (n, 2))
    s = rng.standard_normal((n, 3)) * [1.0, 0.7, tilt]
    s /= np.linalg.norm(s, axis=1, keepdims=True)
    return xy, s


def test_alignment_is_the_in_plane_weighted_mean_of_cos_2_phi_over_cells():
    rng = np.random.default_rng(0)
    xy, s = random_cells(rng, 400, np.array([8.0, 8.0]), 3.0)
    fields = cells_fields(xy, s, rng.normal(0, 0.01, len(xy)))
    phi = np.arctan2(s[:, 1], s[:, 0])
    weight = s[:, 0] ** 2 + s[:, 1] ** 2
    for degrees in (0, 30, 45, 90, 135):
        theta = math.radians(degrees)
        expected = np.sum(weight * np.cos(2 * (phi - theta))) / weight.sum()
        value = parse_objective(f"alignment:{degrees}deg").evaluate(fields)["objective"][0]
        assert value == pytest.approx(expected, abs=1e-5)
    x = parse_objective("alignment:x").evaluate(fields)["objective"][0]
    y = parse_objective("alignment:y").evaluate(fields)["objective"][0]
    assert x == pytest.approx(-y) and abs(x) > 0.1  # the draw is biased along x


def test_perfectly_aligned_cells_give_one_and_crossed_give_minus_one():
    rng = np.random.default_rng(1)
    xy, _ = random_cells(rng, 200, np.array([8.0, 8.0]), 3.0)
    angle = math.radians(30)
    s = np.tile([math.cos(angle), math.sin(angle), 0.0], (len(xy), 1))
    fields = cells_fields(xy, s, np.zeros(len(xy)))
    along = parse_objective("alignment:30deg").evaluate(fields)["objective"][0]
    across = parse_objective("alignment:120").evaluate(fields)["objective"][0]
    assert along == pytest.approx(1.0, abs=1e-6) and across == pytest.approx(-1.0, abs=1e-6)


def test_alignment_inside_a_region_sees_only_the_cells_there():
    """Two clusters further from the halves' boundary (x = 12) and the grid's border than the
    kernel window (5.5 sigma = 4.03 l0): x-aligned on the left, y-aligned on the right."""
    rng = np.random.default_rng(2)
    left, _ = random_cells(rng, 150, np.array([5.0, 12.0]), 0.8)
    right, _ = random_cells(rng, 100, np.array([19.0, 12.0]), 0.8)
    s = np.concatenate([np.tile([1.0, 0, 0], (150, 1)), np.tile([0, 1.0, 0], (100, 1))])
    fields = cells_fields(np.concatenate([left, right]), s, np.zeros(250), box=24.0, pixels=48)
    objective = parse_objective("alignment:x@left + alignment:x@right + alignment:x")
    row = objective.evaluate(fields).iloc[0]
    assert row["alignment:0deg@left"] == pytest.approx(1.0, abs=1e-6)
    assert row["alignment:0deg@right"] == pytest.approx(-1.0, abs=1e-6)
    assert row["alignment:0deg"] == pytest.approx((150 - 100) / 250, abs=1e-6)
    rect = parse_objective("alignment:x@rect(0,0.5,0,1)").evaluate(fields)["objective"][0]
    assert rect == pytest.approx(1.0, abs=1e-6)


def test_density_cv_is_the_cell_weighted_coefficient_of_variation():
    """Piecewise-constant density: each pixel counts with its number of cells."""
    fields = np.zeros((8, PIXELS, PIXELS))
    fields[0, 4:12, 4:20] = 3.0
    fields[0, 12:20, 4:20] = 1.0
    fields[0, 0, 0] = -0.5  # a surrogate's ringing: clipped to 0
    values = np.clip(fields[0].ravel(), 0, None)
    mean = np.average(values, weights=values)
    expected = math.sqrt(np.average((values - mean) ** 2, weights=values)) / mean
    row = parse_objective("uniformity + density_cv").evaluate(fields).iloc[0]
    assert row["density_cv"] == pytest.approx(expected, rel=1e-9)
    assert row["uniformity"] == pytest.approx(1 - expected, rel=1e-9)
    flat = np.zeros((8, PIXELS, PIXELS))
    flat[0, 5:25, 3:9] = 2.5
    assert parse_objective("density_cv").evaluate(flat)["objective"][0] == pytest.approx(0, abs=1e-7)


def test_tension_hot_spot_and_mean_tension():
    fields = np.zeros((8, PIXELS, PIXELS))
    fields[0, 8:24, 8:24] = 2.0
    fields[1, 8:24, 8:24] = 0.01
    fields[1, 10, 20] = 0.5  # right half
    fields[1, 20, 9] = 0.2  # left half
    objective = parse_objective("-max_tension + mean_tension + max_tension@left")
    row = objective.evaluate(fields).iloc[0]
    assert row["max_tension"] == 0.5 and row["max_tension@left"] == 0.2
    expected_mean = fields[1].sum() / fields[0].sum()
    assert row["mean_tension"] == pytest.approx(expected_mean)
    assert row["objective"] == pytest.approx(-0.5 + expected_mean + 0.2)


def test_ratios_ignore_normalisation_and_max_tension_scales_with_it():
    rng = np.random.default_rng(3)
    xy, s = random_cells(rng, 300, np.array([8.0, 8.0]), 3.0)
    raw = cell_fields(np.column_stack([xy, np.zeros(300)]), s, rng.uniform(0, 0.1, 300),
                      BOX, PIXELS).astype(np.float64)
    objective = parse_objective("alignment:x + uniformity + mean_tension + 0*max_tension")
    a = objective.evaluate_raw(raw[None], [300]).iloc[0]
    b = objective.evaluate(raw).iloc[0]
    for name in ("alignment:0deg", "uniformity", "mean_tension"):
        assert a[name] == pytest.approx(b[name], rel=1e-9)
    assert a["max_tension"] == pytest.approx(b["max_tension"] * PIXELS**2 / 300, rel=1e-9)


def test_region_without_cells_is_nan_not_an_error():
    fields = np.zeros((8, PIXELS, PIXELS))
    fields[0, 4:12, 4:12] = 1.0
    fields[2, 4:12, 4:12] = 1.0
    row = parse_objective("alignment:x@right").evaluate(fields).iloc[0]
    assert np.isnan(row["objective"])


def test_parser_terms_weights_and_labels():
    objective = parse_objective("alignment:x+0.5*uniformity - 2e-1*max_tension@centre")
    assert [w for w, _ in objective.terms] == [1.0, 0.5, -0.2]
    assert [q.label for _, q in objective.terms] == ["alignment:0deg", "uniformity",
                                                     "max_tension@centre"]
    assert objective.label == "alignment:0deg+0.5*uniformity-0.2*max_tension@centre"
    assert parse_objective("alignment:0.5rad").terms[0][1].angle == pytest.approx(0.5)
    assert parse_objective("alignment:-30deg").terms[0][1].angle == pytest.approx(-math.pi / 6)
    assert parse_objective("-max_tension").terms == ((-1.0, parse_objective("max_tension").terms[0][1]),)
    constrained = parse_objective("alignment:y; max_tension<=0.02 ; uniformity>0.5")
    assert [c.label for c in constrained.constraints] == ["max_tension<=0.02", "uniformity>0.5"]


def test_constraints_give_violation_and_feasibility():
    fields = np.zeros((2, 8, PIXELS, PIXELS))
    fields[:, 0, 8:24, 8:24] = 2.0
    fields[0, 1, 10, 10] = 0.03
    fields[1, 1, 10, 10] = 0.01
    table = parse_objective("uniformity; max_tension<0.02").evaluate(fields)
    assert table["violation"].tolist() == pytest.approx([0.01, 0.0])
    assert table["feasible"].tolist() == [False, True]


@pytest.mark.parametrize("spec, words", [
    ("alignmnet:x", ["alignmnet", "alignment"]),
    ("alignment", ["needs a direction"]),
    ("uniformity:x", ["takes no direction"]),
    ("alignment:z", ["unknown direction", "'z'"]),
    ("alignment:x@middle", ["unknown region", "'middle'"]),
    ("alignment:x +", ["an objective name"]),
    ("alignment:x$", ["'$'"]),
    ("", ["empty"]),
    ("; uniformity>0.1", ["nothing to maximise"]),
    ("uniformity; max_tension", ["needs a comparison"]),
    ("0.5 uniformity", ["'*'"]),
])
def test_unknown_or_malformed_objectives_name_the_problem(spec, words):
    with pytest.raises(UnknownObjectiveError) as error:
        parse_objective(spec)
    assert all(w in str(error.value) for w in words), str(error.value)
    assert isinstance(error.value, ValueError)


@pytest.mark.parametrize("spec, pixels", [
    ("alignment:x@rect(0.5,0.5,0,1)", None),  # zero width
    ("alignment:x@disc(0.5,0.5,0)", None),
    ("alignment:x@rect(0.3,0.31,0.3,0.31)", 32),  # holds no pixel centre of a 32 px grid
    ("uniformity@rect(0,0.04,0,1)", 32),  # outside the central 0.9 where every mould lies
])
def test_empty_regions_are_refused(spec, pixels):
    with pytest.raises(EmptyRegionError, match="region"):
        parse_objective(spec, pixels=pixels, max_extent=0.9)


def test_region_check_accepts_a_small_reachable_region():
    parse_objective("alignment:x@rect(0.3,0.34,0.3,0.34)", pixels=32, max_extent=0.9)


@pytest.mark.parametrize("spec", [
    "alignment:x; alignment:x>1.1",
    "uniformity; uniformity>1.2",
    "uniformity; density_cv<-0.1",
    "alignment:x; max_tension<0.1; max_tension>0.2",
    "alignment:x; alignment:x>0.6; alignment:y>0.6",  # alignment:y = -alignment:x
    "alignment:x; alignment:x>0.8; alignment:45deg>0.8",  # (0.8, 0.8) is outside the disc
])
def test_constraints_no_mould_can_meet_are_refused(spec):
    with pytest.raises(InfeasibleConstraintError, match="no|contradict"):
        parse_objective(spec)


@pytest.mark.parametrize("spec", [
    "alignment:x; alignment:x>0.3; alignment:45deg>0.3",  # (0.3, 0.3) is inside the disc
    "alignment:x; alignment:x>0.5; alignment:x@left<0.1",  # different regions
    "alignment:x; max_tension>0.1; max_tension<0.2",
])
def test_compatible_constraints_are_accepted(spec):
    assert isinstance(parse_objective(spec), Objective)


def test_errors_are_value_errors_with_one_base_class():
    for error in (UnknownObjectiveError, EmptyRegionError, InfeasibleConstraintError):
        assert issubclass(error, ObjectiveError) and issubclass(error, ValueError)
