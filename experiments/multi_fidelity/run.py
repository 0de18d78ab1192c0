"""How close is a cheap simulation to a mould's expected fields, on kinds of mould that no
training source draws? A feasibility measure for a surrogate that reads a cheap simulation
instead of only the mould (a multi-fidelity corrector), where the surrogate that reads the
mould alone sits at one simulation's scatter (experiments/unseen_kinds, check_verdict).

For each mould of experiments/unseen_kinds' kinds (variants 0..V-1): the truth is 8 simulations
at the product's budget (the seeds of experiments/check_verdict's truth, so that its surrogate
ratios join mould by mould); for each cheap budget, 4 simulations of other seeds. Per mould
and budget: the cheap runs' bias (the distance of their expected fields from the truth's, both
noise-corrected: condor.measures.estimators.ensemble_distance), one cheap run's error against
the truth's expected fields (noise removed), each over one full simulation's scatter, and the
CPU seconds of a cheap and a full run.

  python experiments/multi_fidelity/run.py --variants 5 --budgets 20 50 \\
      --out experiments/multi_fidelity/unseen_cheap.csv
"""

from __future__ import annotations

import argparse
import runpy
import time
from pathlib import Path

import numpy as np
import pandas as pd

from condor.data.fields import cell_fields, normalise
from condor.data.seeds import replica_seed
from condor.files import write_text
from condor.measures import estimators as est
from condor.model.scenes import get_scene
from condor.moulds.mould import Mould
from condor.stages.build import simulate_mould
from condor.stages.check import CHECK_SEED

HERE = Path(__file__).resolve().parent
TRUTH = range(6, 14)  # experiments/check_verdict's truth: replica_seed(CHECK_SEED, 0, k)
CHEAP_SEED = CHECK_SEED + 1  # the cheap runs' own streams
CHEAP_RUNS = 4


def fields_of(mould, scene, budget, seed):
    t = time.process_time()
    r = simulate_mould(mould, scene, None, budget, seed)
    if r.status != "ok":
        raise RuntimeError(f"simulation failed: {r.status}")
    raw = cell_fields(r.positions, r.orientations, r.tension, scene.box, scene.pixels,
                      scene.sigma)
    return normalise(raw, len(r.positions)), time.process_time() - t


def main(argv=None) -> None:
    ap = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    ap.add_argument("--variants", type=int, default=5)
    ap.add_argument("--budgets", type=float, nargs="+", default=[20, 50])
    ap.add_argument("--out", type=Path, required=True)
    a = ap.parse_args(argv)
    shapes = runpy.run_path(str(Path(__file__).resolve().parents[1] / "unseen_kinds"
                                / "shapes.py"))
    KINDS, unseen_mould = shapes["KINDS"], shapes["unseen_mould"]  # that study's own kinds

    scene = get_scene("default")
    rows = []
    for kind in KINDS:
        for v in range(a.variants):
            outline, posts = unseen_mould(kind, v, scene.box)
            mould = Mould(box=scene.box, polygon=outline, tethers=np.asarray(posts, float))
            truth = [fields_of(mould, scene, None, replica_seed(CHECK_SEED, 0, k)) for k in TRUTH]
            reps = np.stack([f for f, _ in truth])[None].astype(np.float64)
            scatter = float(est.noise_ceiling(reps)[0])
            full_s = float(np.median([s for _, s in truth]))
            for budget in a.budgets:
                cheap = [fields_of(mould, scene, budget, replica_seed(CHEAP_SEED, 0, k))
                         for k in range(CHEAP_RUNS)]
                c = np.stack([f for f, _ in cheap])[None].astype(np.float64)
                bias = float(est.ensemble_distance(c, reps).corrected[0])
                one = float(np.mean([est.mse_against_expected(c[:, k], reps).corrected[0]
                                     for k in range(CHEAP_RUNS)]))
                rows.append({"mould": f"{kind}_{v}", "budget": budget, "scatter": np.sqrt(scatter),
                             "bias_ratio": np.sqrt(max(bias, 0.0) / scatter),
                             "one_run_ratio": np.sqrt(max(one, 0.0) / scatter),
                             "cheap_cpu_s": float(np.median([s for _, s in cheap])),
                             "full_cpu_s": full_s})
                r = rows[-1]
                print(f"{r['mould']} budget {budget:g}: bias {r['bias_ratio']:.2f}x, one run "
                      f"{r['one_run_ratio']:.2f}x, {r['cheap_cpu_s']:.2f} s against "
                      f"{full_s:.2f} s", flush=True)
    table = pd.DataFrame(rows)
    write_text(a.out, table.to_csv(index=False, float_format="%.5g"))
    print(table.groupby("budget")[["bias_ratio", "one_run_ratio", "cheap_cpu_s",
                                   "full_cpu_s"]].median().to_string())


if __name__ == "__main__":
    main()
