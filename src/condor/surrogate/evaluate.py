"""Evaluation on the test split, as the paper reports it: per-field MAE per sample, the best
and worst samples for Sx2 and T, and whole-mould statistics
(condor.data.statistics.mould_statistics) of simulation against prediction with their Pearson
r, next to the paper's values. Baselines (baselines.py) and BatchNorm/dropout prediction modes
are evaluated with the same metrics."""

from __future__ import annotations

import time
from dataclasses import dataclass
from pathlib import Path

import numpy as np
import pandas as pd

from condor.measures.estimators import pearson_r  # noqa: F401  (re-exported: the paper's r)
from condor.measures.metrics import (best_worst, correlation_table, mae_frame,  # noqa: F401
                            paper_r, statistics_frame)

from .baselines import fit_baselines
from .samples import (FIELD_NAMES, check_dataset, dataset_pixel_size, model_inputs, read_samples,
                      usable_samples)
from .predict import Predictor



@dataclass
class Evaluation:
    method: str
    mae: pd.DataFrame  # per sample x field
    sim_statistics: pd.DataFrame
    pred_statistics: pd.DataFrame
    correlations: pd.DataFrame

    def summary(self) -> dict:
        """One row for a comparison table: mean MAE per field and r per statistic."""
        row = {"method": self.method, **{f"mae_{k}": v for k, v in self.mae.mean().items()}}
        row.update({f"r_{k}": v for k, v in self.correlations["r"].items()})
        return row


def evaluate_predictions(pred, true, sample_ids, pixel_size: float, method: str,
                         statistics_fn=None) -> Evaluation:
    """All metrics for predictions `pred` against simulations `true` (S, 8, H, W). Both sides'
    normalised statistics use N_c = sum of their own P, as a prediction must."""
    sim_stats = statistics_frame(true, pixel_size, sample_ids, statistics_fn=statistics_fn)
    pred_stats = statistics_frame(pred, pixel_size, sample_ids, statistics_fn=statistics_fn)
    pred_stats = pred_stats.reindex(columns=sim_stats.columns)
    return Evaluation(method, mae_frame(pred, true, sample_ids), sim_stats, pred_stats,
                      correlation_table(sim_stats, pred_stats))


# --- the whole evaluation ------------------------------------------------------------------

def _arrays(ds, indices) -> tuple[np.ndarray, np.ndarray, list]:
    ids = list(ds["sample"].values[indices]) if "sample" in ds.coords else list(indices)
    inputs, fields = read_samples(ds, indices, lambda sel: (
        np.asarray(sel["inputs"].values, dtype=np.float32),
        np.asarray(sel["fields"].values, dtype=np.float32)))
    return inputs, fields, ids


def _test_arrays(ds, split: str):
    """Inputs, the truth and the sample ids of `split`. The truth is a mould's expected fields
    (the store's `fields_mean`, the mean of its replicas) where the store has them, else its
    one simulation."""
    check_dataset(ds)
    test_idx = usable_samples(ds, split)
    if len(test_idx) == 0:
        raise ValueError(f"dataset has no usable samples in split {split!r}")
    inputs, fields, ids = _arrays(ds, test_idx)
    if "fields_mean" in ds and "mould" in ds:
        position = {int(m): k for k, m in enumerate(ds["replicated"].values)}
        counts = ds["n_replicas_ok"].values
        for row, mould in enumerate(ds["mould"].values[test_idx]):
            k = position.get(int(mould))
            if k is not None and counts[k] >= 2:
                fields[row] = ds["fields_mean"].isel(replicated=k).values
    return inputs, fields, ids


def _timed(fn, n: int):
    """fn() and its CPU seconds per mould (n moulds): the cost unit of every study."""
    t0 = time.process_time()
    result = fn()
    return result, (time.process_time() - t0) / max(n, 1)


def _finish(predictions: dict, seconds: dict, true, ids, pixel_size, statistics_fn, out_dir) -> dict:
    """Metrics for every method; with out_dir, summary.csv, <method>_mae.csv and
    <method>_correlations.csv there. Returns the evaluations, the summary, and the truth and
    predictions the figures draw (condor.plots.evaluation_figures)."""
    evaluations = {m: evaluate_predictions(p, true, ids, pixel_size, m, statistics_fn)
                   for m, p in predictions.items()}
    summary = pd.DataFrame([{**ev.summary(), "seconds_per_mould": seconds[m]}
                            for m, ev in evaluations.items()]).set_index("method")
    if out_dir is not None:
        out = Path(out_dir)
        out.mkdir(parents=True, exist_ok=True)
        summary.to_csv(out / "summary.csv")
        for method, ev in evaluations.items():
            ev.mae.to_csv(out / f"{method}_mae.csv")
            ev.correlations.to_csv(out / f"{method}_correlations.csv")
    return {"evaluations": evaluations, "summary": summary, "truth": true,
            "predictions": predictions}


