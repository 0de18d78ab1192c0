"""Every method scored against the expected organisation of the same test moulds.

The truth is the reference ensemble (`recipes.reference_ensemble`: the dataset's replicas
of each test mould). For each method (simulations of `sweep`, surrogates, baselines, and the
dataset solver's own "single simulation" and "mean of k simulations") this module returns:

- `accuracy` rows: the field error against the expected fields, with the finite-replica noise
  removed (condor.measures.estimators: an RMS over the 8 normalised fields, pixels and moulds), its
  bootstrap interval over moulds, the plain (uncorrected) error, per-field errors and the CPU
  seconds per mould. The row "single simulation" is the noise ceiling: what one run of the
  dataset's solver scores.
- `statistics` rows: for each whole-mould statistic (STATISTICS: condor's, as `condor predict`
  names them, condor.data.statistics.MOULD_STATISTICS, then the paper's that condor has no name
  for), the method's Pearson r against the expected statistic (the replica mean's noise removed; `r_plain`: against the
  replica mean as it is) with its interval and n, the ceiling r a perfect predictor reaches
  against one simulation, the bias (median of method / replica mean - 1) and the paper's r.

Simulations are normalised by their cell count N_c, predictions by their own density sum (the
paper's rule for predicted fields).
"""

from __future__ import annotations

import time
from dataclasses import dataclass

import numpy as np
import pandas as pd

from condor.measures import estimators as est
from condor.data.fields import FIELD_NAMES, normalise
from condor.data.statistics import mould_summary_statistics
from condor.measures.metrics import normalise_predicted, paper_r, statistics_frame
from condor.surrogate.calibration import interval_coverage, spread_agreement, tissue_pixels

ACCURACY_COLUMNS = ("method", "family", "cpu_s_per_mould", "field_error", "field_error_lo",
                    "field_error_hi", "field_error_plain", "field_error_plain_lo",
                    "field_error_plain_hi", "n_moulds")
STATISTICS_COLUMNS = ("method", "family", "statistic", "n", "r", "r_lo", "r_hi", "r_plain",
                      "r_plain_lo", "r_plain_hi", "r_ceiling", "bias", "bias_lo", "bias_hi",
                      "informative", "paper_r", "paper_relation")
HELD_OUT = ((1, "single simulation"), (2, "mean of 2 simulations"), (4, "mean of 4 simulations"))

# The statistics the tables score, in one vocabulary (docs/fields.md, "Whole-mould
# statistics"): condor's, under the names `condor predict` prints (direction, an angle, has no
# r), then the paper's that condor has no name for. Two of the paper's are condor's under
# another name and unit (PAPER_NAME): the paper's r is compared on them as the paper's.
STATISTICS = ("alignment", "alignment_x", "mean_tension", "tissue_area", "mean_P", "mean_T",
              "mean_Sx2", "mean_Sx2_norm", "mean_Sy2", "mean_Sy2_norm")
PAPER_NAME = {"mean_tension": "mean_T_norm", "tissue_area": "n_P_gt_0.2"}  # the paper's name
NOT_THE_PAPERS = ("alignment", "alignment_x")  # no paper r
SIGNED = ("alignment_x",)  # its bias, a ratio to a value about 0, means nothing: NaN


@dataclass(frozen=True)
class Answer:
    """A method's answer for the ensemble's moulds: raw fields (M, 8, H, W) (NaN where it
    failed), CPU seconds per mould (M,), and whether it is a prediction (normalised by its own
    density sum) or a simulation (normalised by N_c)."""

    method: str
    family: str
    raw: np.ndarray
    cpu_s: np.ndarray
    predicted: bool = False


def time_predictor(predict_raw, n_moulds: int, repeats: int = 3) -> tuple[np.ndarray, np.ndarray]:
    """`predict_raw(k)` (the raw answer (1, 8, H, W) for mould k) one mould at a time: the raw
    answers (M, 8, H, W) and the median CPU seconds of `repeats` calls per mould (after one
    untimed warm-up call)."""
    raws, seconds = [], []
    for k in range(n_moulds):
        raw = predict_raw(k)
        times = []
        for _ in range(repeats):
            t0 = time.process_time()
            raw = predict_raw(k)
            times.append(time.process_time() - t0)
        raws.append(np.asarray(raw, dtype=np.float32)[0])
        seconds.append(float(np.median(times)))
    return np.stack(raws), np.array(seconds)


