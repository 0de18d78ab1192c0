"""Accuracy against the expected organisation: estimators over replicas (pure numpy).

A CONDOR equilibrium is a random draw: the same mould simulated with another seed forms other
orientation domains. The truth of any accuracy figure is therefore the *expected* fields mu of
a mould (the mean over infinitely many replicas), estimated by the mean of R replicas, and the
finite-replica noise is removed from every error:

    E |m - mean_R|^2 = |m - mu|^2 + sigma^2 / R          (m independent of the replicas)

so  |m - mean_R|^2 - s^2 / R  (s^2 the unbiased replica variance) is an unbiased estimate of
|m - mu|^2. Squared errors are averaged over every element of a mould's array (fields, pixels);
`per_field=True` keeps the first element axis (the field channel) apart.

Shapes: a method's answers are (M, ...) for M moulds; replicas are (M, R, ...) with R >= 2.
Moulds may hold different numbers of replicas: the array is then padded to the largest R with
NaN (a missing replica is NaN in every element, after the mould's own), and each mould's
noise term uses its own count R_i (a tether-free test mould takes more replicas than the
others: experiments/surrogate/README.md, "Tether-free test moulds").
Every figure has a bootstrap interval over moulds (`bootstrap_interval`); a whole-mould
statistic's Pearson r is taken against the expected statistic in the same way (the replica
mean's noise removed from its variance, `expected_r`) and comes with its n, its interval and
the ceiling a perfect predictor of the expected statistic reaches against one simulation
(`statistic_agreement`).
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

# Fewer moulds than this make a Pearson r uninformative (r = +-1 at n = 2 whatever the data).
MIN_MOULDS_FOR_R = 10
BOOTSTRAP_SAMPLES = 2000
LEVEL = 0.95


@dataclass(frozen=True)
class SquaredError:
    """Per-mould squared errors (M,) or (M, F): `plain` against the replica mean, `corrected`
    with the finite-replica noise removed (unbiased for the error against the expected fields;
    it can be slightly negative for a method closer to mu than the noise resolves)."""

    plain: np.ndarray
    corrected: np.ndarray


def as_replicas(replicas, min_replicas: int = 2) -> np.ndarray:
    """`replicas` as a float64 array (M, R, ...), NaN-padded (module docs); ValueError when a
    mould has fewer than min_replicas, or a replica is partly NaN, inf, or before a missing one."""
    array = np.asarray(replicas, dtype=np.float64)
    if array.ndim < 2:
        raise ValueError(f"replicas must have shape (moulds, replicas, ...), got {array.shape}")
    if np.isinf(array).any():
        raise ValueError("replicas contain inf")
    missing = np.isnan(array).reshape(array.shape[:2] + (-1,))
    present = ~missing.all(axis=2)
    if (missing.any(axis=2) & present).any():
        raise ValueError("replicas contain NaN: a replica is either complete or missing (all NaN)")
    if (present[:, 1:] & ~present[:, :-1]).any():
        raise ValueError("a missing (all-NaN) replica comes before a present one: pad at the end")
    counts = present.sum(axis=1)
    if array.shape[0] and counts.min() < min_replicas:
        raise ValueError(f"need at least {min_replicas} replicas per mould, got {counts.min()} "
                         "(a missing replica is all NaN)")
    return array


def pad_replicas(per_mould) -> np.ndarray:
    """Replicas of unequal count, one sequence of arrays per mould (each with at least one), as
    one (M, R, ...) float64 array NaN-padded to the largest count: the estimators' layout."""
    width = max(len(replicas) for replicas in per_mould)
    out = np.full((len(per_mould), width) + np.shape(per_mould[0][0]), np.nan)
    for m, replicas in enumerate(per_mould):
        out[m, :len(replicas)] = replicas
    return out


def replica_counts(replicas) -> np.ndarray:
    """Replicas each mould holds (M,) int: R, or fewer where NaN-padded."""
    return _counts(as_replicas(replicas, 1))


