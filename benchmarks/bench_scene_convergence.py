"""Scene convergence (condor.tradeoff.convergence): fields against depth and box size, with a
seed-to-seed noise baseline. Writes results/benchmarks/scene_convergence.csv and .png.

Quick: 1 mould, depths 2/3/4 l0, default box and the paper box (the same mould at twice the
scale). Full: 3 moulds, depths 1.5/2/3/4.
Run: OPENBLAS_NUM_THREADS=1 python benchmarks/bench_scene_convergence.py [--quick]
"""

import argparse
import os
from concurrent.futures import ProcessPoolExecutor
from pathlib import Path

os.environ.setdefault("OPENBLAS_NUM_THREADS", "1")
os.environ.setdefault("NUMBA_NUM_THREADS", "1")

import pandas as pd  # noqa: E402

from condor import tradeoff  # noqa: E402
from condor.simulate import warm_up  # noqa: E402

OUT = Path("results/benchmarks")


def one_mould(args) -> pd.DataFrame:
    mould_id, depths = args
    return tradeoff.convergence("default", mould_ids=(mould_id,), seeds=(0, 1), depths=depths,
                                box_scales=(1.0, 2.0), log=lambda s: print(s, flush=True))


def main():
    ap = argparse.ArgumentParser()
    ap.add_argument("--quick", action="store_true")
    ap.add_argument("--jobs", type=int, default=1, help="moulds simulated in parallel")
    a = ap.parse_args()
    depths = (2.0, 3.0, 4.0) if a.quick else (1.5, 2.0, 3.0, 4.0)
    tasks = [(m, depths) for m in range(1 if a.quick else 3)]
    warm_up()
    if a.jobs > 1:
        with ProcessPoolExecutor(a.jobs) as pool:
            df = pd.concat(pool.map(one_mould, tasks), ignore_index=True)
    else:
        df = pd.concat([one_mould(t) for t in tasks], ignore_index=True)
    OUT.mkdir(parents=True, exist_ok=True)
    suffix = "_quick" if a.quick else ""
    df.to_csv(OUT / f"scene_convergence{suffix}.csv", index=False)
    tradeoff.convergence_chart(df, OUT / f"scene_convergence{suffix}.png")
    cols = ["study", "value", "baseline", "n_cells", "seconds", "rel_P", "rel_T", "rel_Sx2",
            "rel_Sy2", "rel_Sz2", "rel_mean", "noise", "within_noise"]
    with pd.option_context("display.width", 200, "display.max_columns", 20):
        print(tradeoff.convergence_summary(df)[cols].to_string(
            index=False, float_format=lambda v: f"{v:.3g}"))


if __name__ == "__main__":
    main()
