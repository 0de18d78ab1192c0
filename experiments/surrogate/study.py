"""Train surrogate variants and measure them against the expected fields (replica means): the
cause study, the learning curves and the default's accuracy in docs/surrogate.md.

    PYTHONPATH=src python experiments/surrogate/study.py NAME --settings '{"model": ...}' \\
        --store STORE --replicas REPLICAS.npz --out DIR [--n-train N] [--epochs-at 30 60]
        [--modes eval batch_stats] [--no-symmetrise-too] [--val-store DEFAULT_STORE]

Trains (resuming) DIR/NAME.pt on the store's training moulds (the first --n-train of them when
given; the replica moulds and the validation moulds of --val-store are never trained on),
then appends one row per (checkpoint, prediction mode, symmetrisation) to DIR/results.csv:
whole-mould statistics against the replica means (r, r ceiling, bias; condor.measures.estimators),
the field error against the expected fields and the single-simulation ceiling (RMS over
pixels, noise-corrected, bootstrap intervals over moulds), the spread's calibration
(condor.surrogate.calibration) and the checkerboard amplitude. `--epochs-at` also evaluates
copies of the checkpoint taken at those epochs (a curve against epochs from one run).
Replicas come from experiments/surrogate/replicas.py.
"""

from __future__ import annotations

import argparse
import fcntl
import json
import shutil
import time
from pathlib import Path

import numpy as np
import pandas as pd
import torch

from condor.data.dataset import open_dataset
from condor.measures.estimators import (bootstrap_interval, mse_against_expected, noise_ceiling,
                               root_mean, statistic_agreement)
from condor.data.statistics import STATISTICS
from condor.studies.scoring import statistics_of, study_dataset
from condor.surrogate.calibration import (checkerboard, interval_coverage, spread_agreement,
                                          tissue_pixels)
from condor.surrogate.checkpoint import load_checkpoint
from condor.surrogate.samples import FIELD_NAMES, model_inputs, usable_samples
from condor.surrogate.predict import Predictor
from condor.surrogate.train import train
from condor.surrogate.variants import train_config

def _test_ids(store) -> np.ndarray:
    """The test split's mould ids (the replica moulds, before the replicas exist)."""
    ds = open_dataset(store)
    test = (np.asarray(ds["split"].values).astype(str) == "test") & \
        (np.asarray(ds["replica"].values) == 0)
    return np.asarray(ds["mould"].values)[test]


def measure(prediction, spread, replicas, inputs, pixel_size, scale) -> dict:
    """Every figure of one set of predictions (M, 8, H, W) against replicas (M, R, 8, H, W)."""
    row = {}
    pred_stats = statistics_of(prediction, pixel_size)
    rep_stats = statistics_of(replicas, pixel_size)
    for k, name in enumerate(STATISTICS):
        agreement = statistic_agreement(pred_stats[:, k], rep_stats[:, :, k], n_boot=500)
        for key in ("r", "r_lo", "r_hi", "r_ceiling", "bias", "bias_lo", "bias_hi"):
            row[f"{name}:{key}"] = agreement[key]
    # Field error: RMS over pixels and fields, each field in units of its RMS (scale), so that
    # every field counts; noise-corrected against the replica mean, and the one-run ceiling.
    s = np.asarray(scale)[None, :, None, None]
    err = mse_against_expected(prediction / s, replicas / s[:, None])
    ceiling = noise_ceiling(replicas / s[:, None])
    row["field_rms"], row["field_rms_lo"], row["field_rms_hi"] = bootstrap_interval(err.corrected, n_boot=500)
    row["ceiling_rms"], row["ceiling_rms_lo"], row["ceiling_rms_hi"] = bootstrap_interval(ceiling, n_boot=500)
    ratio = err.corrected / ceiling
    row["error_over_ceiling"], row["error_over_ceiling_lo"], row["error_over_ceiling_hi"] = \
        bootstrap_interval(np.stack([err.corrected, ceiling], 1),
                           lambda v: v[:, 0].mean() / v[:, 1].mean(), n_boot=500)
    row["moulds_below_ceiling"] = float(np.mean(ratio < 1))
    per_field = mse_against_expected(prediction / s, replicas / s[:, None], per_field=True)
    field_ceiling = noise_ceiling(replicas / s[:, None], per_field=True)
    for f, name in enumerate(FIELD_NAMES):
        row[f"{name}:rms"] = root_mean(per_field.corrected[:, f])
        row[f"{name}:ceiling"] = root_mean(field_ceiling[:, f])
    row["sum_P_over_Nc_max_dev"] = float(np.abs(prediction[:, 0].sum((1, 2)) /
                                                replicas[:, 0, 0].sum((1, 2)) - 1).max())
    row["checkerboard"] = float((checkerboard(prediction) / np.asarray(scale)).mean())
    row["checkerboard_replica_mean"] = float((checkerboard(replicas.mean(1)) / np.asarray(scale)).mean())
    # In the difference maps against the replica mean, beside the floor the mean's own noise
    # sets: (mean of replicas 0-3 - mean of 4-7) / 2 has the noise of an 8-replica mean.
    half = replicas.shape[1] // 2
    row["checkerboard_diff"] = float((checkerboard(prediction - replicas.mean(1)) / np.asarray(scale)).mean())
    row["checkerboard_noise"] = float((checkerboard((replicas[:, :half].mean(1) -
                                                     replicas[:, half:2 * half].mean(1)) / 2)
                                       / np.asarray(scale)).mean())
    if spread is not None:
        mask = tissue_pixels(inputs)
        for level, cov in interval_coverage(prediction, spread, replicas, mask).items():
            row[f"coverage_{int(level * 100)}"] = float(cov.mean())
            row[f"coverage_{int(level * 100)}_min"] = float(cov.min())
            row[f"coverage_{int(level * 100)}_max"] = float(cov.max())
        agree = spread_agreement(spread, replicas, mask)
        row["spread_r"] = agree["r"]
        row["spread_ratio"] = agree["ratio"]
        row["spread_pixel_r"] = float(np.median(agree["pixel_r"]))
    return row


