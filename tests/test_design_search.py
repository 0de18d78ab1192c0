"""The CMA-ES search with an analytic predictor of known optimum (condor.design.search)."""

import numpy as np
import pytest

from condor.design.analytic import AnalyticPredictor, raster_order
from condor.design.objectives import EmptyRegionError, parse_objective
from condor.design.search import (DesignSearchError, objective_spread, predict_designs,
                                  prediction_spread, search_designs)
from condor.design.space import DesignSpace, default_space
from condor.moulds.mould import input_channels
from condor.model.scenes import get_scene

SCENE = get_scene("tiny")  # 15.6 l0 box, 32 px: cheap geometry and rasters


@pytest.fixture(scope="module")
def alignment_search():
    objective = parse_objective("alignment:x")
    space = default_space(SCENE, objective, n_tethers=2, symmetry="none")
    predictor = AnalyticPredictor(SCENE.pixels, SCENE.box)
    return objective, space, predictor, search_designs(objective, space, predictor, budget=480, seed=3,
                                               progress=False)


def test_analytic_predictor_alignment_is_the_raster_anisotropy():
    space = DesignSpace.from_scene(SCENE, symmetry="none")
    moulds = [space.mould(x) for x in space.random_vectors(np.random.default_rng(0), 6)]
    inputs = np.stack([input_channels(m, SCENE.pixels) for m in moulds])
    fields = AnalyticPredictor(SCENE.pixels, SCENE.box)(inputs).normalised
    a, b = raster_order(inputs)
    assert np.allclose(parse_objective("alignment:x").evaluate(fields)["objective"], a)
    assert np.allclose(parse_objective("alignment:45deg").evaluate(fields)["objective"], b)


def test_search_improves_the_objective_towards_the_known_optimum(alignment_search):
    objective, space, predictor, result = alignment_search
    probe = result.designs[result.designs["generation"] == 0]
    best = result.designs.iloc[0]
    assert best["rank"] == 1 and best["design"] not in set(probe["design"])
    # Better than random search with the same budget, and near the limit set by the extent
    # rule (a 0.9 x 0.44 box rectangle has a = 0.61; smooth dumbbells a little more).
    rng = np.random.default_rng(99)
    random_moulds = [space.mould(x) for x in space.random_vectors(rng, result.evaluations)]
    random_best = raster_order(np.stack([input_channels(m, SCENE.pixels)
                                         for m in random_moulds]))[0].max()
    assert best["objective"] > random_best + 0.05
    assert best["objective"] > 0.5
    # the table's objective is the objective of the mould it names
    mould = result.mould(best["design"])
    a, _ = raster_order(input_channels(mould, SCENE.pixels)[None])
    assert a[0] == pytest.approx(best["objective"])
    assert result.evaluations == 480 and len(result.designs) == 480
    assert result.history["best_score"].is_monotonic_increasing


def test_search_is_deterministic_for_a_seed_and_leaves_numpy_global_state_alone():
    objective = parse_objective("alignment:x")
    space = default_space(SCENE, objective, n_tethers=2)
    predictor = AnalyticPredictor(SCENE.pixels, SCENE.box)
    first = search_designs(objective, space, predictor, budget=60, popsize=8, seed=3, progress=False)
    np.random.seed(123)
    before = np.random.get_state()[1].copy()
    again = search_designs(objective, space, predictor, budget=60, popsize=8, seed=3, progress=False)
    assert np.array_equal(np.random.get_state()[1], before)
    assert np.array_equal(again.vectors, first.vectors)
    assert again.designs.equals(first.designs)
    other = search_designs(objective, space, predictor, budget=60, popsize=8, seed=4, progress=False)
    assert not np.array_equal(other.vectors, first.vectors)


def test_ranked_designs_are_distinct_and_sorted(alignment_search):
    result = alignment_search[3]
    ranked = result.ranked()
    assert ranked["raster"].is_unique
    assert ranked["score"].is_monotonic_decreasing
    assert result.n_predicted == result.designs["raster"].nunique()  # repeats predicted once


def test_a_constraint_keeps_the_best_design_feasible():
    objective = parse_objective("alignment:x; alignment:x<0.3")
    space = default_space(SCENE, objective, n_tethers=1)
    result = search_designs(objective, space, AnalyticPredictor(SCENE.pixels, SCENE.box), budget=160,
                    seed=0, progress=False)
    best = result.designs.iloc[0]
    assert best["feasible"] and 0.2 < best["objective"] <= 0.3


