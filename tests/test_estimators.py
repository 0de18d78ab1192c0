"""condor.measures.estimators on synthetic draws with a known mean and variance."""

import numpy as np
import pytest

from condor.measures import estimators as est


def draws(rng, moulds=150, replicas=4, shape=(3, 6, 6), sigma=0.5):
    """Known expected fields mu (M, ...) and replicas mu + sigma * N(0, 1) (M, R, ...)."""
    mu = rng.normal(size=(moulds, *shape))
    noise = rng.normal(size=(moulds, replicas, *shape)) * sigma
    return mu, mu[:, None] + noise


def test_corrected_error_recovers_the_known_error_and_plain_does_not():
    rng = np.random.default_rng(1)
    mu, reps = draws(rng, sigma=0.5)
    offset = 0.2 * rng.normal(size=mu.shape[1:])
    truth = float((offset ** 2).mean())  # |m - mu|^2 per mould, the same for every mould
    err = est.mse_against_expected(mu + offset, reps)
    _, lo, hi = est.bootstrap_interval(err.corrected, np.mean)
    assert lo <= truth <= hi
    # The plain form carries sigma^2 / R = 0.0625 on top of 0.04: outside its interval.
    _, plain_lo, _ = est.bootstrap_interval(err.plain, np.mean)
    assert plain_lo > truth + 0.5 * 0.25 / 4


def test_noise_ceiling_and_held_out_means_of_k_simulations():
    rng = np.random.default_rng(2)
    sigma = 0.3
    _, reps = draws(rng, replicas=8, sigma=sigma)
    for values, expected in ((est.noise_ceiling(reps), sigma ** 2),
                             (est.held_out_error(reps, 1).corrected, sigma ** 2),
                             (est.held_out_error(reps, 2).corrected, sigma ** 2 / 2),
                             (est.held_out_error(reps, 4).corrected, sigma ** 2 / 4)):
        _, lo, hi = est.bootstrap_interval(values, np.mean)
        assert lo <= expected <= hi, (expected, lo, hi)
    with pytest.raises(ValueError, match="replicas"):
        est.held_out_error(reps, 7)


def test_per_field_keeps_channels_apart():
    rng = np.random.default_rng(3)
    mu, reps = draws(rng, shape=(2, 5, 5), sigma=0.4)
    offset = np.zeros(mu.shape[1:])
    offset[1] = 0.5  # only channel 1 is wrong
    err = est.mse_against_expected(mu + offset, reps, per_field=True)
    assert err.corrected.shape == (mu.shape[0], 2)
    means = err.corrected.mean(axis=0)
    assert abs(means[0]) < 0.01 and abs(means[1] - 0.25) < 0.02


def test_ensemble_distance_is_zero_for_the_same_states_and_finds_a_shift():
    rng = np.random.default_rng(4)
    mu, a = draws(rng, replicas=3, sigma=0.6)
    b = mu[:, None] + 0.6 * rng.normal(size=(mu.shape[0], 5, *mu.shape[1:]))
    same = est.ensemble_distance(a, b)
    _, lo, hi = est.bootstrap_interval(same.corrected, np.mean)
    assert lo <= 0.0 <= hi
    assert same.plain.mean() > 0.1  # uncorrected, noise looks like a difference
    shifted = est.ensemble_distance(a, b + 0.3)
    _, lo, hi = est.bootstrap_interval(shifted.corrected, np.mean)
    assert lo <= 0.09 <= hi


def test_paired_distance_is_unbiased_where_runs_share_a_seed_and_the_unpaired_is_not():
    """Synthetic rungs whose run k shares a seed: a_k = mu + s_k + e_k, b_k = mu + delta +
    s_k + e'_k, with a shared part s_k (variance rho sigma^2) and a private part. The paired
    estimator's mean over many moulds recovers |delta|^2 at both delta = 0 and delta = 0.3,
    while ensemble_distance, which assumes independent ensembles, falls short by
    2 rho sigma^2 / R (its known bias: the shared part is noise the means' difference lacks)."""
    rng = np.random.default_rng(11)
    moulds, runs, pixels, sigma, rho = 4000, 3, 6, 0.6, 0.8
    mu = rng.normal(size=(moulds, 1, pixels))
    shared = np.sqrt(rho) * sigma * rng.normal(size=(moulds, runs, pixels))

    def private():
        return np.sqrt(1 - rho) * sigma * rng.normal(size=(moulds, runs, pixels))

    a = mu + shared + private()
    bias = 2 * rho * sigma**2 / runs
    for delta in (0.0, 0.3):
        b = mu + delta + shared + private()
        paired = est.paired_distance(a, b).corrected.mean()
        unpaired = est.ensemble_distance(a, b).corrected.mean()
        assert paired == pytest.approx(delta**2, abs=0.01)
        assert unpaired == pytest.approx(delta**2 - bias, abs=0.01)
    # independent runs: both estimators are unbiased, the paired one over its pairs only
    b = mu + 0.3 + sigma * rng.normal(size=(moulds, runs + 2, pixels))
    assert est.paired_distance(a, b).corrected.mean() == pytest.approx(0.09, abs=0.02)
    assert est.ensemble_distance(a, b).corrected.mean() == pytest.approx(0.09, abs=0.02)


