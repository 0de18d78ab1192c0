"""Evaluation on the test split, as the paper reports it: per-field MAE per sample, the best
and worst samples for Sx2 and T, and whole-mould statistics (condor.fields.mould_statistics)
of simulation against prediction with their Pearson r, next to the paper's values. Baselines
(baselines.py) and BatchNorm/dropout prediction modes are evaluated with the same metrics."""

from __future__ import annotations

import time
from dataclasses import dataclass
from pathlib import Path

import numpy as np
import pandas as pd

from .baselines import MaskedMeanBaseline, MouldBlurBaseline
from .data import FIELD_NAMES, check_dataset, dataset_pixel_size, usable_samples
from .predict import Predictor

# The paper's Pearson r (Results): 0.881 for mean density, "above 0.98" for the others.
PAPER_R_MEAN_DENSITY = 0.881
PAPER_R_OTHERS_ABOVE = 0.98
BEST_WORST_FIELDS = ("Sx2", "T")


def pearson_r(x, y) -> float:
    """The paper's r_xy (computational form, in float64); NaN when either side is constant."""
    x = np.asarray(x, dtype=np.float64)
    y = np.asarray(y, dtype=np.float64)
    n = x.size
    num = n * (x * y).sum() - x.sum() * y.sum()
    den = np.sqrt(n * (x * x).sum() - x.sum() ** 2) * np.sqrt(n * (y * y).sum() - y.sum() ** 2)
    return float(num / den) if den > 0 else float("nan")


def mae_frame(pred: np.ndarray, true: np.ndarray, sample_ids, field_names=FIELD_NAMES) -> pd.DataFrame:
    """MAE = mean over pixels |Z_C - Z_ML| per sample (rows) and field (columns), plus "mean"
    over fields. pred, true: (S, 8, H, W) physical units."""
    if pred.shape != true.shape:
        raise ValueError(f"prediction shape {pred.shape} != truth shape {true.shape}")
    mae = np.abs(pred.astype(np.float64) - true).mean(axis=(2, 3))
    frame = pd.DataFrame(mae, columns=list(field_names), index=pd.Index(list(sample_ids), name="sample"))
    frame["mean"] = frame[list(field_names)].mean(axis=1)
    return frame


def statistics_frame(fields: np.ndarray, pixel_size: float, sample_ids=None, n_cells=None,
                     statistics_fn=None) -> pd.DataFrame:
    """Whole-mould statistics per sample (rows) via `statistics_fn` (default
    condor.fields.mould_statistics). A sample the function rejects (e.g. a predicted density
    that sums to <= 0) gets NaN."""
    if statistics_fn is None:
        from condor.fields import mould_statistics as statistics_fn
    rows = []
    for s, f in enumerate(fields):
        try:
            rows.append(statistics_fn(f, pixel_size, None if n_cells is None else float(n_cells[s])))
        except ValueError:
            rows.append({})
    index = pd.Index(list(range(len(fields)) if sample_ids is None else sample_ids), name="sample")
    return pd.DataFrame(rows, index=index)


def paper_r(statistic: str) -> tuple[float, str]:
    """The paper's r for a statistic and how it is stated: ("=", 0.881) or (">", 0.98)."""
    if statistic == "mean_P":
        return PAPER_R_MEAN_DENSITY, "="
    return PAPER_R_OTHERS_ABOVE, ">"


def correlation_table(sim: pd.DataFrame, pred: pd.DataFrame) -> pd.DataFrame:
    """Per statistic: Pearson r of simulated vs predicted values (samples with NaN dropped)
    and the paper's value."""
    rows = []
    for name in sim.columns:
        ok = np.isfinite(sim[name].to_numpy(float)) & np.isfinite(pred[name].to_numpy(float))
        reference, relation = paper_r(name)
        rows.append({"statistic": name, "r": pearson_r(sim[name][ok], pred[name][ok]),
                     "n": int(ok.sum()), "paper_r": reference, "paper_relation": relation})
    return pd.DataFrame(rows).set_index("statistic")


def best_worst(mae: pd.DataFrame, field: str, n: int = 6) -> tuple[list, list]:
    """Sample ids of the n lowest and n highest MAE for `field` (best first, worst first)."""
    ordered = mae[field].sort_values(kind="stable")
    return list(ordered.index[:n]), list(ordered.index[::-1][:n])


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


# --- figures -------------------------------------------------------------------------------

def _pyplot():
    import matplotlib
    matplotlib.use("Agg")
    import matplotlib.pyplot as plt
    return plt


