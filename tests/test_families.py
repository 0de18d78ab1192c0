"""A predictor scored family by family (condor.studies.families), and a prediction checked by
simulation (condor.stages.check)."""

import dataclasses
import math

import numpy as np
import pytest

from condor.data.fields import cell_fields, normalise
from condor.data.seeds import replica_seed
from condor.model.scenes import get_scene
from condor.moulds.lab import lab_mould
from condor.stages.build import simulate_mould
from condor.stages.check import (AUTO, AUTO_CHECK, AUTO_CHECK_MAX_CELLS, CHECK_SEED,
                                 best_estimate, check_count, check_prediction)
from condor.studies.families import family_rows, mean_tension
from condor.studies.recipes import Ensemble
from condor.surrogate.answer import statistics


def _ensemble(truth, sigma, replicas, rng):
    """Replicas (M, R, 8, H, W) drawn about `truth` with noise sigma, as raw fields whose N_c
    is the density sum (normalising them leaves them as they are when sum P = H * W)."""
    m = truth.shape[0]
    raw = truth[:, None] + sigma * rng.standard_normal((m, replicas) + truth.shape[1:])
    n_cells = np.full(m, float(truth.shape[-1] * truth.shape[-2]))
    return Ensemble(moulds=np.arange(m), raw=raw, n_cells=n_cells,
                    inputs=np.ones((m, 2, *truth.shape[-2:]), np.uint8), pixel_size=1.0,
                    seconds=np.ones((m, replicas)), energy_per_cell=np.ones((m, replicas)))


def test_family_rows_against_draws_with_known_answers():
    """Synthetic replicas about known expected fields: a prediction equal to them scores ~0
    with the noise removed (plain error ~ sigma / sqrt R); the ceiling is sigma; a prediction
    whose T is 10% high has a tension bias of +10% exactly."""
    rng = np.random.default_rng(0)
    h = 16
    truth = np.ones((12, 8, h, h))
    truth[:, 1] = rng.uniform(0.5, 1.5, size=(12, 1, 1))  # the tension field
    sigma = 0.05
    ensemble = _ensemble(truth, sigma, 8, rng)
    families = ["a"] * 6 + ["b"] * 6
    exact = family_rows(ensemble, truth, families)
    assert list(exact["family"]) == ["a", "b"] and list(exact["n_moulds"]) == [6, 6]
    assert exact["error"].max() < 0.2 * sigma
    assert exact["noise_ceiling"].to_numpy() == pytest.approx([sigma, sigma], rel=0.1)
    assert np.all(np.abs(exact["tension_bias"]) < 0.01)
    high = truth.copy()
    high[:, 1] *= 1.1
    biased = family_rows(ensemble, high, families)
    # the predicted P sums are exact, the expected's carry the replicas' noise (tiny)
    assert biased["tension_bias"].to_numpy() == pytest.approx([0.1, 0.1], abs=0.005)
    assert mean_tension(high[0]) == pytest.approx(1.1 * mean_tension(truth[0]))
    with pytest.raises(ValueError, match="family labels"):
        family_rows(ensemble, truth, families[:-1])


def test_a_check_scores_the_prediction_against_the_same_simulations_run_directly():
    """check_prediction's replicas are the seeds replica_seed(CHECK_SEED, 0, k): simulated here
    directly, their mean fields as the 'prediction' lie at distance 0 (noise removed), and each
    statistic's simulated mean and sd are the replicas' own."""
    scene = get_scene("tiny")
    mould = lab_mould(1, 2, "strip", scene)
    fields, stats = [], []
    for k in range(3):
        r = simulate_mould(mould, scene, None, None, replica_seed(CHECK_SEED, 0, k))
        f = normalise(cell_fields(r.positions, r.orientations, r.tension, scene.box,
                                  scene.pixels, scene.sigma), len(r.positions))
        fields.append(f)
        stats.append(statistics(f, len(r.positions), scene.pixel_size))
    mean = np.mean(fields, axis=0)
    lines = []
    check = check_prediction(mould, scene, mean, len(r.positions), 3, say=lines.append)
    assert check.n == 3 and len(lines) == 3 and not check.failed
    assert check.error == 0.0 and check.ceiling > 0 and check.ratio == 0.0
    # what predict writes beside the prediction: the replicas' mean, normalised and raw
    np.testing.assert_allclose(check.simulated_normalised, mean, rtol=1e-5, atol=1e-7)
    assert check.simulated[0].sum() == pytest.approx(len(r.positions), rel=1e-4)  # sum P = N_c
    np.testing.assert_allclose(check.simulated * scene.pixels ** 2 / len(r.positions), mean,
                               rtol=1e-4, atol=1e-6)
    assert check.attributes()["simulations"] == 3 and not check.automatic
    # the replicas' own mean as the prediction: no error, so it keeps all the weight
    assert check.weight == 1.0 and check.tension_weight == 1.0
    np.testing.assert_allclose(check.best_normalised, mean, rtol=1e-5, atol=1e-7)
    tension = check.table.set_index("statistic").loc["mean_tension"]
    assert tension.simulated == pytest.approx(np.mean([s["mean_tension"] for s in stats]))
    assert tension.simulated_sd == pytest.approx(np.std([s["mean_tension"] for s in stats],
                                                        ddof=1))
    one = check_prediction(mould, scene, fields[0], len(r.positions), 3)
    assert one.error > 0.5 * one.ceiling  # one of the replicas is no closer than one simulation
    assert "checked by 3 simulations" in one.lines()[0]
    with pytest.raises(ValueError, match="--check 1: .* at least 2"):
        check_prediction(mould, scene, mean, len(r.positions), 1)


