"""Paired comparison of surrogate checkpoints on the same test moulds: the ratio of each one's
field error to the first's, with a bootstrap interval over moulds resampled together (the
moulds' own difficulty cancels, so much smaller differences resolve than by comparing the two
separate intervals of bench_surrogate_study.py).

    PYTHONPATH=src python benchmarks/bench_surrogate_paired.py --store STORE \\
        --replicas REPLICAS.npz REF.pt OTHER.pt [MORE.pt ...] [--csv OUT.csv]

Field error: noise-corrected squared error against the replica mean (condor.measures.estimators),
each field in units of its RMS over the replicas, as in bench_surrogate_study.py; a ratio
below 1 means the checkpoint is closer to the expected fields than REF. Per field too.
"""

from __future__ import annotations

import argparse
from pathlib import Path

import numpy as np
import pandas as pd
import torch

from condor.data.reader import open_dataset
from condor.measures.estimators import bootstrap_interval, mse_against_expected
from condor.surrogate.samples import FIELD_NAMES, model_inputs
from condor.surrogate.predict import Predictor


def _ratio(pairs: np.ndarray) -> float:
    return float(np.sqrt(pairs[:, 1].mean() / pairs[:, 0].mean()))


def predict_replica_moulds(path, ds, mould_ids) -> np.ndarray:
    """A checkpoint's raw prediction (M, 8, H, W) for the moulds `mould_ids` of `ds` (their
    replica-0 samples), with the store's N_c and, for a lattice checkpoint, its `lattice`."""
    position = {int(m): i for i, m in enumerate(np.asarray(ds["sample"].values))}
    pos = [position[int(m)] for m in mould_ids]
    predictor = Predictor(path)
    lattice = model_inputs(ds, pos, "lattice") if predictor.needs_lattice else None
    return predictor(model_inputs(ds, pos, "mask"), n_cells=np.asarray(ds["n_cells"].values)[pos],
                     lattice=lattice).raw.astype(np.float64)


def field_errors(raw, replicas) -> tuple[np.ndarray, np.ndarray]:
    """Corrected squared errors (M,) and per field (M, F), each field in units of its RMS over
    the replicas."""
    scale = np.sqrt((replicas ** 2).mean(axis=(0, 1, 3, 4)))[None, :, None, None]
    overall = mse_against_expected(raw / scale, replicas / scale[:, None]).corrected
    per_field = mse_against_expected(raw / scale, replicas / scale[:, None],
                                     per_field=True).corrected
    return overall, per_field


def paired_errors(checkpoints, store, replicas_npz) -> pd.DataFrame:
    data = np.load(replicas_npz)
    replicas = data["fields"].astype(np.float64)
    ds = open_dataset(store)
    errors = [field_errors(predict_replica_moulds(path, ds, data["mould_ids"]), replicas)
              for path in checkpoints]
    return paired_rows([Path(c).stem for c in checkpoints], errors)


def paired_rows(names, errors) -> pd.DataFrame:
    """One row per name after the first: the ratio of its field error to the first's (overall
    and per field) with its paired bootstrap interval over moulds."""
    rows = []
    for name, (overall, per_field) in zip(names[1:], errors[1:]):
        row = {"reference": names[0], "checkpoint": name}
        est, lo, hi = bootstrap_interval(np.stack([errors[0][0], overall], 1), _ratio)
        row.update(ratio=est, ratio_lo=lo, ratio_hi=hi,
                   moulds_better=float(np.mean(overall < errors[0][0])))
        for f, name in enumerate(FIELD_NAMES):
            est, lo, hi = bootstrap_interval(np.stack([errors[0][1][:, f], per_field[:, f]], 1),
                                             _ratio)
            row.update({f"{name}:ratio": est, f"{name}:lo": lo, f"{name}:hi": hi})
        rows.append(row)
    return pd.DataFrame(rows)


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("checkpoints", nargs="+", help="REF.pt first, then the ones to compare")
    ap.add_argument("--store", required=True)
    ap.add_argument("--replicas", required=True)
    ap.add_argument("--csv", help="also write the table here")
    ap.add_argument("--threads", type=int, default=1)
    args = ap.parse_args()
    if len(args.checkpoints) < 2:
        ap.error("give a reference checkpoint and at least one other")
    torch.set_num_threads(args.threads)
    table = paired_errors(args.checkpoints, args.store, args.replicas)
    if args.csv:
        table.to_csv(args.csv, index=False)
    cols = ["reference", "checkpoint", "ratio", "ratio_lo", "ratio_hi", "moulds_better"] + \
        [f"{n}:ratio" for n in ("P", "T", "Sx2", "Sy2")]
    print(table[cols].round(3).to_string(index=False))


if __name__ == "__main__":
    main()
