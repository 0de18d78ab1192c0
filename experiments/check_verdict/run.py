"""Does a check of N simulations tell which moulds the surrogate gets wrong? For each mould
(experiments/unseen_kinds' kinds that no training source draws, and the lab and paper test moulds
of a default run's store), the prediction of a checkpoint is scored twice: against N simulations
seeded as `condor predict --check N` seeds them (the check), and against 8 more simulations of
other seeds (the truth). A mould is above the scatter when its error against the expected
fields (noise removed) exceeds one simulation's scatter; the check's verdict is that of its own
N replicas. One row a mould and N: both ratios, the check's seconds.

  python experiments/check_verdict/run.py --checkpoint RUN/models/unet.pt \\
      --store RUN/dataset.zarr --test-moulds 60 --variants 5 \\
      --out experiments/check_verdict/check_verdict.csv

Beside them, what predict's verdict says without a check (the tightness, flagged or not).
"""

from __future__ import annotations

import argparse
import runpy
import time
from types import SimpleNamespace
from pathlib import Path

import numpy as np
import pandas as pd

import condor.stages.predict as predict_stage
from condor.data.fields import cell_fields, normalise
from condor.data.seeds import replica_seed
from condor.files import write_text
from condor.measures import estimators as est
from condor.model.scenes import get_scene
from condor.moulds.mould import PAPER, Mould
from condor.stages.build import simulate_mould
from condor.stages.check import CHECK_SEED
from condor.surrogate.predict import Predictor

TRUTH = 8  # replicas of the truth, seeds after the check's largest N
CHECKS = (2, 3, 4, 6)


def simulate(mould, scene, k):
    t = time.process_time()
    r = simulate_mould(mould, scene, None, None, replica_seed(CHECK_SEED, 0, k))
    if r.status != "ok":
        return None, time.process_time() - t
    raw = cell_fields(r.positions, r.orientations, r.tension, scene.box, scene.pixels,
                      scene.sigma)
    return normalise(raw, len(r.positions)), time.process_time() - t


def ratio(predicted, replicas):
    reps = np.asarray(replicas, dtype=np.float64)[None]
    err = est.root_mean(est.mse_against_expected(predicted[None], reps).corrected)
    return err / est.root_mean(est.noise_ceiling(reps))


def combined(predicted, replicas):
    """(the replicas' mean, the prediction and that mean combined, the prediction's weight in
    density and orientation): condor.stages.check.best_estimate, weights by the prediction's
    measured error and the mean's noise (the tension weighed apart since 2026-12-07)."""
    from condor.stages.check import best_estimate

    reps = np.asarray(replicas, dtype=np.float64)
    best, weights = best_estimate(predicted, reps)
    return reps.mean(axis=0), best, float(weights[0])


def moulds_to_score(a, scene):
    shapes = runpy.run_path(str(Path(__file__).resolve().parents[1] / "unseen_kinds"
                                / "shapes.py"))
    KINDS, unseen_mould = shapes["KINDS"], shapes["unseen_mould"]  # that study's own kinds
    out = []
    for kind in KINDS:
        for v in range(a.variants):
            outline, posts = unseen_mould(kind, v, scene.box)
            mould = Mould(box=scene.box, polygon=outline, tethers=np.asarray(posts, dtype=float))
            out.append(("never drawn", f"{kind}_{v}", mould))
    if a.store is not None:
        from condor.data.store import open_store
        from condor.moulds.sources import make_mould  # the store's mould, as built

        ds = open_store(a.store)
        seed = int(ds.attrs["seed"])
        test = np.flatnonzero((ds["split"].values.astype(str) == "test")
                              & (ds["replica"].values == 0))
        for i in test[: a.test_moulds]:
            m = int(ds["mould"].values[i])
            fam = str(ds["family"].values[i])
            mould = make_mould(scene, seed, m, fam)
            assert len(mould.tethers) == int(ds["n_tethers"].values[i]), (m, fam)
            out.append(("paper test" if fam == PAPER else "lab test", f"{fam}_{m}", mould))
    return out


