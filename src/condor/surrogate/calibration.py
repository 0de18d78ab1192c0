"""Is the predicted spread right? Interval coverage and spread agreement against replicas, and
the checkerboard measure of a field (pure numpy).

A surrogate with a spread head (condor.surrogate.physics) predicts, per pixel and field, the
standard deviation `spread` of one simulation around the expected field `mean`. Its central
q-interval is mean -/+ z_q * spread with z_q the standard normal quantile (a Gaussian model
of one run's scatter). Validated on replicas (M moulds, R simulations each): the fraction of
replica pixels inside the tissue that fall in the interval should be q.
"""

from __future__ import annotations

from statistics import NormalDist

import numpy as np

LEVELS = (0.5, 0.9)


def z_of(level: float) -> float:
    """Half-width, in standard deviations, of the central `level` interval of a Gaussian."""
    if not 0 < level < 1:
        raise ValueError(f"interval level must be in (0, 1), got {level}")
    return float(NormalDist().inv_cdf(0.5 + level / 2))


def tissue_pixels(inputs: np.ndarray) -> np.ndarray:
    """(M, 2, H, W) input channels (mould, tether) -> (M, H, W) bool: inside the mould or a
    tether (the tissue footprint)."""
    inputs = np.asarray(inputs)
    if inputs.ndim != 4 or inputs.shape[1] != 2:
        raise ValueError(f"inputs must be (M, 2, H, W), got {inputs.shape}")
    return inputs.astype(bool).any(axis=1)


def _check(mean, spread, replicas, mask):
    mean, spread = np.asarray(mean, np.float64), np.asarray(spread, np.float64)
    replicas, mask = np.asarray(replicas, np.float64), np.asarray(mask, bool)
    if mean.shape != spread.shape or replicas.shape[:1] + replicas.shape[2:] != mean.shape:
        raise ValueError(f"mean {mean.shape}, spread {spread.shape} and replicas "
                         f"{replicas.shape} do not match")
    if mask.shape != mean.shape[:1] + mean.shape[2:]:
        raise ValueError(f"mask {mask.shape} does not match fields {mean.shape}")
    return mean, spread, replicas, mask


def interval_coverage(mean, spread, replicas, mask, levels=LEVELS, fields=None) -> dict:
    """Per mould (M,), for each level q: the fraction of replica values (every replica, every
    field in `fields` (indices; default all), every pixel in `mask`) inside mean -/+ z_q
    spread. mean, spread (M, F, H, W); replicas (M, R, F, H, W), NaN-padded where a mould
    holds fewer (condor.measures.estimators: only its own count); mask (M, H, W)."""
    mean, spread, replicas, mask = _check(mean, spread, replicas, mask)
    chosen = slice(None) if fields is None else list(fields)
    distance = np.abs(replicas - mean[:, None])[:, :, chosen]
    width = spread[:, None, chosen]
    present = ~np.isnan(distance)
    out = {}
    for level in levels:
        inside = distance <= z_of(level) * width
        per_mould = [inside[m][..., mask[m]].sum() / present[m][..., mask[m]].sum()
                     for m in range(len(mean))]
        out[level] = np.asarray(per_mould)
    return out


def spread_agreement(spread, replicas, mask, fields=None) -> dict:
    """Predicted spread against the replicas' standard deviation (ddof 1), inside `mask`:
    `predicted` and `replica` (M,), each mould's root-mean-square spread over pixels and
    fields; `r` their Pearson r over moulds; `ratio` the median of predicted / replica;
    `pixel_r` (M,) each mould's r between the two maps over its tissue pixels."""
    spread = np.asarray(spread, np.float64)
    _check(spread, spread, replicas, mask)
    chosen = slice(None) if fields is None else list(fields)
    replica_std = np.nanstd(np.asarray(replicas, np.float64), axis=1, ddof=1)[:, chosen]
    spread = spread[:, chosen]
    mask = np.asarray(mask, bool)
    predicted = np.array([np.sqrt((spread[m][..., mask[m]] ** 2).mean()) for m in range(len(spread))])
    replica = np.array([np.sqrt((replica_std[m][..., mask[m]] ** 2).mean()) for m in range(len(spread))])
    pixel_r = np.array([np.corrcoef(spread[m][..., mask[m]].ravel(),
                                    replica_std[m][..., mask[m]].ravel())[0, 1]
                        for m in range(len(spread))])
    return {"predicted": predicted, "replica": replica,
            "r": float(np.corrcoef(predicted, replica)[0, 1]),
            "ratio": float(np.median(predicted / replica)), "pixel_r": pixel_r}


def checkerboard(fields) -> np.ndarray:
    """RMS of the period-2 (checkerboard) component of fields (..., H, W): each 2x2 block's
    alternating sum f00 - f01 - f10 + f11, over 4, the amplitude of the Nyquist-frequency
    pattern a stride-2 transposed convolution leaves. Shape (...)."""
    f = np.asarray(fields, np.float64)
    c = (f[..., :-1, :-1] - f[..., :-1, 1:] - f[..., 1:, :-1] + f[..., 1:, 1:]) / 4
    return np.sqrt((c * c).mean(axis=(-2, -1)))


def statistic_spread_ratio(replica_sd, spread, seed: int = 0) -> tuple[float, float, float]:
    """How far one simulation's whole-mould statistic scatters against its predicted spread,
    over moulds: (ratio, lo, hi), ratio = sqrt(mean over moulds of s^2 / spread^2) with its 95%
    bootstrap interval over moulds (condor.measures.estimators). s: each mould's replica
    standard deviation (ddof 1), whose square is unbiased for the variance sigma^2 whatever the
    number of replicas, so the ratio is the noise-corrected root mean square of sigma / spread:
    1 when the spread is right, above 1 too small. It is also the factor that makes a spread
    right in that sense (condor.surrogate.answer.mould_summary's `factors`). replica_sd,
    spread: (M,) per mould; ValueError on a length mismatch, no moulds, a non-finite or
    negative s, or a non-finite or non-positive spread."""
    from condor.measures.estimators import bootstrap_interval, root_mean

    s, spread = np.asarray(replica_sd, np.float64), np.asarray(spread, np.float64)
    if s.ndim != 1 or s.shape != spread.shape or s.size == 0:
        raise ValueError(f"replica_sd {s.shape} and spread {spread.shape} must be the same "
                         "(moulds,) shape, with at least one mould")
    bad = ~np.isfinite(s) | (s < 0)
    if bad.any():
        raise ValueError(f"replica standard deviations must be finite and >= 0, got "
                         f"{s[bad][:5].tolist()} at moulds {np.flatnonzero(bad)[:5].tolist()}")
    bad = ~np.isfinite(spread) | (spread <= 0)
    if bad.any():
        raise ValueError(f"predicted spreads must be finite and > 0, got "
                         f"{spread[bad][:5].tolist()} at moulds {np.flatnonzero(bad)[:5].tolist()}")
    return bootstrap_interval((s / spread) ** 2, root_mean, seed=seed)