def baseline_predictions(ds, inputs: np.ndarray, pixel_size: float) -> tuple[dict, dict]:
    """Each baseline fitted on the "train" split and applied to `inputs`:
    ({name: fields}, {name: prediction seconds per mould})."""
    train_inputs, train_fields, _ = _arrays(ds, usable_samples(ds, "train"))
    predictions, seconds = {}, {}
    for fitted in fit_baselines(train_inputs, train_fields, pixel_size):
        predictions[fitted.name], seconds[fitted.name] = _timed(
            lambda: fitted.predict(inputs), len(inputs))
    return predictions, seconds


def evaluate(checkpoint_path, ds, out_dir=None, split: str = "test", modes=None,
             baselines: bool = True, pixel_size: float | None = None, statistics_fn=None,
             device=None, name: str | None = None) -> dict:
    """Evaluate a checkpoint (in each prediction mode of `modes`, default the checkpoint's
    own and "train", as reference pix2pix predicts) and the baselines on `split`.

    Methods are named f"{name}_{mode}" (name defaults to the checkpoint's network kind).
    Returns {"evaluations": {method: Evaluation}, "summary": DataFrame (method rows, with
    seconds_per_mould: CPU time of the whole-split prediction / moulds)}; with `out_dir`,
    also writes per-sample MAE CSVs, correlation CSVs and summary.csv.
    """
    inputs, true, ids = _test_arrays(ds, split)
    n_cells = np.asarray(ds["n_cells"].values)[usable_samples(ds, split)] if "n_cells" in ds else None
    pixel_size = dataset_pixel_size(ds) if pixel_size is None else pixel_size
    predictor = Predictor(checkpoint_path, device=device)
    lattice = model_inputs(ds, usable_samples(ds, split), "lattice") if predictor.needs_lattice \
        else None
    modes = modes or list(dict.fromkeys([predictor.mode, "train"]))
    name = name or predictor.state["config"]["network"]
    predictions, seconds = {}, {}
    for mode in modes:
        predictor.mode = mode
        method = f"{name}_{mode}"
        predictions[method], seconds[method] = _timed(
            lambda: predictor(inputs, n_cells=n_cells, lattice=lattice).raw, len(inputs))
    if baselines:
        more, more_seconds = baseline_predictions(ds, inputs, pixel_size)
        predictions.update(more)
        seconds.update(more_seconds)
    return _finish(predictions, seconds, true, ids, pixel_size, statistics_fn, out_dir)


def evaluate_baselines(ds, out_dir=None, split: str = "test", pixel_size: float | None = None,
                       statistics_fn=None) -> dict:
    """The baselines alone, with the same metrics and files as `evaluate`."""
    inputs, true, ids = _test_arrays(ds, split)
    pixel_size = dataset_pixel_size(ds) if pixel_size is None else pixel_size
    predictions, seconds = baseline_predictions(ds, inputs, pixel_size)
    return _finish(predictions, seconds, true, ids, pixel_size, statistics_fn, out_dir)


def combine_summaries(paths) -> pd.DataFrame:
    """Concatenate summary.csv files (one row per method) into one table; a method that
    appears twice raises ValueError naming it."""
    frame = pd.concat([pd.read_csv(p, index_col="method") for p in paths])
    repeated = frame.index[frame.index.duplicated()].unique().tolist()
    if repeated:
        raise ValueError(f"method(s) {repeated} appear in more than one summary")
    return frame


def format_evaluation(summary: pd.DataFrame, field_names=FIELD_NAMES) -> str:
    """Text table: mean MAE per field (columns) for each method (rows), with the mean over
    fields and the ratio of each method's mean MAE to the best baseline's."""
    columns = [f"mae_{k}" for k in field_names] + ["mae_mean"]
    table = summary[columns].rename(columns=lambda c: c[4:])
    baselines = [m for m in ("masked_mean", "mould_blur") if m in table.index]
    if baselines:
        table["vs_best_baseline"] = table["mean"] / table.loc[baselines, "mean"].min()
    if "seconds_per_mould" in summary:
        table["ms_per_mould"] = summary["seconds_per_mould"] * 1e3
    return table.to_string(float_format=lambda v: f"{v:.4g}")


def format_correlations(summary: pd.DataFrame) -> str:
    """Text table: Pearson r per statistic (rows) for each method (columns) and the paper's."""
    r_columns = [c for c in summary.columns if c.startswith("r_")]
    table = summary[r_columns].T.rename(index=lambda c: c[2:])
    table["paper"] = [("= " if paper_r(s)[1] == "=" else "> ") + f"{paper_r(s)[0]:g}"
                      for s in table.index]
    return table.to_string(float_format=lambda v: f"{v:.3f}")