def verdict_of(predictor, inputs, lattice, prediction) -> dict:
    """What predict's verdict says of the mould without a check: the tightness and whether
    the shipped threshold flags it (condor.stages.predict.mould_novelty_verdict)."""
    from condor.surrogate.novelty import bank_of

    _, numbers = predict_stage.mould_novelty_verdict(predictor, bank_of(predictor.state),
                                                     inputs, lattice, prediction)
    return {"tightness": numbers.get("inverse_spread", np.nan),
            "flagged": bool(numbers.get("outside", False))}


def main(argv=None) -> None:
    ap = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    ap.add_argument("--checkpoint", type=Path, required=True)
    ap.add_argument("--store", type=Path, default=None, help="a default run's dataset.zarr: "
                    "its test moulds too")
    ap.add_argument("--test-moulds", type=int, default=40)
    ap.add_argument("--variants", type=int, default=3)
    ap.add_argument("--out", type=Path, required=True)
    ap.add_argument("--verdict-only", action="store_true",
                    help="add the verdict's columns to --out's rows (predictions only, no "
                         "simulation: they are deterministic)")
    a = ap.parse_args(argv)
    scene = get_scene("default")
    predictor = Predictor(a.checkpoint)
    rows, verdicts = [], {}
    for group, name, mould in moulds_to_score(a, scene):
        placement = SimpleNamespace(mould=mould)  # as predict places a mould file
        inputs, n_cells, lattice = predict_stage.mould_inputs(predictor, mould, placement, print)
        prediction = predictor(inputs, n_cells=n_cells, lattice=lattice)
        predicted = np.asarray(prediction.normalised, dtype=np.float64)
        verdict = verdict_of(predictor, inputs, lattice, prediction)
        if a.verdict_only:
            verdicts[name] = verdict
            continue
        sims = [simulate(mould, scene, k) for k in range(max(CHECKS) + TRUTH)]
        fields = [f for f, _ in sims]
        if any(f is None for f in fields):
            print(f"{name}: a simulation failed; left out", flush=True)
            continue
        truth = ratio(predicted, fields[max(CHECKS):])
        for n in CHECKS:
            mean, best, weight = combined(predicted, fields[:n])
            rows.append({"group": group, "mould": name, "n_check": n,
                         "check_ratio": ratio(predicted, fields[:n]), "truth_ratio": truth,
                         "mean_ratio": ratio(mean, fields[max(CHECKS):]),
                         "best_ratio": ratio(best, fields[max(CHECKS):]), "weight": weight,
                         "check_cpu_s": sum(s for _, s in sims[:n]), **verdict})
        print(f"{group} {name}: truth {truth:.2f}x, check(4) {rows[-2]['check_ratio']:.2f}x",
              flush=True)
    if a.verdict_only:
        table = pd.read_csv(a.out).drop(columns=["tightness", "flagged"], errors="ignore")
        table = table.join(pd.DataFrame(verdicts).T, on="mould")
    else:
        table = pd.DataFrame(rows)
    write_text(a.out, table.to_csv(index=False, float_format="%.5g"))
    print(summary(table).to_string(index=False))


def summary(table: pd.DataFrame) -> pd.DataFrame:
    out = []
    for (group, n), g in table.groupby(["group", "n_check"]):
        bad, said = g["truth_ratio"] > 1, g["check_ratio"] > 1
        flag = g["flagged"].astype(bool)
        out.append({"group": group, "n_check": n, "moulds": len(g), "above": int(bad.sum()),
                    "caught": int((bad & said).sum()), "false_alarms": int((~bad & said).sum()),
                    "verdict_caught": int((bad & flag).sum()),
                    "verdict_false_alarms": int((~bad & flag).sum()),
                    "median_cpu_s": g["check_cpu_s"].median()})
    return pd.DataFrame(out)


if __name__ == "__main__":
    main()
