"""Score the average of several cached leave-one-kind-out models (an ensemble) on the kinds
they held out and on the paper test moulds (experiments/generalisation/README.md, "An ensemble
of the models").

Each model is named by its tag in run.py's cache (`without_<kind>_<tag>_<key>_<group>.npy`,
e.g. `n450_e120`, `n900_extra0.5_e120`); the ensemble's raw fields are the mean of the models'
raw fields, scored as run.py scores one model (condor.studies.families.family_rows):

    python experiments/generalisation/ensemble.py --pool POOL --cache CACHE \\
        --models n450_e120 n900_extra0.5_e120 --out CSV
"""

from __future__ import annotations

import argparse
import sys
from pathlib import Path

import numpy as np
import pandas as pd

from condor.files import write_text

import run as R  # this folder's run.py (python puts a script's folder first on its path)


def cached_raw(cache: Path, kind: tuple[str, ...], tag: str, group: str) -> np.ndarray:
    """The raw fields a cached model of `tag` without `kind` predicted for `group`."""
    found = sorted(cache.glob(f"without_{'_'.join(kind)}_{tag}_" + "?" * 12 + f"_{group}.npy"))
    if len(found) != 1:
        raise SystemExit(f"{len(found)} cached predictions of the model without "
                         f"{'+'.join(kind)}, tag {tag!r}, in {cache} (need exactly 1): run "
                         f"run.py with that model first")
    return np.load(found[0])


def main(argv=None) -> int:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--pool", type=Path, required=True, help="the pool's dataset.zarr")
    ap.add_argument("--cache", type=Path, default=Path.home() / ".cache/condor/generalisation")
    ap.add_argument("--models", nargs="+", required=True, help="the models' cache tags")
    ap.add_argument("--out", type=Path, default=None)
    a = ap.parse_args(argv)
    ds = R.open_store(a.pool)
    test, fam = R.first_replicas(ds, "test"), R.families_of(ds)
    groups = {"paper": [int(i) for i in test if fam[i] == R.PAPER],
              "lab": [int(i) for i in test if fam[i] != R.PAPER]}
    ensembles = {g: R.reference_ensemble(ds, ids) for g, ids in groups.items()}
    labels = {g: [str(fam[int(m)]) for m in e.moulds] for g, e in ensembles.items()}
    rows = []
    for kind in R.KINDS:
        for group, ensemble in ensembles.items():
            raw = np.mean([cached_raw(a.cache, kind, tag, group) for tag in a.models], axis=0)
            table = R.family_rows(ensemble, raw, labels[group], seed=2026)
            if group == "lab":
                table = table[table["family"].isin(kind)]
            rows.append(table.assign(held_out="+".join(kind)))
    table = pd.concat(rows, ignore_index=True)
    table["models"] = " ".join(a.models)
    ratio = table["error"] / table["noise_ceiling"]
    print(table.assign(ratio=ratio.round(3))[["held_out", "family", "ratio", "error_hi",
                                              "noise_ceiling", "tension_bias"]].to_string())
    if a.out:
        write_text(a.out, table.to_csv(index=False, float_format="%.5g"))
    return 0


if __name__ == "__main__":
    sys.exit(main())
