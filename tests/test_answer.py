"""condor.surrogate.answer's domain verdict: where a mould sits against the training moulds and,
outside, what the out-of-domain study measured for its counts, read from a findings table
(never from numbers in the code)."""

from __future__ import annotations

import json

import numpy as np
import pandas as pd
import pytest
from shapely.geometry import box as shapely_box

from condor import findings
from condor.moulds.place import place_mould
from condor.moulds.paper import generate_mould
from condor.model.scenes import get_scene
from condor.surrogate.answer import domain_table, domain_verdict

SCENE = get_scene("tiny")
AREA, TETHERS = "area / box area", "tethers"


def _row(kind, outside_on, description, n, k, z, coverage):
    return {"kind": kind, "outside_on": outside_on, "description": description, "n_moulds": n,
            "replicas": 4, "z": z, "z_lo": z / 2, "z_hi": z * 2, "spread_ratio": k,
            "spread_ratio_lo": k - 0.3, "spread_ratio_hi": k + 0.5, "coverage_90": coverage,
            "coverage_90_lo": coverage - 0.1, "coverage_90_hi": coverage + 0.05,
            "field_error": 0.2, "field_error_lo": 0.1, "field_error_hi": 0.3,
            "noise_ceiling": 0.15}


def _verdict(tmp_path, table, rows):
    """domain_verdict of `table` against a findings.json whose out_of_domain table holds
    `rows`, read by the findings loader as `condor predict` reads the shipped one."""
    pd.DataFrame(rows).to_csv(tmp_path / "ood.csv", index=False)
    (tmp_path / "findings.json").write_text(json.dumps({"out_of_domain": {
        "question": "q", "table": "ood.csv", "experiment": "experiments/out_of_domain",
        "source": "experiments/out_of_domain/out_of_domain_tiny.csv", "commit": "abc1234"}}))
    finding = findings.load_findings(tmp_path / "findings.json")["out_of_domain"]
    return domain_verdict(table, finding.frame(), f"{finding.experiment} at {finding.commit}")


ROWS = [_row("inside", "", "inside moulds", 8, 1.1, 0.4, 0.88),
        _row("area", AREA, "moulds of another area", 5, 1.7, 1.3, 0.71),
        _row("dogbone", f"{AREA}; {TETHERS}", "dog-bones", 3, 2.5, 3.1, 0.52)]


def _two_post_mould():
    """A small bar with two posts: outside on the area and on the tether count."""
    return place_mould(shapely_box(0, 0, 9, 3), np.array([[1.5, 1.5, 0.5], [7.5, 1.5, 0.5]]),
                       SCENE)


def test_a_mould_outside_on_two_counts_reads_each_counts_measured_row(tmp_path):
    table = domain_table(_two_post_mould(), SCENE)
    assert list(table.loc[~table["inside"], "property"]) == [AREA, TETHERS]
    verdict = _verdict(tmp_path, table, ROWS)
    assert verdict.startswith("OUTSIDE the training domain on 2 of 5 counts")
    assert "(experiments/out_of_domain at abc1234; medians over moulds, 95% intervals)" in verdict
    assert (f"{AREA}: 5 moulds of another area: the statistics are off by 1.3 [0.65, 2.6] of "
            "their predicted spreads, one simulation scatters 1.7x [1.4, 2.2] the predicted "
            "spread, the 90% intervals hold 71% [61%, 76%] of the simulated pixels") in verdict
    assert f"{TETHERS}: not measured" in verdict  # no group outside on the tether count alone
    assert f"{AREA} and {TETHERS} together: 3 dog-bones: the statistics are off by 3.1" in verdict
    assert "Inside it, on 8 inside moulds: the statistics are off by 0.4" in verdict
    assert verdict.endswith("Simulate it (condor simulate) to be sure")


def test_a_group_outside_on_one_count_answers_for_that_count(tmp_path):
    rows = ROWS + [_row("tethers", TETHERS, "moulds with 1-3 tethers", 6, 1.3, 0.9, 0.8)]
    verdict = _verdict(tmp_path, domain_table(_two_post_mould(), SCENE), rows)
    assert (f"{TETHERS}: 6 moulds with 1-3 tethers: the statistics are off by 0.9 [0.45, 1.8] "
            "of their predicted spreads, one simulation scatters 1.3x [1, 1.8]") in verdict
    assert "not measured" not in verdict