def test_predict_checks_by_default_only_where_simulations_are_cheap():
    """`--check auto` (predict's default) runs AUTO_CHECK simulations for a mould of at most
    AUTO_CHECK_MAX_CELLS cells in a scene that can be simulated, none otherwise; a number is
    taken as given, anything else refused naming the flag."""
    default, paper = get_scene("default"), get_scene("paper")
    assert check_count(AUTO, 1500.0, default) == AUTO_CHECK >= 3
    assert check_count(AUTO, AUTO_CHECK_MAX_CELLS + 1.0, paper) == 0
    assert check_count(AUTO, 1500.0, dataclasses.replace(default, depth=math.nan)) == 0
    assert check_count(0, 1500.0, default) == 0 and check_count(7, 1e5, paper) == 7
    for bad in (-1, 2.5, "all", True):
        with pytest.raises(ValueError, match="--check"):
            check_count(bad, 1500.0, default)


def test_the_best_estimate_weighs_prediction_and_simulations_by_their_errors():
    """Synthetic draws with a known truth: replicas = truth + noise sigma, a prediction off by
    a known amount. best_estimate's weight is the prediction's share the known errors give,
    (sigma^2 / N) / (b^2 + sigma^2 / N), within the draws' chance, for the tension and for the
    other fields alike; over many draws its squared error against the truth is below both the
    prediction's and the replicas' mean's. A prediction exact in all but its tension keeps its
    weight in the other fields and loses it in the tension, whose values are tiny beside
    theirs (the normalised T of a simulation)."""
    rng = np.random.default_rng(7)
    truth = rng.uniform(0, 1, (8, 16, 16))
    sigma, n = 0.2, 4
    for bias in (0.05, 0.1, 0.4):
        expected_weight = (sigma ** 2 / n) / (bias ** 2 + sigma ** 2 / n)
        weights, errors = [], {"best": [], "prediction": [], "mean": []}
        for _ in range(40):
            reps = truth + rng.normal(0, sigma, (n,) + truth.shape)
            predicted = truth + bias * rng.choice([-1.0, 1.0], truth.shape)
            best, weight = best_estimate(predicted, reps)
            assert weight.shape == (8,) and np.all(weight[2:] == weight[0])
            weights.append(weight[:2])
            for name, f in (("best", best), ("prediction", predicted), ("mean", reps.mean(0))):
                errors[name].append(np.mean((f - truth) ** 2))
        np.testing.assert_allclose(np.median(weights, axis=0), expected_weight, atol=0.05)
        mse = {k: np.mean(v) for k, v in errors.items()}
        assert mse["best"] < min(mse["prediction"], mse["mean"])
    exact, weight = best_estimate(truth, truth + rng.normal(0, sigma, (n,) + truth.shape))
    assert np.all(weight > 0.9)  # a prediction at the truth keeps (nearly) all the weight
    small = truth.copy()
    small[1] *= 1e-3  # T: tiny values with a noise of about 1% of them (sd 2e-6 a pixel)
    reps = small + rng.normal(0, sigma, (n,) + small.shape) * np.where(
        np.arange(8) == 1, 1e-5, 1.0)[:, None, None]
    off = small.copy()
    off[1] *= 1.3  # 30% off in tension alone: far beyond its noise, nothing beside P's
    best, weight = best_estimate(off, reps)
    assert weight[1] < 0.05 and weight[0] > 0.95
    assert abs(best[1].sum() / small[1].sum() - 1) < 0.02  # the replicas' tension, not 30% off


