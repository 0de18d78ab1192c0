"""Learning curves of the surrogate against the expected fields: test error against the number
of training moulds, the model size and the epochs; writes the small tables docs/surrogate.md
shows (experiments/surrogate/surrogate_curve_*.csv) from the rows of experiments/surrogate/study.py.

    # the runs (each appends to DIR/results.csv; see --help of experiments/surrogate/study.py)
    PYTHONPATH=src python experiments/surrogate/curves.py run data --out DIR \\
        --store BIG_STORE --val-store DEFAULT_STORE --replicas REPLICAS.npz
    PYTHONPATH=src python experiments/surrogate/curves.py run size --out DIR ...
    # the three curves from three kinds of run: the data curve's default-sized run also gives
    # the epoch curve (--epochs-at) and the size curve's base-32 point (--n-train 194)
    ... run data --sizes 194 --epochs-at 30 60 120 180 --store BIG_STORE --val-store ...
    ... run size --bases 16 48 --n-train 194 --store BIG_STORE --val-store ...
    # the tables
    PYTHONPATH=src python experiments/surrogate/curves.py tables --out DIR [--docs experiments/surrogate]

Curves share the default's settings (config/config.yaml, variant `unet`) and change one thing:
- data: the first n training moulds of BIG_STORE (built by the workflow with
  `--config n_moulds=960`: the same seed gives the same first moulds), n in --sizes, each
  trained for the same number of optimiser steps as the default (epochs = default epochs x
  default training moulds / n), so that only the data changes;
- size: U-Net base width in --bases on the default store's training moulds (or the first
  --n-train of --store, as the data curve takes them);
- epochs: one default run evaluated at --epochs-at snapshots (`run epochs`, or `run data`
  with --epochs-at: the run of the default's 194 moulds is then snapshotted).
`tables` completes the size and epoch curves with the data curve's default-sized run
(data_194) where they lack it: its final row is the size curve's default width, its
snapshots the epoch curve.
"""

from __future__ import annotations

import argparse
import json
import subprocess
import sys
from pathlib import Path

import pandas as pd

from condor.config import Config
from condor.plots import learning_curves

REPO = Path(__file__).resolve().parents[2]
DEFAULT_TRAIN_MOULDS = 194  # the default store's training split (240 moulds, 24 test, 22 val)
COLUMNS = ["n_train", "epochs", "parameters", "train_seconds_total", "field_rms", "field_rms_lo",
           "field_rms_hi", "ceiling_rms", "error_over_ceiling", "error_over_ceiling_lo",
           "error_over_ceiling_hi",
           *[f"{s}:{k}" for s in ("mean_T", "mean_Sx2", "n_P_gt_0.2")
             for k in ("r", "r_lo", "r_hi", "bias", "bias_lo", "bias_hi")],
           "mean_Sy2:r", "coverage_90", "spread_r"]


def default_settings(variant: str = "unet") -> dict:
    # to_dict: plain (JSON-safe) values, as experiments/surrogate/study.py --settings takes them
    return Config.load(REPO / "config" / "config.yaml").to_dict()["surrogate"]["models"][variant]


def study(name, settings, args, store, extra=()):
    cmd = [sys.executable, str(Path(__file__).resolve().with_name("study.py")), name,
           "--settings", json.dumps(settings), "--store", store, "--replicas", args.replicas,
           "--out", args.out, "--threads", str(args.threads), *extra]
    if args.val_store:
        cmd += ["--val-store", args.val_store]
    subprocess.run(cmd, check=True)


def run(args) -> None:
    base = default_settings()
    if args.curve == "data":
        for n in args.sizes:
            epochs = max(1, round(base["epochs"] * DEFAULT_TRAIN_MOULDS / n))
            snapshots = ["--epochs-at", *map(str, args.epochs_at)] \
                if args.epochs_at and n == DEFAULT_TRAIN_MOULDS else []
            study(f"data_{n}", {**base, "epochs": epochs}, args, args.store,
                  ["--n-train", str(n), *snapshots])
    elif args.curve == "size":
        n_train = ["--n-train", str(args.n_train)] if args.n_train else []
        for width in args.bases:
            study(f"base_{width}", {**base, "base": width}, args, args.store, n_train)
    else:
        study("epochs", base, args, args.store,
              ["--epochs-at", *map(str, args.epochs_at or [15, 30, 60, 120, 180])])


def tables(args) -> None:
    rows = pd.read_csv(Path(args.out) / "results.csv").drop_duplicates(
        subset=["name", "epochs", "mode", "symmetrise"], keep="last")
    rows = rows.copy()
    rows["base"] = [json.loads(s).get("unet", json.loads(s)).get("base") for s in rows["settings"]]
    final = rows[rows["epochs"] == rows.groupby("name")["epochs"].transform("max")]
    default_run = f"data_{DEFAULT_TRAIN_MOULDS}"
    docs = Path(args.docs)
    docs.mkdir(parents=True, exist_ok=True)
    data = final[final["name"].str.startswith("data_")]
    size = final[final["name"].str.startswith("base_")]
    if not (size["base"] == default_settings()["base"]).any():
        size = pd.concat([size, final[final["name"] == default_run]])
    epochs = rows[rows["name"] == "epochs"]
    if epochs.empty:
        epochs = rows[rows["name"] == default_run]
    picks = {"data": data.sort_values("n_train"), "size": size.sort_values("parameters"),
             "epochs": epochs.sort_values("epochs")}
    for curve, frame in picks.items():
        if frame.empty:
            continue
        table = frame[[c for c in (["base"] if curve == "size" else []) + COLUMNS
                       if c in frame.columns]]
        table.to_csv(docs / f"surrogate_curve_{curve}.csv", index=False, float_format="%.4g")
        print(f"{curve}:\n{table.to_string(index=False)}\n")
    drawn = {curve: frame for curve, frame in picks.items() if not frame.empty}
    if drawn:
        print(learning_curves(drawn, docs / "learning_curves.png"))


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    sub = ap.add_subparsers(dest="command", required=True)
    r = sub.add_parser("run")
    r.add_argument("curve", choices=["data", "size", "epochs"])
    r.add_argument("--out", required=True)
    r.add_argument("--store", required=True)
    r.add_argument("--val-store")
    r.add_argument("--replicas", required=True)
    r.add_argument("--threads", type=int, default=1)
    r.add_argument("--sizes", type=int, nargs="+", default=[48, 97, 194, 388, 776])
    r.add_argument("--bases", type=int, nargs="+", default=[8, 16, 32, 48])
    r.add_argument("--epochs-at", type=int, nargs="+",
                   help="snapshots: of the epochs run (default 15 30 60 120 180), or of the "
                   "data curve's 194-mould run (default none)")
    r.add_argument("--n-train", type=int,
                   help="size curve: train on the first N training moulds of --store")
    t = sub.add_parser("tables")
    t.add_argument("--out", required=True)
    t.add_argument("--docs", default=str(Path(__file__).resolve().parent))
    args = ap.parse_args()
    run(args) if args.command == "run" else tables(args)


if __name__ == "__main__":
    main()