def _counts(array: np.ndarray) -> np.ndarray:
    """replica_counts of an array as_replicas has already checked (a replica is whole)."""
    return (~np.isnan(array.reshape(array.shape[:2] + (-1,))[:, :, 0])).sum(axis=1)


def _per_mould(values: np.ndarray, like: np.ndarray) -> np.ndarray:
    """(M,) values broadcast against an (M, ...) array."""
    return values.reshape(values.shape + (1,) * (like.ndim - 1))


def _noise_of_mean(reps: np.ndarray) -> np.ndarray:
    """Per element, the unbiased variance of the replica mean: s^2 / R_i, (M, ...)."""
    var = np.nanvar(reps, axis=1, ddof=1)
    return var / _per_mould(_counts(reps), var)


def _reduce(x: np.ndarray, per_field: bool) -> np.ndarray:
    """Mean over every axis after the mould axis (after the first element axis if per_field)."""
    first = 2 if per_field else 1
    return x.mean(axis=tuple(range(first, x.ndim))) if x.ndim > first else x


def replica_mean(replicas) -> np.ndarray:
    """The estimate of the expected fields, (M, ...)."""
    return np.nanmean(as_replicas(replicas, 1), axis=1)


def replica_variance(replicas) -> np.ndarray:
    """Unbiased per-element variance of one replica about the expected fields, (M, ...)."""
    return np.nanvar(as_replicas(replicas), axis=1, ddof=1)


def mse_against_expected(method, replicas, per_field: bool = False) -> SquaredError:
    """Squared error of `method` (M, ...) against the expected fields of `replicas` (M, R, ...).
    The method must be independent of these replicas (another seed, solver or a predictor)."""
    reps = as_replicas(replicas)
    answer = np.asarray(method, dtype=np.float64)
    if answer.shape != reps.shape[:1] + reps.shape[2:]:
        raise ValueError(f"method answers {answer.shape} do not match replicas {reps.shape}")
    plain = _reduce((answer - np.nanmean(reps, axis=1)) ** 2, per_field)
    noise = _reduce(_noise_of_mean(reps), per_field)
    return SquaredError(plain, plain - noise)


def noise_ceiling(replicas, per_field: bool = False) -> np.ndarray:
    """Per-mould expected squared error of one simulation against the expected fields: the
    replica variance sigma^2 averaged over elements, (M,) or (M, F)."""
    return _reduce(replica_variance(replicas), per_field)


def held_out_error(replicas, k: int, per_field: bool = False) -> SquaredError:
    """Squared error of the mean of `k` simulations against the expected fields, measured on
    disjoint replicas: each rotation takes k consecutive replicas as the method and the other
    R - k (>= 2) as the truth; the R rotations are averaged (each is unbiased). Its corrected
    value estimates sigma^2 / k: "one simulation" is k = 1. With NaN-padded replicas it uses
    the replicas every mould holds (the first min R_i)."""
    reps = as_replicas(replicas)
    n = int(replica_counts(reps).min())
    reps = reps[:, :n]
    if not 1 <= k <= n - 2:
        raise ValueError(f"held-out error of {k} simulations needs k >= 1 and {k} + 2 <= "
                         f"{n} replicas")
    plain, corrected = [], []
    for start in range(n):
        chosen = (start + np.arange(k)) % n
        rest = np.setdiff1d(np.arange(n), chosen)
        err = mse_against_expected(reps[:, chosen].mean(axis=1), reps[:, rest], per_field)
        plain.append(err.plain)
        corrected.append(err.corrected)
    return SquaredError(np.mean(plain, axis=0), np.mean(corrected, axis=0))


