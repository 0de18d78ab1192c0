"""Energy per cell and field MAE against a long-anneal reference, versus CPU seconds.

For each mould (condor.moulds.generate_mould) and seed: anneal budgets over several decades,
the minimiser and the hybrid; the reference is the lowest-energy result of the longest anneal
followed by the minimiser. Prints a table, writes results/benchmarks/speed_accuracy_<scene>.csv.
Run: OPENBLAS_NUM_THREADS=1 python benchmarks/bench_speed_accuracy.py [--quick] [--scene paper]
"""

import argparse
import csv
from pathlib import Path

import numpy as np

from condor.scenes import get_scene
from condor.simulate import simulate


def fields_of(result, scene):
    try:
        from condor.fields import cell_fields
    except ImportError:
        return None
    return cell_fields(result.positions, result.orientations, result.tension, scene.box,
                       scene.pixels, scene.sigma)


def main():
    ap = argparse.ArgumentParser()
    ap.add_argument("--quick", action="store_true")
    ap.add_argument("--scene", default="default")
    ap.add_argument("--moulds", type=int, default=None)
    a = ap.parse_args()
    scene = get_scene(a.scene)
    from condor.moulds import generate_mould

    n_moulds = a.moulds or (2 if a.quick else 5)
    budgets = [10, 100, 1000] if a.quick else [10, 100, 1000, 10000]
    ref_budget = 10 * budgets[-1]
    rows = []
    for mould_id in range(n_moulds):
        m = generate_mould(0, mould_id, scene.box)
        runs = [("anneal", b) for b in budgets] + [("minimise", None), ("hybrid", None)]
        ref = simulate(m.polygon, m.tethers, scene.depth, "hybrid", ref_budget, seed=0)
        ref_fields = fields_of(ref, scene)
        for solver, budget in runs:
            r = simulate(m.polygon, m.tethers, scene.depth, solver, budget, seed=1)
            f = fields_of(r, scene)
            mae = float(np.abs(f - ref_fields).mean()) if f is not None else float("nan")
            rows.append(dict(mould=mould_id, solver=solver, budget=r.budget, n_cells=r.n_cells,
                             seconds=r.seconds, energy_per_cell=r.energy_per_cell,
                             rel_to_ref=r.energy / ref.energy - 1, field_mae=mae, status=r.status))
            print(f"mould {mould_id} {solver:8s} budget {r.budget:8.0f} cells {r.n_cells:5d} "
                  f"{r.seconds:7.2f} s  E/cell {r.energy_per_cell:.5f}  vs ref {rows[-1]['rel_to_ref']:+.3%} "
                  f"MAE {mae:.4f} {r.status}")
        print(f"mould {mould_id} reference hybrid({ref_budget}) {ref.seconds:.1f} s E/cell {ref.energy_per_cell:.5f}")
    out = Path("results/benchmarks")
    out.mkdir(parents=True, exist_ok=True)
    with open(out / f"speed_accuracy_{scene.name}.csv", "w", newline="") as fh:
        w = csv.DictWriter(fh, fieldnames=rows[0].keys())
        w.writeheader()
        w.writerows(rows)
    for solver in ("minimise", "hybrid"):
        sel = [r for r in rows if r["solver"] == solver]
        print(f"{solver}: median {np.median([r['seconds'] for r in sel]):.2f} s, "
              f"median energy vs reference {np.median([r['rel_to_ref'] for r in sel]):+.3%}")


if __name__ == "__main__":
    main()