def test_statistic_agreement_ceiling_bias_and_small_n():
    rng = np.random.default_rng(5)
    moulds, tau, sigma = 400, 1.0, 0.5
    mu = 10 + tau * rng.normal(size=moulds)
    reps = mu[:, None] + sigma * rng.normal(size=(moulds, 6))
    expected_ceiling = np.sqrt(tau ** 2 / (tau ** 2 + sigma ** 2))
    perfect = est.statistic_agreement(mu, reps)
    assert abs(perfect["r_ceiling"] - expected_ceiling) < 0.02
    # The ceiling is what a perfect predictor scores against one fresh simulation.
    one = mu + sigma * rng.normal(size=moulds)
    assert abs(est.pearson_r(mu, one) - perfect["r_ceiling"]) < 0.04
    assert perfect["r_lo"] <= perfect["r"] <= perfect["r_hi"]
    biased = est.statistic_agreement(1.05 * reps.mean(axis=1), reps)
    assert biased["bias"] == pytest.approx(0.05)
    assert biased["informative"]
    few = est.statistic_agreement(mu[:2], reps[:2])
    assert few["n"] == 2 and not few["informative"] and abs(few["r"]) == pytest.approx(1.0)


def test_bootstrap_interval_covers_the_truth_at_about_its_level():
    rng = np.random.default_rng(6)
    covered = 0
    trials = 60
    for _ in range(trials):
        values = rng.normal(loc=1.0, size=40)
        _, lo, hi = est.bootstrap_interval(values, np.mean, n_boot=400)
        covered += lo <= 1.0 <= hi
    assert 0.85 * trials <= covered <= trials


def test_bad_shapes_are_named():
    with pytest.raises(ValueError, match="at least 2 replicas"):
        est.noise_ceiling(np.zeros((3, 1, 4)))
    with pytest.raises(ValueError, match="do not match"):
        est.mse_against_expected(np.zeros((3, 5)), np.zeros((3, 2, 4)))
    with pytest.raises(ValueError, match="NaN"):
        est.noise_ceiling(np.full((2, 2, 2), np.nan))


def test_expected_r_removes_the_replica_means_noise():
    """Synthetic draws with a known answer: a predictor x = mu + N(0, e^2) over mu ~ N(0, 1)
    has r = 1 / sqrt(1 + e^2) against mu. Against the mean of R noisy replicas the plain r is
    lower by the replica noise; the corrected r recovers the truth."""
    rng = np.random.default_rng(11)
    moulds, noise, error, n_reps = 4000, 0.8, 0.3, 3
    mu = rng.normal(size=moulds)
    x = mu + error * rng.normal(size=moulds)
    reps = mu[:, None] + noise * rng.normal(size=(moulds, n_reps))
    truth = 1 / np.sqrt(1 + error ** 2)
    plain_expected = truth / np.sqrt(1 + noise ** 2 / n_reps)  # attenuated by the mean's noise
    agreement = est.statistic_agreement(x, reps, n_boot=200)
    assert agreement["r"] == pytest.approx(truth, abs=0.01)
    assert agreement["r_plain"] == pytest.approx(plain_expected, abs=0.01)
    assert agreement["r_plain"] < truth - 0.05
    assert agreement["r_lo"] <= agreement["r"] <= agreement["r_hi"]
    # no replica noise: the corrected r is the plain one
    exact = np.repeat(mu[:, None], 2, axis=1)
    assert est.expected_r(x, mu, exact.var(axis=1, ddof=1), 2) == pytest.approx(
        est.pearson_r(x, mu))
    # expected statistics that do not vary beyond the replica noise: no r to give
    flat = rng.normal(size=(50, 4))
    assert np.isnan(est.expected_r(rng.normal(size=50), flat.mean(axis=1),
                                   flat.var(axis=1, ddof=1) * 4, 4))