def calibration_row(method: str, mean_raw: np.ndarray, spread_raw: np.ndarray, ensemble,
                    seed: int = 0) -> dict:
    """How a predicted spread map (raw units, (M, 8, H, W)) agrees with the replicas' scatter
    inside the tissue: coverage of the central 50% and 90% intervals around the predicted
    mean (median over moulds, with the pooled fraction and a bootstrap interval) and the r over
    moulds between predicted and replica RMS spread."""
    mask = tissue_pixels(ensemble.inputs)
    coverage = interval_coverage(mean_raw, spread_raw, ensemble.raw, mask)
    agreement = spread_agreement(spread_raw, ensemble.raw, mask)
    row = {"method": method, "n_moulds": int(len(mask))}
    for level, per_mould in coverage.items():
        value, lo, hi = est.bootstrap_interval(per_mould, np.mean, seed=seed)
        row.update({f"coverage_{int(level * 100)}": value, f"coverage_{int(level * 100)}_lo": lo,
                    f"coverage_{int(level * 100)}_hi": hi})
    row.update(spread_r=agreement["r"], spread_ratio=agreement["ratio"],
               spread_pixel_r=float(np.median(agreement["pixel_r"])))
    return row


def _normalised(answer: Answer, n_cells: np.ndarray) -> np.ndarray:
    if answer.predicted:
        return normalise_predicted(answer.raw).astype(np.float64)
    return normalise(answer.raw.astype(np.float64), n_cells)


def statistics_of(raw: np.ndarray, pixel_size: float, n_cells) -> np.ndarray:
    """(M, len(STATISTICS)) of raw fields (M, 8, H, W); n_cells None: own density sums.
    condor's statistics (condor.data.statistics.mould_summary_statistics) of the fields normalised
    by N_c (or the density sum), the paper's (statistics_frame) beside them; NaN for a mould
    whose fields are not finite."""
    raw = np.asarray(raw)
    paper = statistics_frame(raw, pixel_size, n_cells=n_cells)
    ours = np.full((len(raw), len(STATISTICS)), np.nan)
    for m, fields in enumerate(raw):
        fields = np.asarray(fields, dtype=np.float64)
        n = float(fields[0].sum()) if n_cells is None else float(np.asarray(n_cells)[m])
        if not (np.isfinite(fields).all() and np.isfinite(n) and n > 0):
            continue
        values = mould_summary_statistics(normalise(fields, n), n, pixel_size)
        for k, name in enumerate(STATISTICS):
            ours[m, k] = values[name] if name in values else paper[name].iloc[m]
    return ours


def _error_row(method: str, family: str, cpu: float, err: est.SquaredError,
               per_field: np.ndarray, seed: int) -> dict:
    value, lo, hi = est.bootstrap_interval(err.corrected, seed=seed)
    plain, plain_lo, plain_hi = est.bootstrap_interval(err.plain, seed=seed)
    row = {"method": method, "family": family, "cpu_s_per_mould": cpu, "field_error": value,
           "field_error_lo": lo, "field_error_hi": hi, "field_error_plain": plain,
           "field_error_plain_lo": plain_lo, "field_error_plain_hi": plain_hi,
           "n_moulds": int(len(err.corrected))}
    row.update({f"error_{f}": est.root_mean(per_field[:, k]) for k, f in enumerate(FIELD_NAMES)})
    return row


def _statistic_rows(method: str, family: str, answer_stats: np.ndarray,
                    replica_stats: np.ndarray, seed: int) -> list[dict]:
    rows = []
    present = replica_present(replica_stats)
    for k, name in enumerate(STATISTICS):
        # a mould counts when the answer and every replica it holds give the statistic
        usable = np.isfinite(replica_stats[:, :, k]) | ~present
        keep = np.isfinite(answer_stats[:, k]) & usable.all(axis=1) & (present.sum(axis=1) >= 2)
        agreement = est.statistic_agreement(answer_stats[keep, k], replica_stats[keep][:, :, k],
                                            seed=seed) if keep.sum() >= 2 else \
            {"n": int(keep.sum()), "informative": False}
        if name in SIGNED:
            agreement.update(bias=np.nan, bias_lo=np.nan, bias_hi=np.nan)
        reference, relation = ((np.nan, "") if name in NOT_THE_PAPERS else
                               paper_r(PAPER_NAME.get(name, name)))
        rows.append({"method": method, "family": family, "statistic": name, **agreement,
                     "paper_r": reference, "paper_relation": relation})
    return rows


def replica_present(replica_stats: np.ndarray) -> np.ndarray:
    """(M, R) whether each replica exists: replica_stats (M, R, n) is NaN-padded after a
    mould's own replicas (Ensemble)."""
    return ~np.isnan(replica_stats).all(axis=2)


def replica_statistics(ensemble) -> np.ndarray:
    """(M, R, n_statistics) of every replica, NaN where a mould holds fewer than R."""
    out = np.full(ensemble.raw.shape[:2] + (len(STATISTICS),), np.nan)
    counts = ensemble.replica_counts
    for j in range(ensemble.n_replicas):
        has = counts > j
        out[has, j] = statistics_of(ensemble.raw[has, j], ensemble.pixel_size,
                                    ensemble.n_cells[has])
    return out


