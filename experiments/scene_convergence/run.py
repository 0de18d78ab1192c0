"""Scene convergence (condor.studies.convergence): the systematic change of the fields with
depth and box size, against one simulation's scatter. Writes
results/benchmarks/scene_convergence.csv and .png.

Quick: 1 mould, depths 2/3/4 l0, the default box and the paper box (the same mould at twice
the scale), 3 seeds each. Full: 3 moulds, depths 1.5/2/3/4.
Run: OPENBLAS_NUM_THREADS=1 python experiments/scene_convergence/run.py [--quick] [--jobs 2]
"""

import argparse
import os
from concurrent.futures import ProcessPoolExecutor
from pathlib import Path

os.environ.setdefault("OPENBLAS_NUM_THREADS", "1")
os.environ.setdefault("NUMBA_NUM_THREADS", "1")

import pandas as pd  # noqa: E402

from condor.config import Config  # noqa: E402
from condor import plots  # noqa: E402
from condor.model.scenes import get_scene  # noqa: E402
from condor.model.simulate import warm_up  # noqa: E402
from condor.stages.build import make_mould  # noqa: E402
from condor.studies.convergence import convergence  # noqa: E402

OUT = Path("results/benchmarks")
SCENE = get_scene("default")


def one_mould(args) -> pd.DataFrame:
    mould_id, depths, seeds = args
    return convergence(SCENE, [make_mould(SCENE, Config.default().seed, mould_id)], seeds, depths, (1.0, 2.0),
                       log=lambda s: print(s, flush=True))


def main():
    ap = argparse.ArgumentParser()
    ap.add_argument("--quick", action="store_true")
    ap.add_argument("--seeds", type=int, default=3)
    ap.add_argument("--jobs", type=int, default=1, help="moulds simulated in parallel")
    a = ap.parse_args()
    depths = (2.0, 3.0, 4.0) if a.quick else (1.5, 2.0, 3.0, 4.0)
    tasks = [(m, depths, a.seeds) for m in range(1 if a.quick else 3)]
    warm_up()
    if a.jobs > 1:
        with ProcessPoolExecutor(a.jobs) as pool:
            df = pd.concat(pool.map(one_mould, tasks), ignore_index=True)
    else:
        df = pd.concat([one_mould(t) for t in tasks], ignore_index=True)
    OUT.mkdir(parents=True, exist_ok=True)
    suffix = "_quick" if a.quick else ""
    df.to_csv(OUT / f"scene_convergence{suffix}.csv", index=False)
    plots.convergence_chart(df, OUT / f"scene_convergence{suffix}.png")
    cols = ["study", "mould", "value", "n_cells", "cpu_s", "change_P", "change_T", "change_Sx2",
            "change_Sz2", "noise_P", "noise_T", "justified"]
    with pd.option_context("display.width", 200, "display.max_columns", 20):
        print(df[cols].to_string(index=False, float_format=lambda v: f"{v:.3g}"))


if __name__ == "__main__":
    main()
