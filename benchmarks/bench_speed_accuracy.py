"""Speed against accuracy of the solvers (condor.tradeoff.sweep): table, CSV and PNG.

Writes results/benchmarks/speed_accuracy_<scene>.csv and .png (and speed_accuracy.png over
every scene CSV present). CPU seconds, one thread per process; --jobs runs moulds in parallel
processes (each timing its own CPU time).
Run: OPENBLAS_NUM_THREADS=1 python benchmarks/bench_speed_accuracy.py [--quick] [--scene paper]
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
# Longest affordable anneal (moves per cell) per scene: about 1 min of CPU at the paper scene.
REFERENCE_BUDGET = {"tiny": 1e4, "default": 1e4, "paper": 2e3}


def plan(quick: bool, scene: str) -> dict:
    if scene == "paper":  # ~9,400 cells: the leanest informative set
        methods = [m for m in tradeoff.default_methods((100, 1000))
                   if m.label != "minimise ftol 0.0001"]
    else:
        methods = tradeoff.default_methods((10, 100, 1000) if quick else (10, 100, 1000, 3000))
    return dict(
        scene=scene,
        seeds=(1,) if quick or scene == "paper" else (1, 2),
        methods=methods,
        reference_budget=REFERENCE_BUDGET.get(scene, 1e4) / (10 if quick else 1),
    )


def one_mould(args) -> pd.DataFrame:
    mould_id, kwargs = args
    return tradeoff.sweep(mould_ids=(mould_id,), log=lambda s: print(s, flush=True), **kwargs)


def main():
    ap = argparse.ArgumentParser()
    ap.add_argument("--quick", action="store_true", help="2 moulds, 1 seed, short reference")
    ap.add_argument("--scene", default="default")
    ap.add_argument("--moulds", type=int, default=None, help="number of moulds (ids 0..n-1)")
    ap.add_argument("--jobs", type=int, default=1, help="moulds simulated in parallel")
    a = ap.parse_args()
    n_moulds = a.moulds or (2 if a.quick else 5)
    kwargs = plan(a.quick, a.scene)
    warm_up()  # compile once before any fan-out (numba's cache)
    tasks = [(m, kwargs) for m in range(n_moulds)]
    if a.jobs > 1:
        with ProcessPoolExecutor(a.jobs) as pool:
            parts = list(pool.map(one_mould, tasks))
    else:
        parts = [one_mould(t) for t in tasks]
    df = pd.concat(parts, ignore_index=True)
    OUT.mkdir(parents=True, exist_ok=True)
    suffix = "_quick" if a.quick else ""
    df.to_csv(OUT / f"speed_accuracy_{a.scene}{suffix}.csv", index=False)
    tradeoff.chart(df, OUT / f"speed_accuracy_{a.scene}{suffix}.png")
    paths = sorted(OUT.glob("speed_accuracy_*.csv"))
    full = [pd.read_csv(p) for p in paths if "quick" not in p.name]
    if full:
        tradeoff.chart(pd.concat(full, ignore_index=True), OUT / "speed_accuracy.png")
    with pd.option_context("display.width", 200, "display.max_columns", 20):
        print(tradeoff.summary(df).to_string(index=False, float_format=lambda v: f"{v:.4g}"))


if __name__ == "__main__":
    main()
