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