def accuracy_tables(ensemble, answers, seed: int = 0) -> tuple[pd.DataFrame, pd.DataFrame]:
    """(accuracy, statistics) tables (module docstring) of `answers` on `ensemble`."""
    truth = ensemble.normalised  # (M, R, 8, H, W), NaN-padded
    common = int(ensemble.replica_counts.min())
    replica_stats = replica_statistics(ensemble)
    solver_cpu = float(np.nanmedian(ensemble.seconds))
    accuracy, statistics = [], []
    for k, label in HELD_OUT:
        if k + 2 > common:
            continue
        err = est.held_out_error(truth, k)
        per_field = est.held_out_error(truth, k, per_field=True).corrected
        accuracy.append(_error_row(label, "dataset solver", k * solver_cpu, err, per_field, seed))
        held_stats = replica_stats[:, :k].mean(axis=1)
        statistics += _statistic_rows(label, "dataset solver", held_stats, replica_stats[:, k:],
                                      seed)
    for answer in answers:
        if answer.raw.shape != ensemble.raw.shape[:1] + ensemble.raw.shape[2:]:
            raise ValueError(f"answer {answer.method!r} has shape {answer.raw.shape}, the "
                             f"ensemble's moulds need {ensemble.raw.shape[:1] + ensemble.raw.shape[2:]}")
        normalised = _normalised(answer, ensemble.n_cells)
        ok = np.isfinite(normalised).all(axis=(1, 2, 3))
        if not ok.any():
            continue
        err = est.mse_against_expected(normalised[ok], truth[ok])
        per_field = est.mse_against_expected(normalised[ok], truth[ok], per_field=True).corrected
        accuracy.append(_error_row(answer.method, answer.family,
                                   float(np.median(answer.cpu_s[ok])), err, per_field, seed))
        stats = statistics_of(answer.raw, ensemble.pixel_size,
                            None if answer.predicted else ensemble.n_cells)
        stats[~ok] = np.nan
        statistics += _statistic_rows(answer.method, answer.family, stats, replica_stats, seed)
    return (pd.DataFrame(accuracy), pd.DataFrame(statistics, columns=list(STATISTICS_COLUMNS)))


def score(predictions, dataset, method: str = "predictions", simulated: bool = False,
          seed: int = 0) -> dict:
    """Score your predictions against a condor dataset's expected fields, the finite-replica
    noise removed, with 95% bootstrap intervals over moulds: the same estimators and tables as
    the report's accuracy study (`accuracy_tables`), so the numbers are comparable with it.

    predictions: raw (un-normalised) fields of the dataset's replicated moulds (the test
      moulds), either an array (M, 8, H, W) in the order of `dataset["replicated"]`, or a
      dict {mould id: (8, H, W)} for any of them. Fields are normalised by their own density
      sum (the paper's rule for predicted fields); `simulated=True` normalises them by each
      mould's N_c instead (for a simulator's answers).
    dataset: a store path or condor.open_dataset(...).

    Returns {"accuracy": DataFrame, "statistics": DataFrame, "moulds": ids}: accuracy rows
    `field_error` (RMS over the 8 normalised fields against the expected fields, noise
    removed) with field_error_lo/hi, the plain error and per-field errors, beside the dataset
    solver's own rows ("single simulation" is the noise ceiling); statistics rows: per
    whole-mould statistic, r against the expected statistic with r_lo/r_hi, r_ceiling, bias
    with bias_lo/bias_hi (columns as STATISTICS_COLUMNS)."""
    from condor.studies.recipes import reference_ensemble

    if isinstance(predictions, dict):
        wanted = [int(m) for m in predictions]
        ensemble = reference_ensemble(dataset, moulds=wanted)
        raw = np.stack([np.asarray(predictions[m], dtype=np.float64) for m in ensemble.moulds])
    else:
        ensemble = reference_ensemble(dataset)
        raw = np.asarray(predictions, dtype=np.float64)
        import xarray as xr

        ds = dataset if isinstance(dataset, xr.Dataset) else None
        if ds is None:
            from condor.data.store import open_store

            ds = open_store(dataset)
        order = [int(m) for m in ds["replicated"].values] if "replicated" in ds.coords else []
        if raw.shape[0] != len(order):
            raise ValueError(f"predictions hold {raw.shape[0]} moulds; the dataset has "
                             f"{len(order)} replicated (test) moulds, in the order of "
                             "dataset['replicated'] (or pass a dict {mould id: fields})")
        raw = raw[[order.index(int(m)) for m in ensemble.moulds]]
    expected_shape = ensemble.raw.shape[:1] + ensemble.raw.shape[2:]
    if raw.shape != expected_shape:
        raise ValueError(f"predictions have shape {raw.shape}, the dataset's moulds need "
                         f"{expected_shape} (raw fields, 8 per mould)")
    answer = Answer(method, "yours", raw, np.full(len(raw), np.nan), predicted=not simulated)
    accuracy, statistics = accuracy_tables(ensemble, [answer], seed=seed)
    return {"accuracy": accuracy, "statistics": statistics, "moulds": ensemble.moulds}