def recalibrate_spread(predictor, ds) -> None:
    """Refit the physics head's spread factor on the val split, from factor 1, as training
    does after its last validation (for checkpoints written before the pair-tied factor)."""
    val = usable_samples(ds, "val")
    inputs = np.asarray(ds["inputs"].isel(sample=val).values, dtype=np.float32)
    truth = np.asarray(ds["fields"].isel(sample=val).values, dtype=np.float64)
    predictor.scaling.spread_factor = np.ones(len(FIELD_NAMES))
    p = predictor(inputs, n_cells=np.asarray(ds["n_cells"].values)[val],
                  lattice=model_inputs(ds, val, "lattice") if predictor.needs_lattice else None)
    predictor.scaling.calibrate_spread(p.raw, p.spread, truth, inputs.astype(bool).any(axis=1))


def evaluate_checkpoint(checkpoint, ds, replicas_npz, modes, symmetrise_options,
                        recalibrate: bool = False) -> list[dict]:
    data = np.load(replicas_npz)
    ids = data["mould_ids"]
    replicas = data["fields"].astype(np.float64)
    position = {int(m): i for i, m in enumerate(np.asarray(ds["sample"].values))}
    pos = [position[int(m)] for m in ids]
    inputs = np.asarray(ds["inputs"].isel(sample=pos).values, dtype=np.float32)
    n_cells = np.asarray(ds["n_cells"].values)[pos]
    pixel_size = float(ds.attrs["pixel_size"])
    scale = np.sqrt((replicas ** 2).mean(axis=(0, 1, 3, 4)))
    predictor = Predictor(checkpoint)
    lattice = model_inputs(ds, pos, "lattice") if predictor.needs_lattice else None
    rows = []
    for mode in modes:
        for symmetrise in symmetrise_options:
            predictor.mode, predictor.symmetrise = mode, symmetrise
            if recalibrate and predictor.needs_n_cells:
                recalibrate_spread(predictor, ds)
            t0 = time.perf_counter()
            p = predictor(inputs, n_cells=n_cells, lattice=lattice)
            seconds = (time.perf_counter() - t0) / len(inputs)
            rows.append({"mode": mode, "symmetrise": symmetrise, "predict_s_per_mould": seconds,
                         "spread_factor": json.dumps(np.round(getattr(predictor.scaling, "spread_factor", np.ones(1)), 4).tolist()),
                         **measure(p.raw.astype(np.float64), p.spread, replicas, inputs,
                                   pixel_size, scale)})
    return rows


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("name")
    ap.add_argument("--settings", required=True, help="flat variant settings, JSON")
    ap.add_argument("--store", required=True)
    ap.add_argument("--replicas", required=True)
    ap.add_argument("--out", required=True)
    ap.add_argument("--n-train", type=int)
    ap.add_argument("--val-store", help="take the val moulds from this store's split")
    ap.add_argument("--epochs-at", type=int, nargs="*", default=[])
    ap.add_argument("--modes", nargs="+", default=["eval"])
    ap.add_argument("--no-symmetrise-too", action="store_true",
                    help="also evaluate without test-time symmetrisation")
    ap.add_argument("--threads", type=int, default=1)
    ap.add_argument("--train-only", action="store_true", help="train (resume), evaluate nothing")
    ap.add_argument("--recalibrate", action="store_true",
                    help="refit the spread factor on the val split before evaluating")
    ap.add_argument("--eval-only", action="store_true",
                    help="evaluate the existing checkpoint (and its --epochs-at snapshots) as is")
    args = ap.parse_args()

    torch.set_num_threads(args.threads)
    out = Path(args.out)
    out.mkdir(parents=True, exist_ok=True)
    replica_ids = np.load(args.replicas)["mould_ids"] if Path(args.replicas).exists() else \
        _test_ids(args.val_store or args.store)
    val_ids = None
    if args.val_store:
        vds = open_dataset(args.val_store)
        val_ids = np.asarray(vds["mould"].values)[usable_samples(vds, "val")]
    ds = study_dataset(open_dataset(args.store), replica_ids, args.n_train, val_ids)
    settings = {**json.loads(args.settings), "num_threads": args.threads}
    cfg = train_config(settings, int(ds.sizes["x"]))
    checkpoint = out / f"{args.name}.pt"
    snapshots = {}
    t_cpu, t_wall = time.process_time(), time.perf_counter()
    final_epochs = cfg.epochs
    if args.eval_only:
        for epochs in args.epochs_at:
            if (out / f"{args.name}@{epochs}.pt").exists():
                snapshots[epochs] = out / f"{args.name}@{epochs}.pt"
        state = load_checkpoint(checkpoint)
        snapshots[state["epoch"]] = checkpoint
        history = state["history"]
        settings = {**state["config"], "unet": state["generator_config"]}
        cfg.symmetrise = bool(state["config"].get("symmetrise", False))
    else:
        for epochs in sorted(set(args.epochs_at) | {final_epochs}):
            if epochs > final_epochs:
                continue
            # snapshots of the one run of final_epochs (its schedule), each resumed
            history = train(ds, cfg, checkpoint, log=lambda line: print(args.name, line, flush=True),
                            stop_after=epochs)
            if epochs != final_epochs:
                snapshots[epochs] = out / f"{args.name}@{epochs}.pt"
                shutil.copyfile(checkpoint, snapshots[epochs])
        snapshots[final_epochs] = checkpoint
    if args.train_only:
        return
    train_cpu, train_wall = time.process_time() - t_cpu, time.perf_counter() - t_wall
    train_seconds = sum(r["seconds"] for r in history)
    n_train = len(usable_samples(ds, "train"))
    rows = []
    for epochs, path in sorted(snapshots.items()):
        for row in evaluate_checkpoint(path, ds, args.replicas, args.modes,
                                       [True, False] if args.no_symmetrise_too else [cfg.symmetrise],
                                       args.recalibrate):
            rows.append({"name": args.name, "epochs": epochs, "n_train": n_train,
                         "settings": json.dumps(settings, sort_keys=True),
                         "train_seconds_total": sum(r["seconds"] for r in history[:epochs]),
                         "run_cpu_s": train_cpu,
                         "run_wall_s": train_wall,
                         "parameters": sum(p.numel() for p in Predictor(path).model.parameters()),
                         "val_mae": history[epochs - 1].get("val_mae") if len(history) >= epochs else None,
                         **row})
    frame = pd.DataFrame(rows)
    results = out / "results.csv"
    # Runs of one curve may share DIR and finish together: append under an exclusive lock.
    with open(out / "results.csv.lock", "w") as lock:
        fcntl.flock(lock, fcntl.LOCK_EX)
        if results.exists():
            frame = pd.concat([pd.read_csv(results), frame], ignore_index=True)
        frame.to_csv(results, index=False)
    cols = ["name", "epochs", "mode", "symmetrise", "field_rms", "ceiling_rms", "mean_P:r",
            "mean_P:bias", "mean_T:bias", "mean_Sx2:bias", "mean_T:r", "mean_Sx2:r",
            "checkerboard", "coverage_90"]
    print(pd.DataFrame(rows)[[c for c in cols if c in rows[0]]].to_string())


if __name__ == "__main__":
    main()
