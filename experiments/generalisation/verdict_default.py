"""The shipped novelty verdict as a user meets it: a default run's own checkpoint on replicated
lab and paper moulds (experiments/generalisation/README.md, "The verdict with the default
checkpoint").

For every replicated mould of each store: its novelty (condor.surrogate.novelty's feature
distance to the checkpoint's own training bank, as `condor predict` computes it), the
predicted scatter's inverse_spread, each verdict (the shipped calibration's score above its
threshold; the feature distance above its former threshold, 1.34) and the error over one
simulation's scatter
against the expected fields (noise removed; run.per_mould). Prints, per store, how many moulds
lie above one simulation's scatter and how many of those the verdict flags (caught), and how
many of the others it flags (false alarms); writes every mould with --out.

  python experiments/generalisation/verdict_default.py --checkpoint RUN/models/unet.pt \\
      --store RUN/dataset.zarr results/unseen_seed99/dataset.zarr --out CSV
"""

from __future__ import annotations

import argparse
import sys
from pathlib import Path

import numpy as np
import pandas as pd

from condor.data.store import open_store
from condor.findings import load_findings
from condor.moulds.mould import PAPER
from condor.studies.recipes import reference_ensemble
from condor.surrogate.novelty import bank_of, inverse_spread, mould_novelty, network_inputs
from condor.surrogate.predict import Predictor
from condor.surrogate.samples import model_inputs

import run as study  # noqa: E402  (this folder's study, on sys.path as for any script)

FEATURE_THRESHOLD = 1.3425829998344263  # the feature distance's calibrated threshold (9b32aad)


def store_rows(path: Path, predictor, bank) -> pd.DataFrame:
    ds = open_store(path)
    ids = [int(i) for i in study.first_replicas(ds, "test")]
    ensemble = reference_ensemble(ds, ids)
    family = study.families_of(ds)
    labels = [str(family[int(m)]) for m in ensemble.moulds]
    position = {int(m): i for i, m in enumerate(np.asarray(ds["sample"].values))}
    pos = [position[int(m)] for m in ensemble.moulds]
    masks = model_inputs(ds, pos, "mask")
    lattice = model_inputs(ds, pos, "lattice") if predictor.needs_lattice else None
    out = predictor(masks, n_cells=np.asarray(ds["n_cells"].values)[pos], lattice=lattice)
    rows = study.per_mould(ensemble, out.raw.astype(np.float64), labels)
    x = network_inputs(predictor.inputs_kind, masks, lattice)
    rows["novelty"] = mould_novelty(predictor.model, predictor.inputs_kind, bank, x)
    rows["inverse_spread"] = inverse_spread(out.spread, out.normalised)
    rows["ratio"] = np.sqrt(rows["squared_error"].clip(lower=0) / rows["noise"])
    rows["store"] = str(path)
    rows["source"] = np.where(rows["family"] == PAPER, "paper", "lab")
    return rows


def main(argv=None) -> int:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--checkpoint", type=Path, required=True)
    ap.add_argument("--store", type=Path, nargs="+", required=True)
    ap.add_argument("--out", type=Path, default=None)
    a = ap.parse_args(argv)
    predictor = Predictor(a.checkpoint)
    bank = bank_of(predictor.state)
    if bank is None:
        raise SystemExit(f"{a.checkpoint} carries no training bank (trained before novelty)")
    rows = pd.concat([store_rows(p, predictor, bank) for p in a.store],
                     ignore_index=True)
    finding = load_findings()["novelty"]
    # the shipped verdict's score and threshold, and the feature distance's of 9b32aad's
    # calibration (its threshold 1.34) beside it
    verdicts = {finding.values["score"]: float(finding.values["threshold"]),
                "feature_distance": FEATURE_THRESHOLD}
    column = {"feature_distance": "novelty", "inverse_spread": "inverse_spread"}
    for score, threshold in verdicts.items():
        rows[f"flagged_{score}"] = rows[column[score]] > threshold
        for (store, source), g in rows.groupby(["store", "source"]):
            bad, flag = g["ratio"] > 1, g[f"flagged_{score}"]
            print(f"{score} > {threshold:.3g}: {store} {source}: {len(g)} moulds, "
                  f"{int(bad.sum())} above one simulation's scatter, {int((flag & bad).sum())} "
                  f"of them flagged; {int((flag & ~bad).sum())} of the {int((~bad).sum())} "
                  "others flagged")
        bad, flag = rows["ratio"] > 1, rows[f"flagged_{score}"]
        print(f"{score}: all {len(rows)}: {int((flag & bad).sum())} of {int(bad.sum())} caught, "
              f"{int((flag & ~bad).sum())} of {int((~bad).sum())} false alarms")
    if a.out is not None:
        rows.to_csv(a.out, index=False)
    return 0


if __name__ == "__main__":
    sys.exit(main())