def test_a_checks_verdict_reads_the_bin_its_ratio_falls_in_and_flags_at_the_threshold(tmp_path):
    """with_verdict against a check_verdict finding written here: the line quotes the counts of
    the bin the check's ratio falls in ([lo, hi): an edge belongs to the bin above it), the mould
    is flagged at or above the threshold and not below it, and a check of another number of
    simulations than the finding's is left as it was."""
    import pandas as pd

    from condor.findings import load_findings, record_finding
    from condor.stages.check import Check, with_verdict

    path = tmp_path / "findings.json"
    path.write_text("{}")
    table = pd.DataFrame({"ratio_lo": [0.0, 0.8, 1.0], "ratio_hi": [0.8, 1.0, math.inf],
                          "n_moulds": [30, 10, 20], "n_above": [1, 4, 18],
                          "share_above": [1 / 30, 0.4, 0.9]})
    record_finding("check_verdict", {"question": "q", "table": "check_verdict.csv",
                                     "experiment": "experiments/check_verdict", "source": "s",
                                     "commit": "abc", "values": {"threshold": 0.8, "n_check": 4}},
                   table, path=path)
    finding = load_findings(path)["check_verdict"]

    def checked(ratio, n=4):
        return with_verdict(Check(n=n, error=ratio, ceiling=1.0, table=pd.DataFrame(),
                                  failed=[], seconds=0.0), finding)

    low, edge, mid, off = checked(0.5), checked(0.8), checked(0.95), checked(1.3)
    assert (low.flagged, edge.flagged, mid.flagged, off.flagged) == (False, True, True, True)
    assert "of 30 moulds whose check of 4 read 0-0.8x, 1 lay above" in low.verdict
    assert "MAY be off" not in low.verdict
    assert "MAY be off" in edge.verdict and "of 10 moulds" in edge.verdict
    assert "MAY be off" in mid.verdict and "4 lay above" in mid.verdict
    assert "read 1x and above, 18 lay above" in off.verdict and "MAY" not in off.verdict
    lines = off.lines()
    assert any("is off on this mould" in line for line in lines) and lines[-1].strip() == off.verdict
    assert off.attributes()["flagged"] is True
    other = checked(1.3, n=6)
    assert other.verdict is None and other.flagged is None
    with pytest.raises(ValueError, match="lacks the values"):
        record_finding("check_verdict", {"question": "q", "table": "check_verdict.csv",
                                         "experiment": "e", "source": "s", "commit": "abc",
                                         "values": {"threshold": 0.8}}, table, path=path)
        load_findings(path)


def test_the_check_threshold_is_the_highest_bin_edge_that_catches_nine_in_ten():
    """experiments/check_verdict/calibrate.py on synthetic checks (the truth's ratio read with
    noise): its threshold equals a brute-force search over the bins' inner edges, its rates are
    the counts, and its bins hold every mould once."""
    import runpy
    from pathlib import Path

    import pandas as pd

    study = runpy.run_path(str(Path(__file__).resolve().parents[1] / "experiments" /
                               "check_verdict" / "calibrate.py"))
    rng = np.random.default_rng(3)
    truth = rng.lognormal(-0.2, 0.5, 300)
    table = pd.DataFrame({"truth_ratio": truth,
                          "check_ratio": truth * rng.lognormal(0.0, 0.2, truth.size)})
    above = truth > 1
    passing = [t for t in study["EDGES"][1:-1]
               if (table.check_ratio[above] >= t).mean() >= study["CATCH"]]
    t = study["threshold"](table)
    assert t == max(passing)
    caught, false_alarms = study["rates"](table, t)
    assert caught == pytest.approx(np.mean(table.check_ratio[above] >= t))
    assert false_alarms == pytest.approx(np.mean(table.check_ratio[~above] >= t))
    bins = study["bins"](table)
    assert bins.n_moulds.sum() == len(table) and bins.n_above.sum() == above.sum()
    held = study["held_out_rates"](table, splits=20)
    assert held.shape == (40, 2) and np.median(held[:, 0]) > 0.8


def test_where_errors_classes_pixels_by_their_l1_distance_to_posts_and_outside(monkeypatch):
    """experiments/generalisation/where_errors.py's pixel classes against a brute-force L1
    distance (its dilations use the 4-connected cross) on a square mould with one post."""
    import runpy
    from pathlib import Path

    folder = Path(__file__).resolve().parents[1] / "experiments" / "generalisation"
    monkeypatch.syspath_prepend(str(folder))
    study = runpy.run_path(str(folder / "where_errors.py"))
    n = 24
    mobile, fixed = np.zeros((n, n)), np.zeros((n, n))
    mobile[3:20, 2:21] = 1.0
    fixed[10:12, 8:10], mobile[10:12, 8:10] = 1.0, 0.0
    classes = study["pixel_classes"](np.stack([mobile, fixed])[None])[0]
    names = study["CLASSES"]
    yy, xx = np.mgrid[:n, :n]

    def l1_to(mask):
        ys, xs = np.nonzero(mask)
        return np.min(np.abs(yy[..., None] - ys) + np.abs(xx[..., None] - xs), axis=-1)

    cells, post = (mobile + fixed) > 0, fixed > 0
    near_post = (l1_to(post) <= study["RING"]) & ~post
    near_out = (l1_to(~cells) <= study["RING"]) & cells & ~post & ~near_post
    expected = np.where(~cells, "outside", np.where(post, "post", np.where(
        near_post, "beside_post", np.where(near_out, "edge", "inside"))))
    assert (np.array(names)[classes] == expected).all()
    assert {"post", "beside_post", "edge", "inside", "outside"} == set(expected.ravel())