def test_per_statistic_columns_name_the_statistics_whose_spreads_err_most(tmp_path):
    rows = [dict(r) for r in ROWS]
    rows[1].update({"z_alignment": 4.5, "z_mean_tension": 0.5, "spread_ratio_alignment": 2.5,
                    "spread_ratio_mean_tension": 0.25})
    verdict = _verdict(tmp_path, domain_table(_two_post_mould(), SCENE), rows)
    assert ("5 moulds of another area: the statistics are off by 1.3 [0.65, 2.6] of their "
            "predicted spreads (the most, alignment, by 4.5), one simulation scatters 1.7x "
            "[1.4, 2.2] the predicted spread (from 0.25x for mean_tension to 2.5x for "
            "alignment)") in verdict


def test_a_mould_inside_the_domain_needs_no_measurement():
    mould = generate_mould(7, 3, SCENE)
    table = domain_table(mould, SCENE)
    if not table["inside"].all():
        pytest.skip("this generated mould has a tether the tiny grid misses")
    assert domain_verdict(table).startswith("inside the training domain on all 5")


def test_without_a_measurement_the_verdict_says_so():
    verdict = domain_verdict(domain_table(_two_post_mould(), SCENE))
    assert "Not measured out of the domain. Simulate it" in verdict


def test_the_shipped_table_answers_for_each_count_of_a_two_post_mould():
    finding = findings.load_findings()["out_of_domain"]
    frame = finding.frame()
    verdict = domain_verdict(domain_table(_two_post_mould(), SCENE), frame,
                             f"{finding.experiment} at {finding.commit}")
    assert f"experiments/out_of_domain at {finding.commit}" in verdict
    inside = frame.set_index("kind").loc["inside"]
    assert f"Inside it, on {int(inside['n_moulds'])} {inside['description']}" in verdict
    for count in (AREA, TETHERS):
        assert f"{count}: not measured" not in verdict


# --- the statistics' spreads and their calibration ---------------------------------------------

from condor.surrogate.answer import (SPREAD_STATISTICS, check_spread_factors,  # noqa: E402
                                     mould_summary, spread_calibration, spread_factors,
                                     statistics)
from condor.surrogate.calibration import statistic_spread_ratio  # noqa: E402

N_PX, SIGMA_PX, PIXEL = 24, 1.5, 0.5


def _disc(tension: float) -> np.ndarray:
    """Normalised fields (8, N_PX, N_PX) of a disc of uniform density whose cells all carry
    `tension` and lie along x: its mean tension is exactly `tension`. Its edge is blurred,
    so that the density crosses the tissue area's threshold smoothly."""
    from condor.surrogate.baselines import gaussian_blur

    y, x = np.mgrid[:N_PX, :N_PX] - (N_PX - 1) / 2
    density = gaussian_blur((np.hypot(x, y) < 8).astype(float), SIGMA_PX)
    density *= density.size / density.sum()
    fields = np.zeros((8, N_PX, N_PX))
    fields[0], fields[1] = density, tension * density
    fields[2], fields[3], fields[4] = 0.6 * density, 0.3 * density, 0.1 * density
    return fields


def test_the_ratio_of_scatter_to_spread_recovers_a_known_factor_from_three_replicas():
    rng = np.random.default_rng(5)
    k = 2.5
    sigma = rng.uniform(0.5, 3.0, 400)  # each mould's true scatter; its spread k times too small
    s = rng.normal(0.0, sigma[:, None], (400, 3)).std(axis=1, ddof=1)
    ratio, lo, hi = statistic_spread_ratio(s, sigma / k)
    assert lo < k < hi and ratio == pytest.approx(k, rel=0.06)
    # the median of s / spread, biased low with 3 replicas (by sqrt(ln 2) for Gaussians), is not
    assert np.median(s * k / sigma) < 0.9 * k


def test_a_factor_fitted_on_replicas_makes_the_drawn_spread_one_simulations_scatter():
    """Replicas whose mean tension scatters by a known sigma; a spread map (on T alone) whose
    draws scatter the mean tension by another amount, proportional to sigma over moulds. The
    factor fitted on 150 moulds x 4 replicas makes a new mould's spread its sigma."""
    rng = np.random.default_rng(11)
    unit = dict.fromkeys(SPREAD_STATISTICS, 1.0)
    s, drawn = [], []
    for sigma in rng.uniform(0.002, 0.02, 150):
        replicas = [_disc(t) for t in 0.05 + rng.normal(0.0, sigma, 4)]
        s.append(np.std([statistics(f, 400, PIXEL)["mean_tension"] for f in replicas], ddof=1))
        spread = np.zeros((8, N_PX, N_PX))
        spread[1] = 10 * sigma * replicas[0][0]  # the wrong size: not sigma's
        table = mould_summary(np.mean(replicas, axis=0), 400, PIXEL, spread, sigma_px=SIGMA_PX,
                              factors=unit).set_index("statistic")
        drawn.append(table.loc["mean_tension", "spread"])
    factor = statistic_spread_ratio(s, drawn)[0]
    assert factor < 0.5  # the draws alone scatter more than twice sigma
    sigma = 0.01
    spread = np.zeros((8, N_PX, N_PX))
    spread[1] = 10 * sigma * _disc(0.05)[0]
    calibrated = mould_summary(_disc(0.05), 400, PIXEL, spread, sigma_px=SIGMA_PX,
                               factors={**unit, "mean_tension": factor}).set_index("statistic")
    assert calibrated.loc["mean_tension", "spread"] == pytest.approx(sigma, rel=0.12)


