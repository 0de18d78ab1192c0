"""Paired comparison of surrogate checkpoints on the same test moulds: the ratio of each one's
field error to the first's, with a bootstrap interval over moulds resampled together (the
moulds' own difficulty cancels, so much smaller differences resolve than by comparing the two
separate intervals of experiments/surrogate/study.py).

    PYTHONPATH=src python experiments/surrogate/paired.py --store STORE \\
        --replicas REPLICAS.npz REF.pt OTHER.pt [MORE.pt ...] [--csv OUT.csv]

Field error: noise-corrected squared error against the replica mean (condor.measures.estimators; condor.studies.scoring),
each field in units of its RMS over the replicas, as in experiments/surrogate/study.py; a ratio
below 1 means the checkpoint is closer to the expected fields than REF. Per field too.
"""

from __future__ import annotations

import argparse
from pathlib import Path

import numpy as np
import pandas as pd
import torch

from condor.data.dataset import open_dataset
from condor.studies.scoring import field_errors, paired_rows, predict_replica_moulds
from condor.surrogate.samples import FIELD_NAMES


def paired_errors(checkpoints, store, replicas_npz) -> pd.DataFrame:
    data = np.load(replicas_npz)
    replicas = data["fields"].astype(np.float64)
    ds = open_dataset(store)
    errors = [field_errors(predict_replica_moulds(path, ds, data["mould_ids"]), replicas)
              for path in checkpoints]
    return paired_rows([Path(c).stem for c in checkpoints], errors, FIELD_NAMES)


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
