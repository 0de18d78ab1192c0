"""A training recipe measured against the expected organisation of many moulds.

`train`: the default variant (the `unet` preset, condor.surrogate.variants) with --settings overrides,
trained on a store's training split (--extra-train: and the training moulds of other stores
of the same scene after them, a training set larger than the workflow's budget; --n-train: the
first n of them, the rest left out), validated on its val split. `score`: checkpoints
against the pooled replicated moulds of one or more stores (every test mould with its replicas;
a store built only to test, e.g. with another seed, adds moulds no checkpoint has seen), with
the accuracy stage's own tables (condor.studies.accuracy: field error with the finite-replica
noise removed, r against the expected statistics, bias = median of predicted / simulated - 1,
95% bootstrap intervals over moulds), the field error's ratio to the first checkpoint's (paired
over moulds, with its interval) and the spread map's calibration. Each statistic is also scored
on the tethered moulds alone (subset `tethered`): the tether-free moulds are few and the
surrogate's largest errors.

    PYTHONPATH=src python experiments/surrogate/pooled.py train --store STORE \\
        --out DIR/NAME.pt [--n-train N] [--extra-train STORE ...] [--settings JSON] [--threads 2]
    PYTHONPATH=src python experiments/surrogate/pooled.py score --test STORE [STORE ...] \\
        --out CSV DIR/NAME.pt [DIR/NAME.pt ...]

Every store must share the scene (moulds with fewer replicas are NaN-padded, as in the
accuracy stage: condor.measures.estimators). Predictions are cached
beside each checkpoint (NAME_pooled.npz, keyed by the stores), so scoring more checkpoints
later re-predicts only the new ones.
"""

from __future__ import annotations

import argparse
import json
import time
from pathlib import Path

import numpy as np
import pandas as pd
import torch

import condor
from condor.measures import estimators as est
from condor.data.statistics import STATISTICS
from condor.measures.metrics import normalise_predicted
from condor.studies import accuracy as accuracy_study
from condor.studies.recipes import reference_ensemble
from condor.studies.scoring import (first_training_moulds, paired_ratio, pooled_ensemble,
                                    with_training_moulds)
from condor.surrogate.checkpoint import load_checkpoint
from condor.surrogate.samples import usable_samples
from condor.surrogate.predict import Predictor
from condor.surrogate.train import train
from condor.surrogate.variants import resolve, train_config

REPO = Path(__file__).resolve().parents[2]
CHECKED = ("n_P_gt_0.2", "mean_T", "mean_Sx2", "mean_Sy2")


def default_settings() -> dict:
    return resolve("unet")  # the default preset (condor.surrogate.variants.PRESETS)


def run_training(args) -> None:
    settings = {**default_settings(), **json.loads(args.settings), "num_threads": args.threads}
    ds = condor.open_dataset(args.store).load()
    for store in args.extra_train:
        ds = with_training_moulds(ds, condor.open_dataset(store))
    if args.n_train is not None:
        ds = first_training_moulds(ds, args.n_train)
    print(f"{len(usable_samples(ds, 'train'))} training moulds; settings {settings}", flush=True)
    start = time.perf_counter()
    train(ds, train_config(settings, int(ds.sizes["x"])), args.out,
          log=lambda line: print("   ", line, flush=True))
    print(f"trained in {time.perf_counter() - start:.0f} s (wall)")


def predictions(checkpoint: str, ensemble, key: str) -> tuple[np.ndarray, np.ndarray]:
    """Raw fields and spread of `checkpoint` on the ensemble's moulds (cached)."""
    cache = Path(checkpoint).with_name(Path(checkpoint).stem + "_pooled.npz")
    if cache.exists():
        with np.load(cache) as data:
            if str(data["key"]) == key:
                return data["raw"], data["spread"]
    predictor = Predictor(checkpoint, device="cpu")
    answer = predictor(ensemble.inputs.astype(np.float32), n_cells=ensemble.n_cells,
                       lattice=ensemble.lattice if predictor.needs_lattice else None)
    np.savez_compressed(cache, raw=answer.raw, spread=answer.spread, key=key)
    return answer.raw, answer.spread


def recipe(checkpoint: str) -> dict:
    """What a checkpoint was trained on and how: training moulds, epochs, and its settings
    that differ from the workflow's default variant."""
    state = load_checkpoint(checkpoint)
    config, default = state["config"], {"blocks": 0, **default_settings()}
    setting = {**state["generator_config"], **config}
    setting["blocks"] = setting.get("blocks") or 0  # checkpoints from before the setting
    changed = {k: setting.get(k) for k in ("tension_floor", "blocks", "base", "inputs")
               if setting.get(k) != default.get(k)}
    return {"n_train": state["data"]["n_train"], "epochs": config["epochs"],
            "changes": json.dumps(changed) if changed else ""}