def test_factors_scale_each_statistics_drawn_spread_and_the_area_in_mm2_by_the_areas():
    rng = np.random.default_rng(2)
    fields = _disc(0.05)
    fields[5] = 0.1 * fields[0]  # a tilted direction
    spread = 0.05 * np.abs(fields) + 0.01 * rng.random(fields.shape)
    factors = dict(zip(SPREAD_STATISTICS, (0.5, 2.0, 3.0, 0.25, 0.4)))
    plain = mould_summary(fields, 400, PIXEL, spread, sigma_px=SIGMA_PX, l0_um=20,
                          factors=None).set_index("statistic")["spread"]
    scaled = mould_summary(fields, 400, PIXEL, spread, sigma_px=SIGMA_PX, l0_um=20,
                           factors=factors).set_index("statistic")["spread"]
    for name, k in factors.items():
        assert plain[name] > 0 and scaled[name] == pytest.approx(k * plain[name])
    assert scaled["tissue_area_mm2"] == pytest.approx(0.4 * plain["tissue_area_mm2"])
    assert np.isnan(scaled["reproducibility"])


@pytest.mark.parametrize("factors, words", [
    ({"alignment": 1.0}, "missing"),
    ({**dict.fromkeys(SPREAD_STATISTICS, 1.0), "area": 2.0}, "unknown \\['area'\\]"),
    ({**dict.fromkeys(SPREAD_STATISTICS, 1.0), "mean_tension": 0.0}, "mean_tension.*> 0, got 0"),
    ({**dict.fromkeys(SPREAD_STATISTICS, 1.0), "direction": float("nan")}, "direction"),
    ({**dict.fromkeys(SPREAD_STATISTICS, 1.0), "alignment": "x"}, "alignment must be a number"),
])
def test_bad_spread_factors_are_refused_by_name(factors, words):
    with pytest.raises(ValueError, match=words):
        check_spread_factors(factors)
    with pytest.raises(ValueError, match=words):
        mould_summary(_disc(0.05), 400, PIXEL, factors=factors)


@pytest.mark.parametrize("s, spread, words", [
    ([0.1, 0.2], [0.1], "same"), ([], [], "at least one"), ([0.1, -1.0], [1, 1], "finite and >= 0"),
    ([0.1, 0.2], [1.0, 0.0], "finite and > 0"), ([0.1, 0.2], [1.0, np.nan], "finite and > 0")])
def test_a_spread_ratio_of_bad_values_is_refused(s, spread, words):
    with pytest.raises(ValueError, match=words):
        statistic_spread_ratio(s, spread)


def _calibration_table(sha: str, factors=(1.5, 1.2, 2.0, 0.25, 0.4)) -> pd.DataFrame:
    return pd.DataFrame({"statistic": SPREAD_STATISTICS, "factor": factors,
                         "factor_lo": 0.5, "factor_hi": 3.0, "n_moulds": 40, "replicas": 4,
                         "weights_sha256": sha})


def test_the_calibration_warns_only_for_a_checkpoint_it_was_not_fitted_for():
    sha, other = "a" * 64, "b" * 64
    factors, note, warning = spread_calibration(_calibration_table(sha), sha, "exp at abc")
    assert factors["mean_tension"] == 0.25 and warning is None
    assert "40 moulds x 4" in note and "mean_tension x0.25" in note and "exp at abc" in note
    _, _, warning = spread_calibration(_calibration_table(sha), other)
    assert sha[:12] in warning and other[:12] in warning
    mixed = _calibration_table(sha)
    mixed.loc[0, "weights_sha256"] = "0" * 64
    with pytest.raises(ValueError, match="2 checkpoints"):
        spread_calibration(mixed, sha)
    with pytest.raises(ValueError, match="repeats statistics \\['alignment'\\]"):
        spread_factors(pd.concat([_calibration_table(sha), _calibration_table(sha).iloc[:1]]))


