"""Do two solvers reach the same minimum? Cost, energy and expected fields over an ensemble.

Each solver runs moulds 0..M-1 of dataset seed S (condor.moulds.paper.generate_mould(S, i, scene))
with R replicas each, seeded as the store seeds them (condor.data.seeds.replica_seed; replica 0 is
the dataset's own sample). Per solver it prints: evaluation-equivalents (median, max;
info["evaluations"]), CPU seconds, the largest residual force, and
against the reference solver (the first one): the median over runs of E/cell over the
reference's mean E/cell of the same mould, minus 1, and per mould the ratio of the two
ensembles' mean E/cell minus 1 (its median over moulds, with a bootstrap interval),
and the noise-corrected distance between the two ensembles' expected normalised fields
(condor.measures.estimators.ensemble_distance, RMS over moulds, with its bootstrap interval) beside the
replica noise (the RMS error of one simulation against the expected fields,
condor.measures.estimators.noise_ceiling) and the resolution of the distance (sqrt(s_a^2/R_a + s_b^2/R_b)).

The other solvers run 2R replicas: 0..R-1 share the reference's seeds (the same starts) and
give the paired energy comparison (mean over r of E_other / E_ref of the same start, minus 1,
per mould; median over moulds with its interval); R..2R-1 start elsewhere and give the field
distance (its noise correction assumes independent ensembles).

Runs are cached one file per run under --out (results/benchmarks/solver_ensemble), so an
interrupted study resumes and other solvers can be added later.

    OPENBLAS_NUM_THREADS=1 python experiments/same_minimum/ensemble.py --scene paper \
        --moulds 8 --replicas 3 --solvers hybrid:1e-4 lbfgs:3e-4 lbfgs:1e-3
"""

from __future__ import annotations

import argparse
import time
from pathlib import Path

import numpy as np

from condor.config import Config
from condor.measures import estimators
from condor.data.fields import normalise
from condor.moulds.paper import generate_mould
from condor.model.scenes import get_scene
from condor.data.seeds import replica_seed
from condor.model.simulate import simulate
from condor.stages.build import rasterise_result


def parse_solver(spec: str) -> tuple[str, float | None, float | None]:
    """'solver:ftol' or 'solver:ftol:budget' -> (solver, ftol, budget)."""
    parts = spec.split(":")
    ftol = float(parts[1]) if len(parts) > 1 and parts[1] else None
    budget = float(parts[2]) if len(parts) > 2 else None
    return parts[0], ftol, budget


def label(spec: str) -> str:
    solver, ftol, budget = parse_solver(spec)
    out = solver if ftol is None else f"{solver}_ftol{ftol:g}"
    return out if budget is None else f"{out}_budget{budget:g}"


def run_ensemble(spec: str, scene, dataset_seed: int, moulds: int, replicas: int, out: Path,
                 first_replica: int = 0, log=print) -> dict:
    """Run (or load) every run of one solver (replicas first_replica ...); arrays keyed by
    name, first axes (M, R)."""
    solver, ftol, budget = parse_solver(spec)
    folder = out / label(spec)
    folder.mkdir(parents=True, exist_ok=True)
    keys = ("energy_per_cell", "evaluations", "seconds", "max_force")
    table = {k: np.full((moulds, replicas), np.nan) for k in keys}
    fields = None
    for i in range(moulds):
        mould = generate_mould(dataset_seed, i, scene)
        for slot, r in enumerate(range(first_replica, first_replica + replicas)):
            path = folder / f"{scene.name}_s{dataset_seed}_m{i:03d}_r{r}.npz"
            if not path.exists():
                t0 = time.process_time()
                res = simulate(mould.polygon, mould.tethers, scene.depth, solver, budget,
                               replica_seed(dataset_seed, i, r), ftol)
                f = normalise(rasterise_result(res, scene).astype(np.float64), res.n_cells)
                np.savez(path, energy_per_cell=res.energy_per_cell,
                         evaluations=res.info["evaluations"], seconds=res.seconds,
                         max_force=res.info["max_force"], status=res.status,
                         fields=f.astype(np.float32))
                log(f"{label(spec)} {scene.name} mould {i} replica {r}: {res.status}, E/cell "
                    f"{res.energy_per_cell:.7f}, {res.info['evaluations']:.0f} evaluations, "
                    f"{time.process_time() - t0:.1f} s")
            with np.load(path) as data:
                if str(data["status"]) != "ok":
                    raise RuntimeError(f"{path}: {data['status']}")
                for k in keys:
                    table[k][i, slot] = float(data[k])
                if fields is None:
                    fields = np.zeros((moulds, replicas) + data["fields"].shape, np.float32)
                fields[i, slot] = data["fields"]
    table["fields"] = fields
    return table


