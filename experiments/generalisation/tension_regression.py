"""Could whole-mould descriptors alone predict the mean tension? A least-squares fit of log
(sum T / sum P) on the log of the spring prior's mean stress (condor.data.inputs.stress_channels,
weighted by the lattice channels), the fixed cells' share, the posts, the area and the mean
stress anisotropy, over the pool's tethered training moulds (replica 0), each kind held out in
turn as run.py's models are (experiments/generalisation/README.md, "Composite moulds").

  python experiments/generalisation/tension_regression.py --pool POOL
"""

from __future__ import annotations

import argparse
import sys
from pathlib import Path

import numpy as np
import pandas as pd

from condor.data.inputs import stress_channels
from condor.data.store import open_store

from run import KINDS  # noqa: E402  (this folder's study)


def descriptors(ds) -> pd.DataFrame:
    ok = (np.asarray(ds["status"].values).astype(str) == "ok") & (ds["replica"].values == 0)
    idx = np.flatnonzero(ok)
    stress = stress_channels(ds["inputs"].values[idx].astype(np.float32))
    fields = ds["fields"].values[idx].astype(np.float64)
    lattice = ds["lattice"].values[idx].astype(np.float64)
    cells = lattice.sum(axis=1)

    def mean(a):
        return (a * cells).sum((1, 2)) / cells.sum((1, 2))

    return pd.DataFrame({
        "mould": ds["mould"].values[idx], "family": ds["family"].values[idx].astype(str),
        "split": ds["split"].values[idx].astype(str), "n_tethers": ds["n_tethers"].values[idx],
        "tension": fields[:, 1].sum((1, 2)) / fields[:, 0].sum((1, 2)),
        "stress": mean(stress[:, 0] + stress[:, 1]),
        "anisotropy": mean(np.abs(stress[:, 0] - stress[:, 1])),
        "fixed_share": lattice[:, 1].sum((1, 2)) / cells.sum((1, 2)), "area": cells.sum((1, 2))})


def design(d: pd.DataFrame) -> np.ndarray:
    return np.column_stack([np.ones(len(d)), np.log(d["stress"].clip(1e-3)),
                            np.log(d["fixed_share"]), np.log(d["n_tethers"]), np.log(d["area"]),
                            np.log(d["anisotropy"].clip(1e-3))])


def main(argv=None) -> int:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--pool", type=Path, required=True, help="the pool's dataset.zarr")
    a = ap.parse_args(argv)
    d = descriptors(open_store(a.pool))
    d = d[d["n_tethers"] > 0]
    rows = []
    for held in [(), *KINDS]:
        train = d[(d["split"] == "train") & ~d["family"].isin(held)]
        beta, *_ = np.linalg.lstsq(design(train), np.log(train["tension"]), rcond=None)
        test = d[(d["split"] == "test") & (d["family"].isin(held) if held else True)]
        ratio = np.exp(design(test) @ beta) / test["tension"]
        for family, r in ratio.groupby(test["family"]):
            rows.append({"held_out": "+".join(held) or "none", "family": family,
                         "median_ratio": float(np.median(r)),
                         "median_abs_log_ratio": float(np.median(np.abs(np.log(r))))})
    table = pd.DataFrame(rows)
    print(table.round(3).to_string(index=False))
    return 0


if __name__ == "__main__":
    sys.exit(main())
