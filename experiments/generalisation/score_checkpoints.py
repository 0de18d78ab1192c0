"""Score trained checkpoints, family by family, on a store's test moulds against their
replicas (condor.studies.families.family_rows: the error against the expected fields with the
noise removed, one simulation's ceiling, the median mean-tension bias, 95% intervals):

  python experiments/generalisation/score_checkpoints.py --store STORE \\
      --checkpoint NAME=PATH [NAME=PATH ...] --out CSV

e.g. two default runs' checkpoints on new lab moulds of a seed neither run drew (unseen.yaml).
With --paired NAME it also writes OUT's stem + _paired.csv: each other checkpoint's error over
NAME's on the same moulds (the root of the ratio of their mean squared errors, noise removed),
per family, over the lab moulds and over every mould, with a 95% interval over moulds resampled
in pairs.
"""

from __future__ import annotations

import argparse
import os
import sys
from pathlib import Path

os.environ.setdefault("OPENBLAS_NUM_THREADS", "1")

import numpy as np  # noqa: E402
import pandas as pd  # noqa: E402

from condor.data.store import open_store  # noqa: E402
from condor.studies.families import family_rows  # noqa: E402
from condor.studies.recipes import reference_ensemble  # noqa: E402
from condor.studies.scoring import paired_ratio, predict_replica_moulds  # noqa: E402

import run as study  # noqa: E402  (its own folder is on sys.path, as for any script)


def main(argv=None) -> int:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--store", type=Path, required=True, help="a dataset.zarr with test replicas")
    ap.add_argument("--checkpoint", nargs="+", required=True, help="NAME=PATH")
    ap.add_argument("--out", type=Path, required=True)
    ap.add_argument("--seed", type=int, default=0, help="the bootstrap's")
    ap.add_argument("--paired", default=None, metavar="NAME",
                    help="the checkpoint the others are paired against, mould by mould")
    a = ap.parse_args(argv)
    ds = open_store(a.store)
    fam = study.families_of(ds)
    ids = [int(i) for i in study.first_replicas(ds, "test")]
    ensemble = reference_ensemble(ds, ids)
    labels = [str(fam[int(m)]) for m in ensemble.moulds]
    rows, errors = [], {}
    for spec in a.checkpoint:
        name, _, path = spec.partition("=")
        if not path:
            raise SystemExit(f"--checkpoint {spec!r}: expected NAME=PATH")
        raw = predict_replica_moulds(Path(path), ds, list(ensemble.moulds))
        errors[name] = study.per_mould(ensemble, raw, labels)["squared_error"].to_numpy()
        every = family_rows(ensemble, raw, ["every"] * len(labels), seed=a.seed)
        rows.append(pd.concat([family_rows(ensemble, raw, labels, seed=a.seed), every])
                    .assign(checkpoint=name))
    table = pd.concat(rows, ignore_index=True)
    table["ratio"] = table["error"] / table["noise_ceiling"]
    table.to_csv(a.out, index=False)
    print(table[["checkpoint", "family", "n_moulds", "ratio", "error_hi", "noise_ceiling",
                 "tension_bias"]].round(3).to_string(index=False))
    if a.paired is not None:
        if a.paired not in errors:
            raise SystemExit(f"--paired {a.paired!r} names no --checkpoint ({sorted(errors)})")
        paired = paired_ratios(errors, a.paired, np.asarray(labels, dtype=object), a.seed)
        paired.to_csv(a.out.with_name(a.out.stem + "_paired.csv"), index=False)
        print(paired.round(3).to_string(index=False))
    return 0


def paired_ratios(errors: dict, against: str, labels: np.ndarray, seed: int) -> pd.DataFrame:
    """Each checkpoint's error over `against`'s, per family, over the lab moulds (every label
    but the paper's) and over every mould: sqrt(mean squared error / theirs), its interval
    from moulds resampled in pairs (condor.studies.scoring.paired_ratio)."""
    groups = {**{f: labels == f for f in dict.fromkeys(labels)},
              "lab": labels != study.PAPER, "every": np.ones(len(labels), bool)}
    rows = []
    for name, err in errors.items():
        if name == against:
            continue
        for group, mask in groups.items():
            if not mask.any():
                continue
            value, lo, hi = paired_ratio(errors[against][mask], err[mask], seed=seed)
            rows.append({"checkpoint": name, "against": against, "family": group,
                         "n_moulds": int(mask.sum()), "ratio": value, "ratio_lo": lo,
                         "ratio_hi": hi})
    return pd.DataFrame(rows)


if __name__ == "__main__":
    sys.exit(main())