def ensemble_distance(a, b, per_field: bool = False) -> SquaredError:
    """Squared distance between the expected fields of two ensembles of the same moulds,
    a (M, Ra, ...) and b (M, Rb, ...): |mean_a - mean_b|^2 - s_a^2/Ra - s_b^2/Rb is unbiased
    for |mu_a - mu_b|^2 (0 when both sample the same states)."""
    ra, rb = as_replicas(a), as_replicas(b)
    if ra.shape[:1] + ra.shape[2:] != rb.shape[:1] + rb.shape[2:]:
        raise ValueError(f"ensembles {ra.shape} and {rb.shape} are not of the same moulds")
    plain = _reduce((np.nanmean(ra, axis=1) - np.nanmean(rb, axis=1)) ** 2, per_field)
    noise = _reduce(_noise_of_mean(ra), per_field) + _reduce(_noise_of_mean(rb), per_field)
    return SquaredError(plain, plain - noise)


def paired_distance(a, b, per_field: bool = False) -> SquaredError:
    """`ensemble_distance` for two ensembles whose replica k share a seed, a (M, Ra, ...) and
    b (M, Rb, ...): the paper reference's rungs, whose run k starts from the same state with the
    same random stream at every budget. Over the n pairs k < min(Ra, Rb) where both ran, the
    differences d_k = a_k - b_k give |mean(d)|^2 - s_d^2 / n, unbiased for |mu_a - mu_b|^2
    whatever the pairs' correlation. ensemble_distance assumes independent ensembles: paired
    runs that stay alike make it biased low (it removes noise their difference does not carry),
    so a ladder of shared seeds reads 'not resolved' too often."""
    ra, rb = as_replicas(a), as_replicas(b)
    if ra.shape[:1] + ra.shape[2:] != rb.shape[:1] + rb.shape[2:]:
        raise ValueError(f"ensembles {ra.shape} and {rb.shape} are not of the same moulds")
    n = min(ra.shape[1], rb.shape[1])
    diff = ra[:, :n] - rb[:, :n]  # NaN where either run of a pair is missing (>= 2 pairs:
    # as_replicas holds each side's first 2 runs present)
    plain = _reduce(np.nanmean(diff, axis=1) ** 2, per_field)
    return SquaredError(plain, plain - _reduce(_noise_of_mean(diff), per_field))


def root_mean(per_mould) -> float:
    """sqrt of the mean over moulds, floored at 0 (an RMS error from per-mould squared errors)."""
    return float(np.sqrt(max(float(np.mean(per_mould)), 0.0)))


def bootstrap_interval(per_mould, statistic=root_mean, n_boot: int = BOOTSTRAP_SAMPLES,
                       level: float = LEVEL, seed: int = 0) -> tuple[float, float, float]:
    """(estimate, lo, hi): `statistic` of the per-mould values (M, ...) and its percentile
    bootstrap interval over moulds resampled with replacement (deterministic for `seed`)."""
    values = np.asarray(per_mould, dtype=np.float64)
    if values.shape[0] < 1:
        raise ValueError("bootstrap needs at least one mould")
    estimate = float(statistic(values))
    rng = np.random.default_rng([seed, values.shape[0]])
    draws = rng.integers(0, values.shape[0], size=(n_boot, values.shape[0]))
    boot = np.array([statistic(values[d]) for d in draws], dtype=np.float64)
    boot = boot[np.isfinite(boot)]
    if boot.size == 0:
        return estimate, float("nan"), float("nan")
    tail = 100 * (1 - level) / 2
    lo, hi = np.percentile(boot, [tail, 100 - tail])
    return estimate, float(lo), float(hi)


def pearson_r(x, y) -> float:
    """Pearson r in float64; NaN when either side is constant or n < 2."""
    x = np.asarray(x, dtype=np.float64)
    y = np.asarray(y, dtype=np.float64)
    if x.size < 2:
        return float("nan")
    dx, dy = x - x.mean(), y - y.mean()
    den = np.sqrt((dx * dx).sum() * (dy * dy).sum())
    return float((dx * dy).sum() / den) if den > 0 else float("nan")


