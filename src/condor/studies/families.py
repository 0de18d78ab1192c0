"""A predictor scored family by family: the error against each family's expected fields,
beside that family's own noise ceiling, and the bias of its mean tension.

One row a family of moulds (`families`, one label a mould of the ensemble): `error` the
predictor's field error against the expected fields with the finite-replica noise removed
(condor.measures.estimators: RMS over the 8 normalised fields, pixels and the family's moulds)
with its 95% bootstrap interval over moulds; `noise_ceiling` one simulation's error against the
same expected fields (held out from the replicas); `tension_bias` the median over moulds of
predicted / expected mean tension - 1 (condor.surrogate.answer's mean_tension, sum T / sum P)
with its interval. The workflow scores its lab test set with it
(evaluation/families_lab.csv) and experiments/generalisation its held-out families.
"""

from __future__ import annotations

import numpy as np
import pandas as pd

from condor.measures import estimators as est
from condor.measures.metrics import normalise_predicted

FAMILY_COLUMNS = ("family", "n_moulds", "replicas", "error", "error_lo", "error_hi",
                  "noise_ceiling", "tension_bias", "tension_bias_lo", "tension_bias_hi")
_P, _T = 0, 1  # the density and tension fields' places (condor.data.fields.FIELD_NAMES)


def mean_tension(normalised: np.ndarray) -> np.ndarray:
    """sum T / sum P of normalised fields (..., 8, H, W): the mean cell tension."""
    f = np.asarray(normalised, dtype=np.float64)
    return f[..., _T, :, :].sum(axis=(-2, -1)) / f[..., _P, :, :].sum(axis=(-2, -1))


def family_rows(ensemble, predicted_raw: np.ndarray, families, seed: int = 0) -> pd.DataFrame:
    """FAMILY_COLUMNS for each family of `families` (one label a mould of `ensemble`, in its
    order) of a predictor's raw fields `predicted_raw` (M, 8, H, W), normalised by their own
    density sum (the paper's rule for predicted fields)."""
    families = np.asarray(families, dtype=object)
    truth = ensemble.normalised  # (M, R, 8, H, W), NaN-padded
    predicted = normalise_predicted(np.asarray(predicted_raw)).astype(np.float64)
    if len(families) != len(truth) or predicted.shape[0] != len(truth):
        raise ValueError(f"{len(families)} family labels and {predicted.shape[0]} predictions "
                         f"for {len(truth)} moulds")
    rows = []
    for family in dict.fromkeys(families):  # first-seen order
        idx = np.flatnonzero(families == family)
        err = est.mse_against_expected(predicted[idx], truth[idx])
        error, lo, hi = est.bootstrap_interval(err.corrected, seed=seed)
        counts = ensemble.replica_counts[idx]
        ceiling = (est.root_mean(est.held_out_error(truth[idx], 1).corrected)
                   if counts.min() >= 3 else float("nan"))
        expected = mean_tension(np.nanmean(truth[idx], axis=1))
        bias, bias_lo, bias_hi = est.bootstrap_interval(mean_tension(predicted[idx]) / expected
                                                        - 1.0, np.median, seed=seed)
        rows.append({"family": family, "n_moulds": int(len(idx)), "replicas": int(counts.min()),
                     "error": error, "error_lo": lo, "error_hi": hi, "noise_ceiling": ceiling,
                     "tension_bias": bias, "tension_bias_lo": bias_lo,
                     "tension_bias_hi": bias_hi})
    return pd.DataFrame(rows, columns=list(FAMILY_COLUMNS))