def test_another_training_of_the_fitted_recipe_gets_a_note_not_a_warning():
    """The default run trained on another machine has other weights and the same recipe: its
    factors apply without a warning, and the note says whose they are. A checkpoint of
    another recipe is warned, and so is any checkpoint where the table names no recipe."""
    sha, other, recipe = "a" * 64, "b" * 64, "c" * 64
    table = _calibration_table(sha).assign(recipe_sha256=recipe)
    _, note, warning = spread_calibration(table, other, "exp at abc", recipe)
    assert warning is None and "another training of this checkpoint's recipe" in note
    _, note, warning = spread_calibration(table, sha, "exp at abc", recipe)
    assert warning is None and "another training" not in note  # the very weights
    _, _, warning = spread_calibration(table, other, "exp at abc", "d" * 64)
    assert sha[:12] in warning and other[:12] in warning
    _, _, warning = spread_calibration(_calibration_table(sha), other, "exp at abc", recipe)
    assert warning is not None


def test_a_recipe_is_its_settings_network_and_data_description_not_threads_or_data_bits():
    """recipe_sha256 is blind to the thread count and to the data's fingerprint (the bytes,
    which differ between machines), and sees a training setting, the network's width and the
    number of training samples."""
    import copy

    from condor.surrogate.checkpoint import recipe_sha256

    state = {"config": {"epochs": 120, "num_threads": 2, "field_weights": (2.0, 1.0)},
             "generator_config": {"base": 32, "depth": 4},
             "data": {"n_train": 495, "fingerprint": "f" * 64}, "generator": {}}
    base = recipe_sha256(state)
    assert len(base) == 64
    for key, name, value, same in (("config", "num_threads", 8, True),
                                   ("data", "fingerprint", "0" * 64, True),
                                   ("config", "epochs", 60, False),
                                   ("generator_config", "base", 48, False),
                                   ("data", "n_train", 400, False)):
        changed = copy.deepcopy(state)
        changed[key][name] = value
        assert (recipe_sha256(changed) == base) == same, (key, name)
    assert recipe_sha256({"generator": {}}) is None  # a network without its recipe


def test_a_network_is_known_by_its_weights_not_its_file(tmp_path):
    """Two checkpoints of the same weights whose histories differ (each epoch's wall-clock
    seconds) have one weights_sha256; another weight does not."""
    import torch

    from condor.surrogate.checkpoint import load_checkpoint, save_checkpoint, weights_sha256
    from condor.surrogate.networks import UNetConfig, UNetGenerator

    net = UNetGenerator(UNetConfig(size=16, base=4, depth=3), torch.Generator().manual_seed(0))
    state = {"generator": net.state_dict(), "history": [{"seconds": 1.0}]}
    paths = [tmp_path / "a.pt", tmp_path / "b.pt"]
    save_checkpoint(state, paths[0])
    save_checkpoint(dict(state, history=[{"seconds": 2.0}]), paths[1])
    assert paths[0].read_bytes() != paths[1].read_bytes()
    a, b = (weights_sha256(torch.load(p, weights_only=False)) for p in paths)  # as saved
    assert a == b and len(a) == 64
    with torch.no_grad():
        next(net.parameters()).view(-1)[0] += 1e-6
    assert weights_sha256({"generator": net.state_dict()}) != a


def test_the_shipped_calibration_names_every_statistic_once_and_a_checkpoint():
    finding = findings.load_findings()["spread_calibration"]
    table = finding.frame()
    factors = spread_factors(table)
    assert set(factors) == set(SPREAD_STATISTICS)
    assert (table["factor_lo"] <= table["factor"]).all() and \
        (table["factor"] <= table["factor_hi"]).all()
    assert table["weights_sha256"].str.fullmatch(r"[0-9a-f]{64}").all()
    assert table["recipe_sha256"].str.fullmatch(r"[0-9a-f]{64}").all()  # a sibling's factors too


def test_the_printed_direction_says_when_the_alignment_is_within_its_spread():
    """A mould whose cells point every way (alignment 0.002 +- 0.029) has a direction that is
    noise: the printed summary says so beside it; an aligned mould's direction stands alone."""
    from condor.surrogate.answer import NO_DIRECTION, direction_is_clear, format_mould_summary

    def table(alignment, spread):
        return pd.DataFrame([("alignment", alignment, spread, "0..1"),
                             ("direction", 55.0, 111.0, "deg from x"),
                             ("mean_tension", 0.01, 0.001, "T units")],
                            columns=["statistic", "value", "spread", "unit"])

    aligned, isotropic = table(0.6, 0.04), table(0.002, 0.029)
    assert direction_is_clear(aligned) and not direction_is_clear(isotropic)
    assert direction_is_clear(table(0.002, np.nan))  # no spread to judge by
    lines = {line.split()[0]: line for line in format_mould_summary(isotropic).splitlines()}
    assert NO_DIRECTION in lines["direction"] and NO_DIRECTION not in lines["alignment"]
    assert NO_DIRECTION not in format_mould_summary(aligned)
