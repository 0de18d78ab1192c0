"""Should training use a mould's replicas as extra samples, or their mean as the target?

On a store whose training moulds have R replicas (build one with the workflow, e.g.
`snakemake --cores 2 --configfile config/tiny.yaml --config n_moulds=64 results=results/reps
"simulation={'replicas': {'train': 4, 'val': 1, 'test': 8}}" --until dataset`), trains the
physics U-Net three ways at the same number of optimiser steps: replica 0 only ("first"),
every replica as a sample ("all", 1/R of the epochs) and the replicas' mean as the target
("mean"), then scores each on the test moulds against their expected fields
(condor.studies.accuracy: noise-corrected field error with its interval, the bias of the
whole-mould statistics) and the calibration of the predicted spread (90% and 50% coverage).
Run: OPENBLAS_NUM_THREADS=1 python experiments/surrogate/train_replicas.py --store STORE
         [--epochs 120] [--base 8] [--seeds 0 1]
"""

import argparse
import os
from pathlib import Path

os.environ.setdefault("OPENBLAS_NUM_THREADS", "1")

import numpy as np  # noqa: E402
import pandas as pd  # noqa: E402

from condor.data.store import open_store  # noqa: E402
from condor.studies import accuracy  # noqa: E402
from condor.studies.recipes import reference_ensemble  # noqa: E402
from condor.surrogate.predict import Predictor  # noqa: E402
from condor.surrogate.train import train  # noqa: E402
from condor.surrogate.variants import train_config  # noqa: E402

OUT = Path("results/benchmarks")


def main():
    ap = argparse.ArgumentParser()
    ap.add_argument("--store", required=True)
    ap.add_argument("--epochs", type=int, default=120, help="epochs of the 'first' run")
    ap.add_argument("--base", type=int, default=8)
    ap.add_argument("--seeds", type=int, nargs="+", default=[0])
    a = ap.parse_args()
    ds = open_store(a.store)
    replicas = max(ds.attrs["data_config"]["replicas"]["train"], 1)
    test = [int(m) for m, s in zip(ds["mould"].values, ds["split"].values.astype(str))
            if s == "test"]
    ensemble = reference_ensemble(a.store, sorted(set(test)))
    inputs = ensemble.inputs.astype(np.float32)
    rows, stats = [], []
    OUT.mkdir(parents=True, exist_ok=True)
    for seed in a.seeds:
        for use in ("first", "all", "mean"):
            epochs = a.epochs // replicas if use == "all" else a.epochs
            settings = {"model": "unet", "head": "physics", "loss": "gaussian",
                        "upsample": "bilinear", "base": a.base, "epochs": epochs,
                        "batch_size": 4, "lr": 2e-3, "augment": True, "symmetrise": True,
                        "replicas": use, "seed": seed}
            path = OUT / f"replicas_{use}_{seed}.pt"
            path.unlink(missing_ok=True)
            train(ds, train_config(settings, int(ds.sizes["x"])), path, log=lambda s: None)
            predictor = Predictor(path, device="cpu")
            prediction = predictor(inputs, n_cells=ensemble.n_cells)
            answer = accuracy.Answer(use, "surrogate", prediction.raw, np.zeros(len(inputs)),
                                     predicted=True)
            table, statistics = accuracy.accuracy_tables(ensemble, [answer], seed=seed)
            row = table.set_index("method").loc[use].to_dict()
            row.update(accuracy.calibration_row(use, prediction.raw, prediction.spread, ensemble))
            row.update(use=use, seed=seed, epochs=epochs)
            rows.append(row)
            stats.append(statistics[statistics["method"] == use].assign(seed=seed))
            print(f"{use} seed {seed}: field error {row['field_error']:.4f} "
                  f"[{row['field_error_lo']:.4f}, {row['field_error_hi']:.4f}], coverage 90% "
                  f"{row['coverage_90']:.3f}, 50% {row['coverage_50']:.3f}", flush=True)
    table = pd.DataFrame(rows)
    table.to_csv(OUT / "train_replicas.csv", index=False)
    pd.concat(stats).to_csv(OUT / "train_replicas_statistics.csv", index=False)
    ceiling = accuracy.accuracy_tables(ensemble, [])[0].set_index("method")
    print(f"single simulation (ceiling): {ceiling.loc['single simulation', 'field_error']:.4f}")
    print(table[["use", "seed", "epochs", "field_error", "field_error_lo", "field_error_hi",
                 "coverage_50", "coverage_90", "spread_r"]].to_string(index=False))


if __name__ == "__main__":
    main()
