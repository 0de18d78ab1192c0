"""Score trained checkpoints, family by family, on a store's test moulds against their
replicas (condor.studies.families.family_rows: the error against the expected fields with the
noise removed, one simulation's ceiling, the median mean-tension bias, 95% intervals):

  python experiments/generalisation/score_checkpoints.py --store STORE \\
      --checkpoint NAME=PATH [NAME=PATH ...] --out CSV

e.g. two default runs' checkpoints on new lab moulds of a seed neither run drew (unseen.yaml).
"""

from __future__ import annotations

import argparse
import os
import sys
from pathlib import Path

os.environ.setdefault("OPENBLAS_NUM_THREADS", "1")

import pandas as pd  # noqa: E402

from condor.data.store import open_store  # noqa: E402
from condor.studies.families import family_rows  # noqa: E402
from condor.studies.recipes import reference_ensemble  # noqa: E402
from condor.studies.scoring import predict_replica_moulds  # noqa: E402

import run as study  # noqa: E402  (its own folder is on sys.path, as for any script)


def main(argv=None) -> int:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--store", type=Path, required=True, help="a dataset.zarr with test replicas")
    ap.add_argument("--checkpoint", nargs="+", required=True, help="NAME=PATH")
    ap.add_argument("--out", type=Path, required=True)
    ap.add_argument("--seed", type=int, default=0, help="the bootstrap's")
    a = ap.parse_args(argv)
    ds = open_store(a.store)
    fam = study.families_of(ds)
    ids = [int(i) for i in study.first_replicas(ds, "test")]
    ensemble = reference_ensemble(ds, ids)
    labels = [str(fam[int(m)]) for m in ensemble.moulds]
    rows = []
    for spec in a.checkpoint:
        name, _, path = spec.partition("=")
        if not path:
            raise SystemExit(f"--checkpoint {spec!r}: expected NAME=PATH")
        raw = predict_replica_moulds(Path(path), ds, list(ensemble.moulds))
        every = family_rows(ensemble, raw, ["every"] * len(labels), seed=a.seed)
        rows.append(pd.concat([family_rows(ensemble, raw, labels, seed=a.seed), every])
                    .assign(checkpoint=name))
    table = pd.concat(rows, ignore_index=True)
    table["ratio"] = table["error"] / table["noise_ceiling"]
    table.to_csv(a.out, index=False)
    print(table[["checkpoint", "family", "n_moulds", "ratio", "error_hi", "noise_ceiling",
                 "tension_bias"]].round(3).to_string(index=False))
    return 0


if __name__ == "__main__":
    sys.exit(main())
