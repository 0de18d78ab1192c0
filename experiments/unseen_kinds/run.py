"""Checkpoints on kinds of mould that no source of condor draws (shapes.py), as a new user
meets them: `condor predict --check N` on each mould (condor.stages.predict.predict_mould, the
same call), which prints the prediction's field error against N simulations' mean (noise
removed) beside one simulation's scatter, the verdict, and the whole-mould numbers both ways.

  python experiments/unseen_kinds/run.py --checkpoint NAME=RUN/models/unet.pt [...] \\
      --variants 2 --check 6 --out experiments/unseen_kinds/CSV

One row a checkpoint x mould: the error and ceiling, their ratio, the predicted and simulated
mean tension (its bias) and alignment (its difference in simulated sd), the verdict's score and
whether it flagged the mould. Then, per checkpoint: the median ratio, the share of moulds above
one simulation's scatter, the median |tension bias|, and how many of the moulds above the
scatter the verdict flagged. The simulations are the check's own (seeded per replica, so every
checkpoint meets the same ones).
"""

from __future__ import annotations

import argparse
import json
import tempfile
from pathlib import Path

import numpy as np
import pandas as pd
import zarr

import condor.stages.check as check_stage
import condor.stages.predict as predict_stage
from condor.files import write_text
from condor.findings import record_finding
from condor.model.scenes import get_scene
from condor.stages.predict import predict_mould

from shapes import KINDS, unseen_mould  # this folder's (on sys.path as for any script)


_SIMULATED: dict = {}
_simulate = check_stage.simulate_mould


def _simulate_once(mould, scene, solver, budget, seed):
    """The check's simulation, run once a mould and seed however many checkpoints meet it."""
    key = (mould.polygon.wkb, np.asarray(mould.tethers).tobytes(), scene.name, solver, budget,
           seed)
    if key not in _SIMULATED:
        _SIMULATED[key] = _simulate(mould, scene, solver, budget, seed)
    return _SIMULATED[key]


check_stage.simulate_mould = _simulate_once
# A study's checkpoint (experiments/generalisation/run.py's) carries no training moulds'
# descriptors, so predict would hold its moulds to the paper generator's area (0.4 +- 50%) and
# refuse some of these: the study scores the network, so the domain check says nothing here
# (the default run's checkpoint, which carries them, refused none of these moulds).
predict_stage.training_domain_check = lambda mould, scene, ranges=None: []


def write_mould(path: Path, outline, posts) -> None:
    spec = {"outline": np.asarray(outline.exterior.coords)[:-1].round(4).tolist(),
            "holes": [np.asarray(h.coords)[:-1].round(4).tolist() for h in outline.interiors],
            "tethers": np.asarray(posts).round(4).tolist(), "units": "l0"}
    path.write_text(json.dumps(spec))


def rows_for(name: str, checkpoint: Path, moulds: list, n_check: int, folder: Path) -> list:
    rows = []
    for kind, variant, path in moulds:
        out = folder / f"{name}_{kind}_{variant}.zarr"
        res = predict_mould(checkpoint, path, out, check=n_check, force=True,
                            say=lambda line: None, warn=lambda line: None)
        c = res.check
        t = c.table.set_index("statistic")
        numbers = zarr.open_group(str(out), mode="r").attrs.get("novelty", {})
        rows.append({"checkpoint": name, "kind": kind, "variant": variant, "replicas": c.n,
                     "error": c.error, "ceiling": c.ceiling, "ratio": c.error / c.ceiling,
                     "tension_predicted": t.loc["mean_tension", "predicted"],
                     "tension_simulated": t.loc["mean_tension", "simulated"],
                     "tension_bias": t.loc["mean_tension", "predicted"]
                     / t.loc["mean_tension", "simulated"] - 1,
                     "alignment_sd": t.loc["alignment", "difference_in_sd"],
                     "tightness": numbers.get("inverse_spread", np.nan),
                     "novelty": numbers.get("novelty", np.nan),
                     "flagged": bool(numbers.get("outside", False))})
        r = rows[-1]
        print(f"{name} {kind} {variant}: {r['ratio']:.2f}x, tension {100 * r['tension_bias']:+.1f}%,"
              f" tightness {r['tightness']:.1f}{' FLAGGED' if r['flagged'] else ''}", flush=True)
    return rows


def summary(table: pd.DataFrame) -> pd.DataFrame:
    out = []
    for name, g in table.groupby("checkpoint", sort=False):
        bad = g["ratio"] > 1
        out.append({"checkpoint": name, "moulds": len(g), "median_ratio": g["ratio"].median(),
                    "above_scatter": int(bad.sum()),
                    "median_abs_tension_bias": g["tension_bias"].abs().median(),
                    "tension_within_3pct": int((g["tension_bias"].abs() <= 0.03).sum()),
                    "caught": int((bad & g["flagged"]).sum()),
                    "false_alarms": int((~bad & g["flagged"]).sum())})
    return pd.DataFrame(out)


def main(argv=None) -> None:
    ap = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    ap.add_argument("--checkpoint", nargs="+", required=True, help="NAME=PATH ...")
    ap.add_argument("--variants", type=int, default=2)
    ap.add_argument("--kinds", nargs="+", default=list(KINDS))
    ap.add_argument("--check", type=int, default=6)
    ap.add_argument("--out", type=Path)
    ap.add_argument("--ship", default=None, metavar="NAME",
                    help="write checkpoint NAME's rows as the product's `never_drawn` finding "
                         "(src/condor/findings), with --commit: that of the default run it is")
    ap.add_argument("--commit", default=None, help="the commit the shipped checkpoint ran at")
    a = ap.parse_args(argv)
    if a.ship and not a.commit:
        ap.error("--ship needs --commit: the commit whose default run made the checkpoint")
    scene = get_scene("default")
    with tempfile.TemporaryDirectory() as tmp:
        folder = Path(tmp)
        moulds = []
        for kind in a.kinds:
            for v in range(a.variants):
                path = folder / f"{kind}_{v}.json"
                write_mould(path, *unseen_mould(kind, v, scene.box))
                moulds.append((kind, v, path))
        rows = []
        for spec in a.checkpoint:
            name, _, path = spec.partition("=")
            rows += rows_for(name, Path(path), moulds, a.check, folder)
    table = pd.DataFrame(rows)
    print(summary(table).round(3).to_string(index=False))
    if a.out:
        write_text(a.out, table.to_csv(index=False))
    if a.ship:
        ship(table[table["checkpoint"] == a.ship], a.commit, a.variants, a.check)


def ship(rows: pd.DataFrame, commit: str, variants: int, n_check: int) -> None:
    """The shipped checkpoint's rows as the `never_drawn` finding (condor.findings)."""
    if rows.empty:
        raise SystemExit("--ship names no checkpoint of --checkpoint")
    columns = ["kind", "variant", "replicas", "error", "ceiling", "ratio", "tension_bias",
               "tightness"]
    record_finding("never_drawn", {
        "question": "How close does the default run's checkpoint come, and how far off is its "
                    "mean tension, on kinds of mould that no training source draws?",
        "table": "never_drawn.csv",
        "experiment": "experiments/unseen_kinds",
        "source": f"experiments/unseen_kinds/run.py --variants {variants} --check {n_check}: "
                  f"{rows['kind'].nunique()} kinds x {variants} moulds (shapes.py), each "
                  f"checked by {n_check} simulations as `condor predict --check` checks it, "
                  "with the default run's checkpoint",
        "commit": commit}, rows[columns])


if __name__ == "__main__":
    main()
