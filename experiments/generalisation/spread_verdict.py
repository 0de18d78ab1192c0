"""Does the surrogate's own predicted scatter tell the moulds it gets wrong better than the
novelty score? (experiments/generalisation/README.md, "The predicted scatter as a verdict").

A mould's error is "above one simulation's scatter" when its squared error against the
expected fields exceeds one simulation's (novelty.py's `bad`). Where that scatter is small
(moulds held tightly by their posts) the bar is low. The surrogate predicts the scatter: its
reproducibility, the RMS of the spread map over the tissue pixels (as `condor predict` prints
it, condor.surrogate.answer.mould_summary). For every model x test mould of novelty.py's table
(`--table`, e.g. rim_n500/novelty_moulds.csv; the models found in --cache by their names), this
computes the reproducibility, then each score's AUROC for `bad`, the share caught at 20%
false alarms and the false alarms at 90% caught (novelty.py's `flagging`):

- the feature distance (the shipped verdict's score);
- 1 / reproducibility (a tight predicted scatter: likely above it);
- their product's log, log(feature distance) - log(reproducibility).

  python experiments/generalisation/spread_verdict.py --pool POOL --fresh FRESH \\
      --cache CACHE --table experiments/generalisation/rim_n500/novelty_moulds.csv \\
      --out experiments/generalisation/rim_n500/spread_verdict.csv
"""

from __future__ import annotations

import argparse
import sys
from pathlib import Path

import numpy as np
import pandas as pd

from condor.data.store import open_store
from condor.surrogate.predict import Predictor
from condor.surrogate.samples import model_inputs

import run as study  # noqa: E402  (this folder's study, on sys.path as for any script)
from novelty import flagging  # noqa: E402  (this folder's novelty.py: AUROC, caught at 20%)

FRESH = "fresh seed"


def reproducibility(checkpoint: Path, ds) -> pd.DataFrame:
    """Per test mould of ds (replica 0): the RMS of the predicted spread over the pixels the
    predicted density covers (P > 0), as mould_summary's `reproducibility`."""
    ids = [int(i) for i in study.first_replicas(ds, "test")]
    position = {int(m): i for i, m in enumerate(np.asarray(ds["sample"].values))}
    pos = [position[m] for m in ids]
    predictor = Predictor(checkpoint)
    lattice = model_inputs(ds, pos, "lattice") if predictor.needs_lattice else None
    out = predictor(model_inputs(ds, pos, "mask"), n_cells=np.asarray(ds["n_cells"].values)[pos],
                    lattice=lattice)
    rms = [float(np.sqrt((out.spread[k][:, out.normalised[k, 0] > 0] ** 2).mean()))
           for k in range(len(ids))]
    return pd.DataFrame({"mould": ids, "reproducibility": rms})


def main(argv=None) -> int:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--pool", type=Path, required=True)
    ap.add_argument("--fresh", type=Path, required=True)
    ap.add_argument("--cache", type=Path, required=True)
    ap.add_argument("--table", type=Path, required=True, help="novelty.py's novelty_moulds.csv")
    ap.add_argument("--out", type=Path, required=True)
    a = ap.parse_args(argv)
    table = pd.read_csv(a.table)
    table["store"] = np.where(table["family"] == FRESH, "fresh", "pool")
    stores = {"pool": open_store(a.pool), "fresh": open_store(a.fresh)}
    parts = []
    for name in table["model"].unique():
        found = [p for p in a.cache.glob(f"{name}_e*_*.pt")]
        if len(found) != 1:
            raise SystemExit(f"{len(found)} checkpoints of {name} in {a.cache}, not one")
        for store, ds in stores.items():
            parts.append(reproducibility(found[0], ds).assign(model=name, store=store))
    rows = table.merge(pd.concat(parts, ignore_index=True), on=["model", "mould", "store"],
                       how="left", validate="one_to_one")
    if rows["reproducibility"].isna().any():
        raise SystemExit("a mould of the table has no prediction")
    rows["inverse_spread"] = 1.0 / rows["reproducibility"]
    rows["feature_over_spread"] = (np.log(rows["feature_distance"])
                                   - np.log(rows["reproducibility"]))
    scores = ("feature_distance", "inverse_spread", "feature_over_spread")
    summary = []
    for scope, part in [("every model x test mould", rows),
                        ("moulds of the held-out kinds", rows[rows["held_out_mould"]]),
                        *[(f"held out {h}", g) for h, g in rows.groupby("held_out")]]:
        for score in scores:
            summary.append({"scope": scope, "score": score,
                            **flagging(part[score].to_numpy(float),
                                       part["bad"].to_numpy(bool))})
    summary = pd.DataFrame(summary)
    a.out.parent.mkdir(parents=True, exist_ok=True)
    summary.to_csv(a.out, index=False)
    rows.to_csv(a.out.with_name(a.out.stem + "_moulds.csv"), index=False)
    print(summary.round(3).to_string(index=False))
    return 0


if __name__ == "__main__":
    sys.exit(main())