def score_rows(name: str, raw, spread, ensemble, replica_stats) -> list[dict]:
    """The accuracy stage's figures of one checkpoint's answers on the pooled ensemble
    (replica_stats: `accuracy_study.replica_statistics(ensemble)`)."""
    answer = accuracy_study.Answer(name, "surrogate", raw, np.zeros(len(raw)), predicted=True)
    errors, _ = accuracy_study.accuracy_tables(ensemble, [answer])
    error = errors[errors["method"] == name].iloc[0]
    ceiling = errors[errors["method"] == "single simulation"].iloc[0]
    calibration = accuracy_study.calibration_row(name, raw, spread, ensemble)
    row = {"name": name, "n_moulds": len(raw), "field_error": error.field_error,
           "field_error_lo": error.field_error_lo, "field_error_hi": error.field_error_hi,
           "ceiling": ceiling.field_error, **{f"{f}:error": error[f"error_{f}"]
                                               for f in ("P", "T", "Sx2", "Sy2")},
           "coverage_90": calibration["coverage_90"], "coverage_50": calibration["coverage_50"],
           "spread_r": calibration["spread_r"]}
    predicted = accuracy_study.statistics_of(raw, ensemble.pixel_size, None)
    tethered = ensemble.inputs[:, 1].sum(axis=(1, 2)) > 0
    for subset, keep in (("", np.ones(len(raw), bool)), ("tethered ", tethered)):
        for statistic in CHECKED:
            k = STATISTICS.index(statistic)
            agreement = est.statistic_agreement(predicted[keep, k], replica_stats[keep][:, :, k])
            for key in ("r", "r_lo", "r_hi", "r_plain", "r_ceiling", "bias", "bias_lo",
                        "bias_hi"):
                row[f"{subset}{statistic}:{key}"] = agreement[key]
    row["tether_free_moulds"] = int((~tethered).sum())
    return [row]


def run_scoring(args) -> None:
    torch.set_num_threads(args.threads)
    ensemble = pooled_ensemble([reference_ensemble(store) for store in args.test])
    replica_stats = accuracy_study.replica_statistics(ensemble)
    key = "|".join(str(Path(s).resolve()) for s in args.test)
    print(f"{len(ensemble.moulds)} moulds x {ensemble.describe_replicas()}", flush=True)
    rows, errors = [], {}
    for checkpoint in args.checkpoints:
        raw, spread = predictions(checkpoint, ensemble, key)
        row = score_rows(Path(checkpoint).stem, raw, spread, ensemble, replica_stats)[0]
        rows.append({"name": row.pop("name"), **recipe(checkpoint), **row})
        errors[rows[-1]["name"]] = est.mse_against_expected(
            normalise_predicted(raw).astype(np.float64), ensemble.normalised).corrected
    reference = rows[0]["name"]
    for row in rows:  # the field error against the first checkpoint's, paired over moulds
        row["reference"] = reference
        row["ratio"], row["ratio_lo"], row["ratio_hi"] = paired_ratio(errors[reference],
                                                                      errors[row["name"]])
    table = pd.DataFrame(rows)
    if args.out:
        Path(args.out).parent.mkdir(parents=True, exist_ok=True)
        table.to_csv(args.out, index=False)
    shown = ["name", "n_train", "epochs", "field_error", "ceiling", "ratio"] + [f"{s}:{k}" for s in CHECKED
                                                  for k in ("r", "bias")] + \
        [f"tethered {s}:r" for s in ("mean_Sx2", "mean_Sy2")] + ["coverage_90"]
    with pd.option_context("display.width", 250, "display.max_columns", 40):
        print(table[shown].round(4).to_string(index=False))


def main(argv=None) -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    sub = parser.add_subparsers(dest="command", required=True)
    t = sub.add_parser("train")
    t.add_argument("--store", required=True)
    t.add_argument("--out", required=True)
    t.add_argument("--n-train", type=int, default=None)
    t.add_argument("--extra-train", nargs="*", default=[],
                   help="stores whose training moulds are added to the training split")
    t.add_argument("--settings", default="{}")
    t.add_argument("--threads", type=int, default=2)
    s = sub.add_parser("score")
    s.add_argument("--test", nargs="+", required=True)
    s.add_argument("--out", default=None)
    s.add_argument("--threads", type=int, default=1)
    s.add_argument("checkpoints", nargs="+")
    args = parser.parse_args(argv)
    run_training(args) if args.command == "train" else run_scoring(args)


if __name__ == "__main__":
    main()
