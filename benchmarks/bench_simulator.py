"""Kernel speed: ns per Metropolis trial, ns per bond energy, ms per energy+gradient at 10k cells.

Run: OPENBLAS_NUM_THREADS=1 python benchmarks/bench_simulator.py   (writes results/benchmarks/)
"""

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


def main():
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


if __name__ == "__main__":
    main()