def compare(ref: dict, other: dict) -> dict:
    """Energy and field agreement with the reference ensemble (M, R) of another (M, 2R):
    paired energies on replicas 0..R-1, field distance from replicas R..2R-1."""
    r = ref["energy_per_cell"].shape[1]
    paired = other["energy_per_cell"][:, :r] / ref["energy_per_cell"] - 1
    per_mould = paired.mean(axis=1)
    energy = estimators.bootstrap_interval(per_mould, np.median)
    independent = other["fields"][:, r:] if other["fields"].shape[1] > r else other["fields"]
    dist = estimators.ensemble_distance(independent, ref["fields"])
    distance = estimators.bootstrap_interval(dist.corrected)
    resolution = float(np.sqrt(np.mean(dist.plain - dist.corrected)))
    noise = np.sqrt(np.mean(estimators.noise_ceiling(ref["fields"])))
    return {"dE_median": float(np.median(paired)), "dE_mould": energy, "distance": distance,
            "resolution": resolution, "noise": float(noise)}


def _nanmax(values) -> str:
    """Largest value over the runs that report it ("n/a" for runs of code without it)."""
    values = np.asarray(values)
    return f"{np.nanmax(values):.2g}" if np.isfinite(values).any() else "n/a"


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--scene", default="paper")
    parser.add_argument("--seed", type=int, default=Config.default().seed, help="dataset seed of the moulds")
    parser.add_argument("--moulds", type=int, default=8)
    parser.add_argument("--replicas", type=int, default=3)
    parser.add_argument("--solvers", nargs="+", default=["hybrid:1e-4", "lbfgs:"],
                        help="solver:ftol[:budget]; the first is the reference")
    parser.add_argument("--out", type=Path, default=Path("results/benchmarks/solver_ensemble"))
    args = parser.parse_args()
    scene = get_scene(args.scene)
    results = {}
    for n, spec in enumerate(args.solvers):
        replicas = args.replicas if n == 0 else 2 * args.replicas
        results[spec] = run_ensemble(spec, scene, args.seed, args.moulds, replicas, args.out)
    ref = results[args.solvers[0]]
    print(f"\n{scene.name} scene, moulds 0-{args.moulds - 1} of seed {args.seed}, "
          f"{args.replicas} replicas; reference {args.solvers[0]}")
    print("| solver | evaluations median (max) | CPU s median | max force (max) | "
          "E/cell vs ref (paired): runs, moulds [95%] | field distance RMS [95%] | "
          "resolution | replica noise |")
    print("|---|---|---|---|---|---|---|---|")
    for spec, res in results.items():
        c = compare(ref, res)
        lo, hi = c["dE_mould"][1:]
        d, dlo, dhi = c["distance"]
        print(f"| {label(spec)} | {np.median(res['evaluations']):.0f} "
              f"({np.max(res['evaluations']):.0f}) | {np.median(res['seconds']):.1f} | "
              f"{_nanmax(res['max_force'])} | {100 * c['dE_median']:+.2f}%, "
              f"{100 * c['dE_mould'][0]:+.2f}% [{100 * lo:+.2f}, {100 * hi:+.2f}] | "
              f"{d:.4f} [{dlo:.4f}, {dhi:.4f}] | {c['resolution']:.4f} | {c['noise']:.4f} |")


if __name__ == "__main__":
    main()