def plot_mae_distribution(mae: pd.DataFrame, path, title: str = ""):
    """Histogram of per-sample MAE, one panel per field."""
    plt = _pyplot()
    fields = [c for c in mae.columns if c != "mean"]
    fig, axes = plt.subplots(2, (len(fields) + 1) // 2, figsize=(12, 5))
    for ax, name in zip(axes.flat, fields):
        ax.hist(mae[name], bins=min(20, max(5, len(mae) // 3)), color="tab:blue")
        ax.set_title(f"{name}: median {mae[name].median():.3g}", fontsize=9)
        ax.set_xlabel("MAE")
    fig.suptitle(title or "per-sample MAE (test split)")
    fig.tight_layout()
    fig.savefig(path, dpi=100)
    plt.close(fig)


def plot_best_worst(mae: pd.DataFrame, true: np.ndarray, pred: np.ndarray, field: str, path,
                    which: str = "best", n: int = 6):
    """Rows: the n best (or worst) samples by MAE of `field`; columns: simulation,
    prediction, difference (prediction - simulation). true/pred rows follow mae's index."""
    plt = _pyplot()
    best, worst = best_worst(mae, field, n)
    ids = best if which == "best" else worst
    k = FIELD_NAMES.index(field)
    position = {sid: i for i, sid in enumerate(mae.index)}
    fig, axes = plt.subplots(len(ids), 3, figsize=(7.5, 2.3 * len(ids)), squeeze=False)
    for row, sid in zip(axes, ids):
        sim, prd = true[position[sid], k], pred[position[sid], k]
        lo, hi = min(sim.min(), prd.min()), max(sim.max(), prd.max())
        diff = prd - sim
        span = np.abs(diff).max() or 1.0
        for ax, image, label, kw in ((row[0], sim, "simulation", {"vmin": lo, "vmax": hi}),
                                     (row[1], prd, "prediction", {"vmin": lo, "vmax": hi}),
                                     (row[2], diff, "difference", {"vmin": -span, "vmax": span,
                                                                   "cmap": "RdBu_r"})):
            im = ax.imshow(image, origin="lower", **kw)
            ax.set_xticks([]), ax.set_yticks([])
            ax.set_title(f"{sid}: {label}" + (f" (MAE {mae.loc[sid, field]:.3g})"
                                               if label == "difference" else ""), fontsize=8)
            fig.colorbar(im, ax=ax, fraction=0.046)
    fig.suptitle(f"{field}: {n} {which} test samples by MAE")
    fig.tight_layout()
    fig.savefig(path, dpi=90)
    plt.close(fig)


def plot_statistics_scatter(ev: Evaluation, path):
    """Simulated vs predicted whole-mould statistics, with r and a dashed y = x."""
    plt = _pyplot()
    names = list(ev.sim_statistics.columns)
    fig, axes = plt.subplots(2, (len(names) + 1) // 2, figsize=(3 * ((len(names) + 1) // 2), 6))
    for ax, name in zip(axes.flat, names):
        x, y = ev.sim_statistics[name], ev.pred_statistics[name]
        ax.scatter(x, y, s=10)
        lo, hi = np.nanmin([x.min(), y.min()]), np.nanmax([x.max(), y.max()])
        ax.plot([lo, hi], [lo, hi], "k--", lw=0.8)
        ax.set_title(f"{name}: r = {ev.correlations.loc[name, 'r']:.3f}", fontsize=9)
        ax.set_xlabel("simulation", fontsize=8)
        ax.set_ylabel("prediction", fontsize=8)
    fig.suptitle(f"whole-mould statistics, {ev.method}")
    fig.tight_layout()
    fig.savefig(path, dpi=100)
    plt.close(fig)


def write_figures(ev: Evaluation, true: np.ndarray, pred: np.ndarray, out_dir) -> list[Path]:
    out = Path(out_dir)
    out.mkdir(parents=True, exist_ok=True)
    paths = [out / f"{ev.method}_mae_distribution.png", out / f"{ev.method}_statistics.png"]
    plot_mae_distribution(ev.mae, paths[0], f"per-sample MAE, {ev.method}")
    plot_statistics_scatter(ev, paths[1])
    for field in BEST_WORST_FIELDS:
        for which in ("best", "worst"):
            paths.append(out / f"{ev.method}_{field}_{which}.png")
            plot_best_worst(ev.mae, true, pred, field, paths[-1], which)
    return paths


# --- the whole evaluation ------------------------------------------------------------------

def _arrays(ds, indices) -> tuple[np.ndarray, np.ndarray, list]:
    sel = ds.isel(sample=indices)
    ids = list(sel["sample"].values) if "sample" in sel.coords else list(indices)
    return (np.asarray(sel["inputs"].values, dtype=np.float32),
            np.asarray(sel["fields"].values, dtype=np.float32), ids)


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
    """fn() and its wall seconds per mould (n moulds)."""
    t0 = time.perf_counter()
    result = fn()
    return result, (time.perf_counter() - t0) / max(n, 1)


def _finish(predictions: dict, seconds: dict, true, ids, pixel_size, statistics_fn, out_dir,
            figure_dir) -> dict:
    """Metrics for every method; with out_dir, summary.csv, <method>_mae.csv and
    <method>_correlations.csv there and the figures in figure_dir (default out_dir)."""
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
            write_figures(ev, true, predictions[method], figure_dir or out)
    return {"evaluations": evaluations, "summary": summary}


def baseline_predictions(ds, inputs: np.ndarray, pixel_size: float) -> tuple[dict, dict]:
    """Each baseline fitted on the "train" split and applied to `inputs`:
    ({name: fields}, {name: prediction seconds per mould})."""
    train_inputs, train_fields, _ = _arrays(ds, usable_samples(ds, "train"))
    predictions, seconds = {}, {}
    for baseline in (MaskedMeanBaseline(), MouldBlurBaseline(pixel_size)):
        fitted = baseline.fit(train_inputs, train_fields)
        predictions[baseline.name], seconds[baseline.name] = _timed(
            lambda: fitted.predict(inputs), len(inputs))
    return predictions, seconds


def evaluate(checkpoint_path, ds, out_dir=None, split: str = "test", modes=None,
             baselines: bool = True, pixel_size: float | None = None, statistics_fn=None,
             device=None, name: str | None = None, figure_dir=None) -> dict:
    """Evaluate a checkpoint (in each prediction mode of `modes`, default the checkpoint's
    own and "train", as reference pix2pix predicts) and the baselines on `split`.

    Methods are named f"{name}_{mode}" (name defaults to the checkpoint's model kind).
    Returns {"evaluations": {method: Evaluation}, "summary": DataFrame (method rows, with
    seconds_per_mould: wall time of the whole-split prediction / moulds)}; with `out_dir`,
    also writes per-sample MAE CSVs, correlation CSVs, summary.csv, and figures (into
    `figure_dir`, default out_dir).
    """
    inputs, true, ids = _test_arrays(ds, split)
    pixel_size = dataset_pixel_size(ds) if pixel_size is None else pixel_size
    predictor = Predictor(checkpoint_path, device=device)
    modes = modes or list(dict.fromkeys([predictor.mode, "train"]))
    name = name or predictor.state["config"]["model"]
    predictions, seconds = {}, {}
    for mode in modes:
        predictor.mode = mode
        method = f"{name}_{mode}"
        predictions[method], seconds[method] = _timed(lambda: predictor(inputs).raw, len(inputs))
    if baselines:
        more, more_seconds = baseline_predictions(ds, inputs, pixel_size)
        predictions.update(more)
        seconds.update(more_seconds)
    return _finish(predictions, seconds, true, ids, pixel_size, statistics_fn, out_dir, figure_dir)


def evaluate_baselines(ds, out_dir=None, split: str = "test", pixel_size: float | None = None,
                       statistics_fn=None, figure_dir=None) -> dict:
    """The baselines alone, with the same metrics and files as `evaluate`."""
    inputs, true, ids = _test_arrays(ds, split)
    pixel_size = dataset_pixel_size(ds) if pixel_size is None else pixel_size
    predictions, seconds = baseline_predictions(ds, inputs, pixel_size)
    return _finish(predictions, seconds, true, ids, pixel_size, statistics_fn, out_dir, figure_dir)


def combine_summaries(paths) -> pd.DataFrame:
    """Concatenate summary.csv files (one row per method) into one table; a method that
    appears twice raises ValueError naming it."""
    frame = pd.concat([pd.read_csv(p, index_col="method") for p in paths])
    repeated = frame.index[frame.index.duplicated()].unique().tolist()
    if repeated:
        raise ValueError(f"method(s) {repeated} appear in more than one summary")
    return frame


def format_summary(summary: pd.DataFrame, field_names=FIELD_NAMES) -> str:
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