def test_bad_setups_fail_before_any_prediction():
    predictor = AnalyticPredictor(SCENE.pixels, SCENE.box)
    space = DesignSpace.from_scene(SCENE)
    with pytest.raises(EmptyRegionError):
        search_designs(parse_objective("uniformity@rect(0,0.04,0,1)"), space, predictor, budget=10)
    with pytest.raises(DesignSearchError, match="31.25 l0 box"):
        search_designs(parse_objective("uniformity"), space, AnalyticPredictor(64, 31.25), budget=10)
    with pytest.raises(DesignSearchError, match="budget"):
        search_designs(parse_objective("uniformity"), space, predictor, budget=1)
    assert predictor.calls == 0


def test_progress_bar_only_when_asked(capsys):
    objective = parse_objective("uniformity")
    space = DesignSpace.from_scene(SCENE, n_tethers=1)
    predictor = AnalyticPredictor(SCENE.pixels, SCENE.box)
    search_designs(objective, space, predictor, budget=20, popsize=8, progress=False)
    assert capsys.readouterr().err == ""
    search_designs(objective, space, predictor, budget=20, popsize=8, progress=True)
    assert "design uniformity" in capsys.readouterr().err


class SpreadPredictor(AnalyticPredictor):
    """The analytic predictor with a reproducibility map (`spread`, raw units)."""

    def __init__(self, *args, level=0.0, **kwargs):
        super().__init__(*args, **kwargs)
        self.level = level

    def __call__(self, inputs):
        prediction = super().__call__(inputs)
        prediction.spread = self.level * np.abs(prediction.raw)
        return prediction


def test_predict_designs_reports_the_objective_and_its_spread_when_there_is_a_map():
    space = DesignSpace.from_scene(SCENE)
    moulds = [space.mould(x, i) for i, x in
              enumerate(space.random_vectors(np.random.default_rng(1), 3))]
    objective = parse_objective("alignment:x")
    plain = predict_designs(objective, moulds, AnalyticPredictor(SCENE.pixels, SCENE.box))
    assert plain.spread is None and plain.table["predicted_spread"].isna().all()
    assert plain.table["mould_id"].tolist() == [0, 1, 2]
    small = predict_designs(objective, moulds, SpreadPredictor(SCENE.pixels, SCENE.box, level=0.01))
    large = predict_designs(objective, moulds, SpreadPredictor(SCENE.pixels, SCENE.box, level=0.1))
    assert np.allclose(small.table["objective"], plain.table["objective"])
    # the spread is in normalised units and the objective's spread grows with the map
    assert np.allclose(small.spread, 0.01 * np.abs(small.normalised))
    assert (large.table["predicted_spread"] > 5 * small.table["predicted_spread"]).all()
    assert (small.table["predicted_spread"] > 0).all()


def test_objective_spread_matches_a_linear_objective_with_uniform_noise():
    """mean_tension is linear in T at fixed P (noise on P is second order here): its spread is
    positive and doubles with the map."""
    fields = np.zeros((1, 8, 32, 32))
    fields[0, 0, 8:24, 8:24] = 4.0
    fields[0, 1, 8:24, 8:24] = 0.1
    objective = parse_objective("mean_tension")
    one = objective_spread(objective, fields, np.full_like(fields, 0.01), 1.5, draws=200)
    two = objective_spread(objective, fields, np.full_like(fields, 0.02), 1.5, draws=200)
    assert one[0] > 0 and two[0] == pytest.approx(2 * one[0], rel=0.2)


def test_prediction_spread_prefers_a_normalised_map():
    class P:
        raw = np.ones((1, 8, 4, 4))
        n_cells = np.array([8.0])
        spread = np.ones((1, 8, 4, 4))
    assert np.allclose(prediction_spread(P()), 2.0)  # 16 px / 8 cells
    P.spread_normalised = np.full((1, 8, 4, 4), 0.5)
    assert np.allclose(prediction_spread(P()), 0.5)


def test_the_search_reports_a_spread_only_when_the_surrogate_has_a_map():
    objective = parse_objective("alignment:x")
    space = DesignSpace.from_scene(SCENE, n_tethers=1)
    plain = search_designs(objective, space, AnalyticPredictor(SCENE.pixels, SCENE.box), budget=20,
                   popsize=8, progress=False)
    assert "predicted_spread" not in plain.designs
    spread = search_designs(objective, space, SpreadPredictor(SCENE.pixels, SCENE.box, level=0.05),
                    budget=20, popsize=8, progress=False)
    assert (spread.designs["predicted_spread"] > 0).all()
    assert np.allclose(spread.designs.sort_values("design")["objective"],
                       plain.designs.sort_values("design")["objective"])