def reliability(replicas) -> float:
    """Expected correlation between two simulations of the same moulds for a whole-mould
    statistic (replicas (M, R)): the intraclass correlation from the one-way ANOVA, i.e. the
    between-mould variance of mu over that plus the within-mould variance sigma^2."""
    reps = as_replicas(replicas)
    if reps.ndim != 2:
        raise ValueError(f"a statistic's replicas are (moulds, replicas), got {reps.shape}")
    within = np.nanvar(reps, axis=1, ddof=1).mean()
    between = np.nanmean(reps, axis=1).var(ddof=1) - _noise_of_mean(reps).mean()
    total = between + within
    return float(np.clip(between / total, 0.0, 1.0)) if total > 0 else float("nan")


def _pairs_r(columns: np.ndarray) -> float:
    """Plain r of (method, replica mean) rows (M, 2 or 3)."""
    return pearson_r(columns[:, 0], columns[:, 1])


def expected_r(method, replica_mean, replica_var, n_replicas) -> float:
    """Pearson r of a method against the *expected* statistic mu, with the finite-replica
    noise removed: cov(method, mean_R) is unbiased for cov(method, mu) (the method is
    independent of the replicas) and var(mean_R) - mean(s^2 / R) for var(mu) (n_replicas: R,
    or R_i per mould). NaN when the moulds' expected statistics do not vary beyond that
    noise; clipped to [-1, 1]."""
    x = np.asarray(method, dtype=np.float64)
    m = np.asarray(replica_mean, dtype=np.float64)
    if x.size < 2:
        return float("nan")
    dx, dm = x - x.mean(), m - m.mean()
    var_x = (dx * dx).mean()
    var_mu = (dm * dm).mean() - np.mean(np.asarray(replica_var, dtype=np.float64)
                                        / n_replicas) * (x.size - 1) / x.size
    if not (var_x > 0 and var_mu > 0):
        return float("nan")
    return float(np.clip((dx * dm).mean() / np.sqrt(var_x * var_mu), -1.0, 1.0))


def statistic_agreement(method, replicas, n_boot: int = BOOTSTRAP_SAMPLES,
                        seed: int = 0) -> dict:
    """How a method's whole-mould statistic (M,) agrees with the replicas' (M, R).

    r: Pearson r against the expected statistic, the finite-replica noise removed
    (`expected_r`), with r_lo, r_hi (bootstrap over moulds); r_plain (r_plain_lo, r_plain_hi):
    against the replica mean as it is, lowered by that noise; r_ceiling: the r a perfect
    predictor of the expected statistic reaches against one simulation, sqrt(reliability);
    bias: median over moulds of method / replica mean - 1, with bias_lo, bias_hi; n: moulds;
    informative: n >= MIN_MOULDS_FOR_R (with fewer, r says little).
    """
    reps = as_replicas(replicas)
    answer = np.asarray(method, dtype=np.float64)
    if answer.shape != reps.shape[:1] or reps.ndim != 2:
        raise ValueError(f"method statistic {answer.shape} does not match replicas {reps.shape}")
    mean = np.nanmean(reps, axis=1)
    columns = np.stack([answer, mean, np.nanvar(reps, axis=1, ddof=1), replica_counts(reps)],
                       axis=1)
    r, r_lo, r_hi = bootstrap_interval(
        columns, lambda c: expected_r(c[:, 0], c[:, 1], c[:, 2], c[:, 3]), n_boot, seed=seed)
    r_plain, r_plain_lo, r_plain_hi = bootstrap_interval(columns, _pairs_r, n_boot, seed=seed)
    with np.errstate(divide="ignore", invalid="ignore"):
        ratio = answer / mean - 1.0
    bias, bias_lo, bias_hi = bootstrap_interval(ratio, np.median, n_boot, seed=seed)
    ceiling = reliability(reps)
    return {"n": int(len(mean)), "r": r, "r_lo": r_lo, "r_hi": r_hi, "r_plain": r_plain,
            "r_plain_lo": r_plain_lo, "r_plain_hi": r_plain_hi,
            "r_ceiling": float(np.sqrt(ceiling)) if np.isfinite(ceiling) else float("nan"),
            "bias": bias, "bias_lo": bias_lo, "bias_hi": bias_hi,
            "informative": bool(len(mean) >= MIN_MOULDS_FOR_R)}
