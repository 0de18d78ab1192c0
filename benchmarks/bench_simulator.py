"""Kernel speed: ns per Metropolis trial, ns per bond energy, ms per energy+gradient at 10k cells;
and how fast FIRE converges: evaluations until the energy is within 1% / 0.1% / 0.01% of its
final value and until the largest force falls below 1e-3 / 1e-4 (one generated mould).

Run: OPENBLAS_NUM_THREADS=1 python benchmarks/bench_simulator.py [--fire-scene paper]
(writes results/benchmarks/bench_simulator.csv and fire_convergence_<scene>.csv)
"""

import argparse
import csv
import time
from pathlib import Path

import numpy as np
from shapely.geometry import box

from condor.anneal import anneal
from condor.energy import DELTA, bond_energies, energy_gradient, random_orientations
from condor.lattice import build_lattice
from condor.simulate import warm_up


def median_time(fn, repeats=7):
    times = []
    for _ in range(repeats):
        t = time.process_time()
        fn()
        times.append(time.process_time() - t)
    return float(np.median(times))


def fire_convergence(scene_name: str) -> dict:
    """FIRE from the lattice of generate_mould(0, 0) to ftol 1e-5 (20,000 evaluations at most)."""
    from condor.minimise import minimise
    from condor.moulds import generate_mould
    from condor.scenes import get_scene

    scene = get_scene(scene_name)
    m = generate_mould(0, 0, scene.box)
    lat = build_lattice(m.polygon, m.tethers, scene.depth)
    ori = random_orientations(lat.n_cells, np.random.default_rng([1, 1]))
    trace = np.full((20000, 2), np.nan)
    t = time.process_time()
    _, _, info = minimise(lat, lat.positions, ori, max_iter=20000, ftol=1e-5, trace=trace)
    seconds = time.process_time() - t
    n = info["min_iterations"]
    energy, force = trace[:n, 0], trace[:n, 1]

    def first(mask):
        return int(np.argmax(mask)) + 1 if mask.any() else -1

    row = {"scene": scene_name, "n_cells": lat.n_cells, "evaluations": n, "seconds": seconds,
           "ms_per_evaluation": 1e3 * seconds / n, "final_max_force": info["min_max_force"]}
    for tol in (1e-2, 1e-3, 1e-4):
        row[f"evals_energy_within_{tol:g}"] = first(energy <= energy[-1] * (1 + tol))
    for tol in (1e-3, 1e-4):
        row[f"evals_force_below_{tol:g}"] = first(force < tol)
    return row


def main():
    ap = argparse.ArgumentParser()
    ap.add_argument("--fire-scene", default="default", help="scene of the FIRE convergence run")
    a = ap.parse_args()
    warm_up()
    side = np.sqrt(10000 / 6)  # ~10,000 cells: 6 layers of 1 cell per l0^2 at depth 4
    lat = build_lattice(box(0, 0, side, side), np.array([[side / 3, side / 2, 1.5]]), 4.0)
    ori = random_orientations(lat.n_cells, np.random.default_rng([0, 0]))
    pos = lat.positions + np.random.default_rng([0, 1]).normal(scale=0.05, size=lat.positions.shape)
    args = (lat.bond_i, lat.bond_j, lat.bond_kbar, lat.bond_rest, DELTA)
    gp, go = np.zeros_like(pos), np.zeros_like(ori)
    t_grad = median_time(lambda: energy_gradient(pos, ori, *args, gp, go))
    t_bonds = median_time(lambda: bond_energies(pos, ori, *args))
    n_mobile = int((~lat.fixed).sum())
    budget = 20
    t_anneal = median_time(lambda: anneal(lat, pos, ori, budget, [0, 2]), repeats=3)
    rows = {
        "n_cells": lat.n_cells,
        "n_bonds": lat.n_bonds,
        "bonds_per_cell": lat.n_bonds * 2 / lat.n_cells,
        "ms_energy_gradient": 1e3 * t_grad,
        "ns_per_bond_energy": 1e9 * t_bonds / lat.n_bonds,
        "ns_per_bond_energy_gradient": 1e9 * t_grad / lat.n_bonds,
        "ns_per_metropolis_trial": 1e9 * t_anneal / (budget * n_mobile),
    }
    for k, v in rows.items():
        print(f"{k:30s} {v:.4g}")
    out = Path("results/benchmarks")
    out.mkdir(parents=True, exist_ok=True)
    with open(out / "bench_simulator.csv", "w", newline="") as fh:
        w = csv.writer(fh)
        w.writerow(rows.keys())
        w.writerow(rows.values())
    fire = fire_convergence(a.fire_scene)
    for k, v in fire.items():
        print(f"{k:30s} {v:.4g}" if isinstance(v, float) else f"{k:30s} {v}")
    with open(out / f"fire_convergence_{a.fire_scene}.csv", "w", newline="") as fh:
        w = csv.writer(fh)
        w.writerow(fire.keys())
        w.writerow(fire.values())


if __name__ == "__main__":
    main()