class CellPredictor(AnalyticPredictor):
    """The analytic predictor that also takes each mould's N_c (as Predictor does), from
    `cells(mould)`, and records the N_c it was asked for."""

    def __init__(self, *args, cells, **kwargs):
        super().__init__(*args, **kwargs)
        self.cells, self.seen = cells, []

    def mould_arguments(self, moulds):
        return {"n_cells": np.array([self.cells(m) for m in moulds], np.float64)}

    def __call__(self, inputs, n_cells=None):
        self.seen += list(n_cells)
        return super().__call__(inputs)


@pytest.mark.parametrize("depends_on_design", [False, True])
def test_the_cache_tells_designs_apart_by_everything_the_surrogate_reads(depends_on_design):
    """The same vector twice gives the same masks; it is predicted once when the surrogate's
    other inputs (N_c here) agree and twice when they differ (the mould id stands in for a
    sub-pixel difference in the cells)."""
    from condor.design.search import _Evaluator

    objective = parse_objective("alignment:x")
    space = default_space(SCENE, objective, n_tethers=2, symmetry="none")
    predictor = CellPredictor(SCENE.pixels, SCENE.box,
                              cells=(lambda m: 100.0 + m.mould_id) if depends_on_design
                              else (lambda m: 100.0))
    evaluate = _Evaluator(objective, space, predictor, SCENE.pixels, penalty=10.0,
                          repair_weight=0.05, seed=0)
    x = np.full(space.dim, 0.1)
    scores = evaluate(np.stack([x, x]), generation=0, restart=0)
    masks = [input_channels(space.decode(x, mould_id=k, seed=0).mould, SCENE.pixels)
             for k in range(2)]
    np.testing.assert_array_equal(masks[0], masks[1])
    assert evaluate.n_predicted == (2 if depends_on_design else 1)
    assert predictor.seen == ([100.0, 101.0] if depends_on_design else [100.0])
    assert np.all(np.isfinite(scores))


@pytest.mark.parametrize("spec, statistic", [
    ("alignment:x", "alignment_x"), ("alignment:y", "alignment_x"),
    ("-alignment:90deg", "alignment_x"), ("alignment:x; max_tension<0.5", "alignment_x"),
    ("mean_tension", "mean_tension"), ("-mean_tension", "mean_tension"),
    ("alignment:45deg", None), ("alignment:x@centre", None), ("mean_tension@centre", None),
    ("alignment:x+0.5*uniformity", None), ("max_tension", None), ("uniformity", None)])
def test_calibrated_statistic_names_the_whole_mould_statistic_the_objective_equals(spec,
                                                                                  statistic):
    from condor.design.search import calibrated_statistic

    assert calibrated_statistic(parse_objective(spec)) == statistic


def test_the_calibrated_objectives_are_multiples_of_their_statistics():
    """The premise of calibrated_statistic: on random fields, alignment:x and alignment:y are
    +-1 x condor.surrogate.answer's alignment_x, and mean_tension its mean_tension."""
    from condor.design.search import calibrated_statistic
    from condor.surrogate.answer import statistics

    rng = np.random.default_rng(5)
    fields = rng.uniform(0.0, 1.0, (3, 8, 16, 16))
    for spec, sign in (("alignment:x", 1), ("alignment:y", -1), ("mean_tension", 1),
                       ("-mean_tension", -1)):
        objective = parse_objective(spec)
        values = objective.evaluate(fields)["objective"].to_numpy()
        name = calibrated_statistic(objective)
        expected = [statistics(f, 100.0, 1.0)[name] for f in fields]
        assert np.allclose(values, sign * np.asarray(expected)), spec


def test_design_spread_factor_is_the_findings_factor_of_the_statistic():
    import torch

    from condor.findings import load_findings
    from condor.stages.design import objective_spread_factor

    table = load_findings()["spread_calibration"].frame().set_index("statistic")["factor"]
    other = type("P", (), {"state": {"generator": {"w": torch.zeros(3)}}})()  # not the fitted net
    factor, line = objective_spread_factor(parse_objective("alignment:y"), other)
    assert factor == pytest.approx(table["alignment_x"]) and "calibrated" in line
    assert "warning" in line  # fitted for another checkpoint
    factor, line = objective_spread_factor(parse_objective("-mean_tension"), other)
    assert factor == pytest.approx(table["mean_tension"])
    factor, line = objective_spread_factor(parse_objective("uniformity"), other)
    assert factor == 1.0 and "uncalibrated" in line
