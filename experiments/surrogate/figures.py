"""Figures of docs/surrogate.md from the study's checkpoints and the replicas.

    PYTHONPATH=src python experiments/surrogate/figures.py --store S --replicas R.npz \\
        --results DIR/results.csv --checkpoints A.pt B.pt --labels A B --out docs/figures

- surrogate_bias.png: per cause-study run, the bias of each whole-mould statistic against the
  replica means (median over test moulds of predicted / replica mean - 1), from results.csv;
- surrogate_difference.png: prediction - replica mean of one mould's Sx2 and T for each
  checkpoint, beside the replica mean (the checkerboard of transposed convolutions shows);
- surrogate_spread.png: the last checkpoint's predicted spread of P and Sx2 beside the
  replicas' standard deviation, for two moulds.
"""

from __future__ import annotations

import argparse
from pathlib import Path

import matplotlib

matplotlib.use("Agg")
import matplotlib.pyplot as plt  # noqa: E402
import numpy as np  # noqa: E402
import pandas as pd  # noqa: E402

from condor.data.dataset import open_dataset  # noqa: E402
from condor.surrogate.samples import FIELD_NAMES  # noqa: E402
from condor.surrogate.predict import Predictor  # noqa: E402

STATS = ("mean_P", "n_P_gt_0.2", "mean_T", "mean_Sx2", "mean_Sy2", "mean_T_norm")


def bias_figure(results: Path, names, out: Path) -> None:
    rows = pd.read_csv(results).drop_duplicates(subset=["name", "epochs", "mode", "symmetrise"],
                                                keep="last")
    rows = rows[rows["mode"] == "eval"]
    fig, ax = plt.subplots(figsize=(9, 3.6))
    width = 0.8 / len(STATS)
    labels = []
    for i, name in enumerate(names):
        sel = rows[(rows["name"] == name) & rows["symmetrise"]]
        if sel.empty:
            continue
        row = sel.iloc[-1]
        labels.append(name)
        for k, stat in enumerate(STATS):
            b, lo, hi = (row[f"{stat}:{key}"] * 100 for key in ("bias", "bias_lo", "bias_hi"))
            ax.bar(len(labels) - 1 + (k - len(STATS) / 2 + 0.5) * width, b, width,
                   yerr=[[b - lo], [hi - b]], color=f"C{k}", label=stat if len(labels) == 1 else None,
                   error_kw={"lw": 0.7})
    ax.axhspan(-1, 1, color="0.85", zorder=0)
    ax.axhline(0, color="k", lw=0.6)
    ax.set_xticks(range(len(labels)), labels, rotation=15, fontsize=8)
    ax.set_ylabel("bias, % (median predicted / replica mean - 1)")
    ax.legend(fontsize=7, ncol=3)
    ax.set_title("whole-mould statistics against the replica means, 24 test moulds (grey: |bias| <= 1%)",
                 fontsize=9)
    fig.tight_layout()
    fig.savefig(out, dpi=90)
    plt.close(fig)


def predictions(checkpoints, inputs, n_cells):
    return [Predictor(c)(inputs, n_cells=n_cells) for c in checkpoints]


def difference_figure(preds, labels, replica_mean, mould, mould_id, out: Path) -> None:
    fields = ("Sx2", "T")
    fig, axes = plt.subplots(len(fields), len(preds) + 1, figsize=(2.6 * (len(preds) + 1), 5))
    for row, field in zip(axes, fields):
        k = FIELD_NAMES.index(field)
        truth = replica_mean[mould, k]
        im = row[0].imshow(truth, origin="lower")
        row[0].set_title(f"{field}: replica mean", fontsize=8)
        plt.colorbar(im, ax=row[0], fraction=0.046)
        span = max(np.abs(p.raw[mould, k] - truth).max() for p in preds)
        for ax, p, label in zip(row[1:], preds, labels):
            im = ax.imshow(p.raw[mould, k] - truth, origin="lower", cmap="RdBu_r", vmin=-span, vmax=span)
            ax.set_title(f"{label}: prediction - mean", fontsize=8)
            plt.colorbar(im, ax=ax, fraction=0.046)
    for ax in axes.flat:
        ax.set_xticks([]), ax.set_yticks([])
    fig.suptitle(f"test mould {mould_id}: difference maps against the mean of 8 replicas", fontsize=9)
    fig.tight_layout()
    fig.savefig(out, dpi=80)
    plt.close(fig)


def spread_figure(pred, replicas, moulds, mould_ids, out: Path) -> None:
    fields = ("P", "Sx2")
    std = replicas.std(axis=1, ddof=1)
    fig, axes = plt.subplots(len(moulds), 2 * len(fields), figsize=(10, 2.5 * len(moulds)))
    for row, m in zip(np.atleast_2d(axes), moulds):
        for j, field in enumerate(fields):
            k = FIELD_NAMES.index(field)
            hi = max(std[m, k].max(), pred.spread[m, k].max())
            for ax, image, label in ((row[2 * j], pred.spread[m, k], "predicted spread"),
                                     (row[2 * j + 1], std[m, k], "replica std (8 runs)")):
                im = ax.imshow(image, origin="lower", vmin=0, vmax=hi, cmap="magma")
                ax.set_title(f"{mould_ids[m]} {field}: {label}", fontsize=8)
                ax.set_xticks([]), ax.set_yticks([])
                plt.colorbar(im, ax=ax, fraction=0.046)
    fig.tight_layout()
    fig.savefig(out, dpi=80)
    plt.close(fig)


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--store", required=True)
    ap.add_argument("--replicas", required=True)
    ap.add_argument("--results")
    ap.add_argument("--bias-runs", nargs="*", default=[])
    ap.add_argument("--checkpoints", nargs="+", required=True)
    ap.add_argument("--labels", nargs="+", required=True)
    ap.add_argument("--mould", type=int, default=47, help="mould id of the difference maps")
    ap.add_argument("--spread-moulds", type=int, nargs="+", default=[47, 12])
    ap.add_argument("--out", required=True)
    args = ap.parse_args()
    out = Path(args.out)
    out.mkdir(parents=True, exist_ok=True)
    if args.results and args.bias_runs:
        bias_figure(Path(args.results), args.bias_runs, out / "surrogate_bias.png")
    data = np.load(args.replicas)
    ids = list(data["mould_ids"])
    replicas = data["fields"].astype(np.float64)
    ds = open_dataset(args.store)
    inputs = np.asarray(ds["inputs"].isel(sample=ids).values, dtype=np.float32)
    n_cells = np.asarray(ds["n_cells"].values)[ids]
    preds = predictions(args.checkpoints, inputs, n_cells)
    difference_figure(preds, args.labels, replicas.mean(1), ids.index(args.mould), args.mould,
                      out / "surrogate_difference.png")
    if preds[-1].spread is not None:
        spread_figure(preds[-1], replicas, [ids.index(m) for m in args.spread_moulds], ids,
                      out / "surrogate_spread.png")


if __name__ == "__main__":
    main()
