"""How well 24 test moulds resolve a whole-mould statistic's bias, and whether a correction
fitted on the val split removes it (docs/surrogate.md "In the default run").

    PYTHONPATH=src python experiments/surrogate/bias.py --store STORE \\
        --replicas REPLICAS.npz CHECKPOINT [CHECKPOINT ...] [--out CSV]

Per checkpoint and statistic: r and bias (median of predicted / replica mean - 1) against the
test moulds' replica means (condor.measures.estimators.statistic_agreement); the MAD (x 1.4826) of the
per-mould ratios and the median's standard error from it (1.2533 MAD / sqrt(M), the
normal approximation); the slope of log(replica mean) on log(predicted) (above 1: the
predictions are shrunk towards the average); and two corrections fitted on the val split's
moulds (one simulation each) then applied to the test moulds: a gain 1 / (1 + val bias), and
log(true) = a + b log(predicted) by least absolute deviations. Replicas come from
experiments/surrogate/replicas.py --from-store.
"""

from __future__ import annotations

import argparse

import numpy as np
import pandas as pd

from condor.data.dataset import open_dataset
from condor.measures.estimators import statistic_agreement
from condor.data.statistics import STATISTICS
from condor.studies.scoring import predict_replica_moulds, statistics_of, study_dataset
from condor.surrogate.samples import dataset_pixel_size

CHECKED = ("n_P_gt_0.2", "mean_T", "mean_Sx2", "mean_Sy2")
MAD_TO_SD = 1.4826  # a normal's standard deviation over its median absolute deviation
MEDIAN_SE = 1.2533  # a median's standard error over the mean's (sqrt(pi / 2)), normal draws


def robust_spread(values: np.ndarray) -> float:
    return float(MAD_TO_SD * np.median(np.abs(values - np.median(values))))


def lad_line(x: np.ndarray, y: np.ndarray, slopes=np.linspace(0.7, 1.4, 141)) -> tuple[float, float]:
    """(a, b) of y = a + b x by least absolute deviations: for each slope on the grid the best
    intercept is the median residual."""
    best = min(((np.abs(y - np.median(y - b * x) - b * x).sum(), b) for b in slopes))
    b = best[1]
    return float(np.median(y - b * x)), float(b)


def bias_rows(checkpoint, ds, mould_ids, replica_stats, val_ids, val_truth, pixel) -> list[dict]:
    pred = statistics_of(predict_replica_moulds(checkpoint, ds, mould_ids), pixel)
    val_pred = statistics_of(predict_replica_moulds(checkpoint, ds, val_ids), pixel)
    rows = []
    for name in CHECKED:
        k = STATISTICS.index(name)
        truth = replica_stats[:, :, k]
        mean = truth.mean(axis=1)
        agree = statistic_agreement(pred[:, k], truth, n_boot=500)
        ratio = pred[:, k] / mean - 1
        val_ratio = val_pred[:, k] / val_truth[:, k] - 1
        gain = 1 / (1 + np.median(val_ratio))
        positive = (val_pred[:, k] > 0) & (val_truth[:, k] > 0)
        a, b = lad_line(np.log(val_pred[positive, k]), np.log(val_truth[positive, k]))
        mapped = np.exp(a) * np.clip(pred[:, k], 1e-300, None) ** b
        spread = robust_spread(ratio)
        rows.append({
            "checkpoint": str(checkpoint), "statistic": name, "n": len(mean),
            "r": agree["r"], "r_ceiling": agree["r_ceiling"], "bias": agree["bias"],
            "bias_lo": agree["bias_lo"], "bias_hi": agree["bias_hi"],
            "ratio_spread": spread, "bias_se": MEDIAN_SE * spread / np.sqrt(len(mean)),
            "log_slope": float(np.polyfit(np.log(pred[:, k]), np.log(mean), 1)[0]),
            "val_n": len(val_ratio), "val_bias": float(np.median(val_ratio)),
            "val_ratio_spread": robust_spread(val_ratio),
            "gain": gain, "gain_bias": float(np.median(pred[:, k] * gain / mean - 1)),
            "map_a": a, "map_b": b, "map_r": float(np.corrcoef(mapped, mean)[0, 1]),
            "map_bias": float(np.median(mapped / mean - 1))})
    return rows


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("checkpoints", nargs="+")
    ap.add_argument("--store", required=True)
    ap.add_argument("--replicas", required=True)
    ap.add_argument("--out", help="CSV of the rows")
    args = ap.parse_args()
    data = np.load(args.replicas)
    ds = study_dataset(open_dataset(args.store), data["mould_ids"])
    pixel = dataset_pixel_size(ds)
    replica_stats = statistics_of(data["fields"].astype(np.float64), pixel)
    first = np.asarray(ds["replica"].values) == 0
    val = first & (np.asarray(ds["split"].values).astype(str) == "val")
    val_ids = np.asarray(ds["mould"].values)[val]
    val_truth = statistics_of(np.asarray(ds["fields"].isel(sample=np.flatnonzero(val)).values,
                                         np.float64), pixel)
    rows = [row for c in args.checkpoints
            for row in bias_rows(c, ds, data["mould_ids"], replica_stats, val_ids, val_truth,
                                 pixel)]
    table = pd.DataFrame(rows)
    if args.out:
        table.to_csv(args.out, index=False)
    print(table.drop(columns="checkpoint").round(4).to_string(index=False))


if __name__ == "__main__":
    main()
