"""Learning curves of the surrogate against the expected fields: test error against the number
of training moulds, the model size and the epochs; writes the small tables docs/surrogate.md
shows (docs/data/surrogate_curve_*.csv) from the rows of bench_surrogate_study.py.

    # the runs (each appends to DIR/results.csv; see --help of bench_surrogate_study.py)
    PYTHONPATH=src python benchmarks/bench_surrogate_curves.py run data --out DIR \\
        --store BIG_STORE --val-store DEFAULT_STORE --replicas REPLICAS.npz
    PYTHONPATH=src python benchmarks/bench_surrogate_curves.py run size --out DIR ...
    # the tables
    PYTHONPATH=src python benchmarks/bench_surrogate_curves.py tables --out DIR --docs docs/data

Curves share the default's settings (config/config.yaml, variant `unet`) and change one thing:
- data: the first n training moulds of BIG_STORE (built by the workflow with
  `--config n_moulds=960`: the same seed gives the same first moulds), n in --sizes, each
  trained for the same number of optimiser steps as the default (epochs = default epochs x
  default training moulds / n), so that only the data changes;
- size: U-Net base width in --bases on the default store's training moulds;
- epochs: one default run evaluated at --epochs-at snapshots.
"""

from __future__ import annotations

import argparse
import json
import subprocess
import sys
from pathlib import Path

import pandas as pd

from condor.config import Config

REPO = Path(__file__).resolve().parents[1]
DEFAULT_TRAIN_MOULDS = 194  # the default store's training split (240 moulds, 24 test, 22 val)
COLUMNS = ["n_train", "epochs", "parameters", "train_seconds_total", "field_rms", "field_rms_lo",
           "field_rms_hi", "ceiling_rms", "error_over_ceiling", "error_over_ceiling_lo",
           "error_over_ceiling_hi", "mean_T:r", "mean_T:bias", "mean_Sx2:r", "mean_Sx2:bias",
           "mean_Sy2:r", "n_P_gt_0.2:r", "n_P_gt_0.2:bias", "coverage_90", "spread_r"]


def default_settings(variant: str = "unet") -> dict:
    # to_dict: plain (JSON-safe) values, as bench_surrogate_study.py --settings takes them
    return Config.load(REPO / "config" / "config.yaml").to_dict()["surrogate"]["models"][variant]


def study(name, settings, args, store, extra=()):
    cmd = [sys.executable, str(REPO / "benchmarks" / "bench_surrogate_study.py"), name,
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
            study(f"data_{n}", {**base, "epochs": epochs}, args, args.store, ["--n-train", str(n)])
    elif args.curve == "size":
        for width in args.bases:
            study(f"base_{width}", {**base, "base": width}, args, args.store)
    else:
        study("epochs", base, args, args.store,
              ["--epochs-at", *map(str, args.epochs_at)])


def tables(args) -> None:
    rows = pd.read_csv(Path(args.out) / "results.csv").drop_duplicates(
        subset=["name", "epochs", "mode", "symmetrise"], keep="last")
    docs = Path(args.docs)
    docs.mkdir(parents=True, exist_ok=True)
    picks = {"data": rows[rows["name"].str.startswith("data_")].sort_values("n_train"),
             "size": rows[rows["name"].str.startswith("base_")].sort_values("parameters"),
             "epochs": rows[rows["name"] == "epochs"].sort_values("epochs")}
    for curve, frame in picks.items():
        if frame.empty:
            continue
        table = frame[[c for c in COLUMNS if c in frame.columns]]
        table.to_csv(docs / f"surrogate_curve_{curve}.csv", index=False, float_format="%.4g")
        print(f"{curve}:\n{table.to_string(index=False)}\n")


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
    r.add_argument("--epochs-at", type=int, nargs="+", default=[15, 30, 60, 120, 180])
    t = sub.add_parser("tables")
    t.add_argument("--out", required=True)
    t.add_argument("--docs", default=str(REPO / "docs" / "data"))
    args = ap.parse_args()
    run(args) if args.command == "run" else tables(args)


if __name__ == "__main__":
    main()