def _pad(groups, width=None):
    """Ragged replicas (a list of (R_i, ...) arrays) -> NaN-padded (M, R, ...)."""
    width = width or max(len(g) for g in groups)
    out = np.full((len(groups), width) + groups[0].shape[1:], np.nan)
    for m, g in enumerate(groups):
        out[m, :len(g)] = g
    return out


def test_nan_padded_replicas_equal_each_moulds_own_computation():
    """Moulds holding different numbers of replicas: every estimator equals the same formula
    applied to each mould's own replicas, one mould at a time."""
    rng = np.random.default_rng(21)
    groups = [rng.normal(size=(n, 3, 5)) for n in (4, 20, 4, 7, 2)]
    padded = _pad(groups)
    np.testing.assert_array_equal(est.replica_counts(padded), [4, 20, 4, 7, 2])
    method = rng.normal(size=(5, 3, 5))
    err = est.mse_against_expected(method, padded)
    for m, g in enumerate(groups):
        own = est.mse_against_expected(method[m:m + 1], g[None])
        assert err.plain[m] == pytest.approx(own.plain[0])
        assert err.corrected[m] == pytest.approx(own.corrected[0])
        assert est.noise_ceiling(padded)[m] == pytest.approx(est.noise_ceiling(g[None])[0])
    other = _pad([rng.normal(size=(n, 3, 5)) for n in (3, 3, 9, 3, 3)])
    dist = est.ensemble_distance(padded, other)
    assert dist.corrected[2] == pytest.approx(
        est.ensemble_distance(padded[2:3, :4], other[2:3, :9]).corrected[0])
    # one simulation against the rest: only the replicas every mould holds (here 2: k = 1 needs 3)
    with pytest.raises(ValueError, match="held-out"):
        est.held_out_error(padded, 1)
    kept = est.held_out_error(padded[:4], 1)
    np.testing.assert_allclose(kept.corrected, est.held_out_error(padded[:4, :4], 1).corrected)


def test_nan_padded_statistics_recover_the_expected_r_with_unequal_replicas():
    """Synthetic draws with a known answer: a few moulds scatter 10x more and hold 20
    replicas, the rest 4; the corrected r recovers 1 / sqrt(1 + e^2) with each mould's own
    noise term, and the ceiling is the intraclass correlation of one simulation."""
    rng = np.random.default_rng(5)
    moulds, error = 3000, 0.3
    mu = rng.normal(size=moulds)
    x = mu + error * rng.normal(size=moulds)
    noisy = rng.random(moulds) < 0.05
    sigma = np.where(noisy, 3.0, 0.3)
    counts = np.where(noisy, 20, 4)
    groups = [mu[m] + sigma[m] * rng.normal(size=counts[m]) for m in range(moulds)]
    padded = _pad(groups)
    agreement = est.statistic_agreement(x, padded, n_boot=50)
    assert agreement["r"] == pytest.approx(1 / np.sqrt(1 + error ** 2), abs=0.015)
    ceiling = np.sqrt(1 / (1 + np.mean(sigma ** 2)))
    assert agreement["r_ceiling"] == pytest.approx(ceiling, abs=0.02)
    # with equal counts the ragged formula is the plain one
    even = rng.normal(size=(30, 4)) + rng.normal(size=(30, 1))
    assert est.reliability(_pad(list(even[:, :, None]))[:, :, 0]) == pytest.approx(
        est.reliability(even))


def test_padding_must_be_whole_missing_replicas_at_the_end():
    reps = np.zeros((2, 3, 4))
    reps[0, 2, 1] = np.nan
    with pytest.raises(ValueError, match="complete or missing"):
        est.as_replicas(reps)
    reps = np.zeros((2, 3, 4))
    reps[0, 0] = np.nan
    with pytest.raises(ValueError, match="pad at the end"):
        est.as_replicas(reps)
    reps = np.zeros((2, 3, 4))
    reps[1, 1:] = np.nan
    with pytest.raises(ValueError, match="at least 2 replicas per mould, got 1"):
        est.as_replicas(reps)


def test_pad_replicas_keeps_each_moulds_own_and_pads_with_nan():
    from condor.measures.estimators import pad_replicas
    a = [np.ones((2, 3)), 2 * np.ones((2, 3))]
    b = [3 * np.ones((2, 3))]
    out = pad_replicas([a, b])
    assert out.shape == (2, 2, 2, 3)
    assert np.array_equal(out[0, 1], a[1]) and np.array_equal(out[1, 0], b[0])
    assert np.isnan(out[1, 1]).all()
    assert list(est.replica_counts(out)) == [2, 1]
