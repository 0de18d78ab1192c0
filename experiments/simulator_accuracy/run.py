"""Every simulation method against the expected fields, outside the workflow (any scene).

For moulds 0..n-1 of `generate_mould(seed, id, scene)`: R replicas with the dataset's solver
(the reference ensemble, condor.data.seeds.replica_seed), every method of condor.studies.sweep
(long anneal, short anneals, minimiser, converged hybrid) once per mould, then
condor.studies.accuracy: field error against the expected fields with the noise removed,
interval, the single-simulation ceiling. Writes results/benchmarks/accuracy_<scene>.csv and
the chart; prints the table.
Run: OPENBLAS_NUM_THREADS=1 python experiments/simulator_accuracy/run.py --scene default --moulds 8 \\
         --replicas 4 [--reference-budget 1e4] [--jobs 2]
"""

import argparse
import os
from concurrent.futures import ProcessPoolExecutor
from pathlib import Path

os.environ.setdefault("OPENBLAS_NUM_THREADS", "1")
os.environ.setdefault("NUMBA_NUM_THREADS", "1")

import numpy as np  # noqa: E402
import pandas as pd  # noqa: E402

from condor.config import Config  # noqa: E402
from condor import plots  # noqa: E402
from condor.data.fields import cell_fields  # noqa: E402
from condor.model.scenes import get_scene  # noqa: E402
from condor.data.seeds import replica_seed  # noqa: E402
from condor.model.simulate import warm_up  # noqa: E402
from condor.stages.build import make_mould, simulate_mould  # noqa: E402
from condor.studies import accuracy, recipes, sweep  # noqa: E402

OUT = Path("results/benchmarks")


def one_mould(args):
    scene_name, seed, mould_id, replicas, methods = args
    scene = get_scene(scene_name)
    mould = make_mould(scene, seed, mould_id)
    raw, seconds, energies, n_cells = [], [], [], 0
    for r in range(replicas):
        result = simulate_mould(mould, scene, None, None, replica_seed(seed, mould_id, r))
        raw.append(cell_fields(result.positions, result.orientations, result.tension, scene.box,
                               scene.pixels, scene.sigma))
        seconds.append(result.seconds)
        energies.append(result.energy_per_cell)
        n_cells = result.n_cells
        print(f"mould {mould_id} replica {r}: {result.status} {result.seconds:.1f} s", flush=True)
    rows, fields = sweep.run_methods(mould, scene, methods, seed, log=lambda s: print(s, flush=True))
    return np.stack(raw), np.array(seconds), np.array(energies), n_cells, rows, fields


def main():
    ap = argparse.ArgumentParser()
    ap.add_argument("--scene", default="default")
    ap.add_argument("--seed", type=int, default=Config.default().seed)
    ap.add_argument("--moulds", type=int, default=8)
    ap.add_argument("--replicas", type=int, default=4)
    ap.add_argument("--reference-budget", type=float, default=1e4)
    ap.add_argument("--anneal-budgets", type=float, nargs="+", default=[10, 100, 1000])
    ap.add_argument("--jobs", type=int, default=1, help="moulds simulated in parallel")
    a = ap.parse_args()
    scene = get_scene(a.scene)
    methods = sweep.study_methods(a.reference_budget, a.anneal_budgets)
    warm_up()  # compile once before any fan-out (numba's cache)
    tasks = [(a.scene, a.seed, m, a.replicas, methods) for m in range(a.moulds)]
    if a.jobs > 1:
        with ProcessPoolExecutor(a.jobs) as pool:
            parts = list(pool.map(one_mould, tasks))
    else:
        parts = [one_mould(t) for t in tasks]
    ensemble = recipes.Ensemble(
        moulds=np.arange(a.moulds), raw=np.stack([p[0] for p in parts]),
        n_cells=np.array([float(p[3]) for p in parts]),
        inputs=np.zeros((a.moulds, 2, scene.pixels, scene.pixels), np.uint8),
        pixel_size=scene.pixel_size, seconds=np.stack([p[1] for p in parts]),
        energy_per_cell=np.stack([p[2] for p in parts]))
    answers = []
    for k, method in enumerate(methods):
        answers.append(accuracy.Answer(method.label, method.family,
                                       np.stack([p[5][k] for p in parts]),
                                       np.array([p[4][k]["cpu_s"] for p in parts])))
    table, statistics = accuracy.accuracy_tables(ensemble, answers, seed=a.seed)
    OUT.mkdir(parents=True, exist_ok=True)
    table.to_csv(OUT / f"accuracy_{a.scene}.csv", index=False)
    statistics.to_csv(OUT / f"statistics_{a.scene}.csv", index=False)
    pd.DataFrame([r for p in parts for r in p[4]]).to_csv(OUT / f"sweep_{a.scene}.csv", index=False)
    plots.accuracy_chart(table, OUT / f"accuracy_{a.scene}.png",
                         title=f"scene {a.scene}, {a.moulds} moulds x {a.replicas} replicas")
    cols = ["method", "cpu_s_per_mould", "field_error", "field_error_lo", "field_error_hi",
            "field_error_plain"]
    print(table[cols].to_string(index=False, float_format=lambda v: f"{v:.4g}"))


if __name__ == "__main__":
    main()
