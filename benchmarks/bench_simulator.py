"""Simulator speed: kernels, and the cost of a solve in evaluation-equivalents beside CPU seconds.

Kernels, measured in one run (medians, process time, one thread), at about 10,000 cells:
energy+gradient (ms, ns per bond), one bond energy (ns), a Metropolis trial (a move; ns; bar
0.35 us, goal 0.25) and the rasterisation of 10,000 cells into 8 fields at 256 px (ms; bar
20 ms). The anneal on --threads threads against one (wall time, interleaved runs; the same
bits): the strips' parallel speed-up (bar 1.7x on 2 cores).

Solves: each solver of --solvers (default: the default solver and the old default, hybrid) on
mould 0 of dataset seed --seed in --scene (replica 0's seed), printing evaluation-equivalents
(info["evaluations"]: minimiser evaluations plus the anneal's bonds evaluated over the bonds
of one evaluation), CPU seconds, CPU ms per evaluation-equivalent, the largest residual force
and E/cell; and for L-BFGS the evaluations until the energy is within 1% / 0.1% / 0.01% of its
final value and the largest residual force is below 1e-3 / 3e-4 / 1e-4 (run to 1e-5).
A busy machine inflates the seconds, not the evaluations: compare evaluations across runs,
seconds only within one.

Walls: a 20 x 10 l0 rectangle with two posts (radius 1, depth 4), seeds 0-3, each solver: the
largest residual force over all cells and over the cells touching a post (within 1e-6 l0).

Run: OPENBLAS_NUM_THREADS=1 python benchmarks/bench_simulator.py [--scene paper]
(writes results/benchmarks/bench_simulator.csv and solve_cost_<scene>.csv)
"""

import argparse
import csv
import time
from pathlib import Path

import numpy as np
from shapely.geometry import box

from condor.config import Config
from condor.data import fields as F
from condor.model.anneal import anneal, available_threads
from condor.model.energy import DELTA, bond_energies, energy_gradient, random_orientations
from condor.model.lattice import build_lattice
from condor.model.lbfgs import minimise_lbfgs
from condor.moulds.paper import generate_mould
from condor.model.scenes import PAPER_BOX, get_scene
from condor.data.seeds import replica_seed
from condor.model.simulate import DEFAULT_SOLVER, simulate, warm_up


def median_time(fn, repeats=7):
    times = []
    for _ in range(repeats):
        t = time.process_time()
        fn()
        times.append(time.process_time() - t)
    return float(np.median(times))


def kernels() -> dict:
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
    t_anneal = median_time(lambda: anneal(lat, pos, ori, budget, [0, 2]), repeats=5)
    # rasterisation: 10,000 cells over a disc of 40% of the paper box (bench_fields' layout)
    rng = np.random.default_rng([0, 10000])
    radius = np.sqrt(0.4 / np.pi) * PAPER_BOX * np.sqrt(rng.uniform(size=10000))
    angle = rng.uniform(0, 2 * np.pi, size=10000)
    xy = PAPER_BOX / 2 + np.stack([radius * np.cos(angle), radius * np.sin(angle)], axis=1)
    s = rng.normal(size=(10000, 3))
    s /= np.linalg.norm(s, axis=1, keepdims=True)
    values = F.cell_values(s, rng.normal(0.1, 0.05, size=10000))
    F.rasterise(xy, values, PAPER_BOX, 256)
    t_raster = median_time(lambda: F.rasterise(xy, values, PAPER_BOX, 256), repeats=15)
    t_weights = median_time(lambda: [F.pixel_weights(xy[:, k], 256, PAPER_BOX / 256, F.SIGMA_L0)
                                     for k in (0, 1)], repeats=15)
    return {
        "n_cells": lat.n_cells,
        "n_bonds": lat.n_bonds,
        "bonds_per_cell": lat.n_bonds * 2 / lat.n_cells,
        "ms_energy_gradient": 1e3 * t_grad,
        "ns_per_bond_energy": 1e9 * t_bonds / lat.n_bonds,
        "ns_per_bond_energy_gradient": 1e9 * t_grad / lat.n_bonds,
        "ns_per_metropolis_trial": 1e9 * t_anneal / (budget * n_mobile),
        "ms_raster_10k_cells_8_fields_256px": 1e3 * t_raster,
        "ms_raster_pixel_weights_part": 1e3 * t_weights,
    }


def parallel_speedup(threads: int, repeats: int = 5) -> dict:
    """The anneal's wall time on `threads` threads against one, interleaved runs (medians)."""
    side = np.sqrt(10000 / 6)
    lat = build_lattice(box(0, 0, side, side), np.array([[side / 3, side / 2, 1.5]]), 4.0)
    ori = random_orientations(lat.n_cells, np.random.default_rng([0, 0]))
    budget = 20
    n_moves = budget * int((~lat.fixed).sum())
    walls = {1: [], threads: []}
    for n in (1, threads):
        anneal(lat, lat.positions, ori, 2, [0, 2], threads=n)  # compile and start the threads
    for _ in range(repeats):
        for n in (1, threads):
            t = time.perf_counter()
            anneal(lat, lat.positions, ori, budget, [0, 2], threads=n)
            walls[n].append(time.perf_counter() - t)
    one, many = np.median(walls[1]), np.median(walls[threads])
    return {"threads": threads, "ns_per_move_wall_1_thread": 1e9 * one / n_moves,
            f"ns_per_move_wall_{threads}_threads": 1e9 * many / n_moves,
            "speedup": one / many}


def solve_costs(scene_name: str, seed: int, solvers) -> list[dict]:
    scene = get_scene(scene_name)
    mould = generate_mould(seed, 0, scene)
    sim_seed = replica_seed(seed, 0, 0)
    rows = []
    for solver in solvers:
        r = simulate(mould.polygon, mould.tethers, scene.depth, solver, seed=sim_seed)
        evaluations = r.info["evaluations"]
        rows.append({"scene": scene_name, "solver": solver, "n_cells": r.n_cells,
                     "evaluations": evaluations, "seconds": r.seconds,
                     "ms_per_evaluation": 1e3 * r.seconds / max(evaluations, 1),
                     "max_force": r.info["max_force"], "energy_per_cell": r.energy_per_cell,
                     "status": r.status})
    return rows


def lbfgs_convergence(scene_name: str, seed: int) -> dict:
    scene = get_scene(scene_name)
    mould = generate_mould(seed, 0, scene)
    lat = build_lattice(mould.polygon, mould.tethers, scene.depth)
    sim_seed = replica_seed(seed, 0, 0)
    ori = random_orientations(lat.n_cells, np.random.default_rng([sim_seed, 1]))
    trace = np.full((20000, 2), np.nan)
    _, _, info = minimise_lbfgs(lat, lat.positions, ori, 20000, 1e-5, trace=trace)
    n = info["min_evaluations"]
    energy, force = trace[:n, 0], trace[:n, 1]

    def first(mask):
        return int(np.argmax(mask)) + 1 if mask.any() else -1

    row = {"scene": scene_name, "evaluations_to_1e-5": n}
    for tol in (1e-2, 1e-3, 1e-4):
        row[f"evals_energy_within_{tol:g}"] = first(energy <= energy[-1] * (1 + tol))
    for tol in (1e-3, 3e-4, 1e-4):
        row[f"evals_force_below_{tol:g}"] = first(force < tol)
    return row


def wall_residuals(solvers, seeds=range(4)) -> list[dict]:
    from condor.model.walls import residual_forces

    polygon, posts = box(0, 0, 20, 10), np.array([[5.0, 5.0, 1.0], [15.0, 5.0, 1.0]])
    lat = build_lattice(polygon, posts, 4.0)
    rows = []
    for solver in solvers:
        for seed in seeds:
            r = simulate(polygon, posts, 4.0, solver, seed=seed)
            f = residual_forces(lat, r.positions, r.orientations)
            gap = np.min(np.hypot(r.positions[:, :1] - posts[:, 0], r.positions[:, 1:2] - posts[:, 1])
                         - posts[:, 2], axis=1)
            touching = (gap < 1e-6) & ~lat.fixed
            rows.append({"solver": solver, "seed": seed, "max_force": float(f.max()),
                         "cells_on_posts": int(touching.sum()),
                         "max_force_on_posts": float(f[touching].max(initial=0.0)),
                         "evaluations": r.info["evaluations"]})
    return rows


def _print(row: dict) -> None:
    for k, v in row.items():
        print(f"  {k:36s} {v:.4g}" if isinstance(v, float) else f"  {k:36s} {v}")


def main():
    ap = argparse.ArgumentParser()
    ap.add_argument("--scene", default="default", help="scene of the solves")
    ap.add_argument("--seed", type=int, default=Config.default().seed,
                    help="dataset seed of the mould (default: the default config's)")
    ap.add_argument("--solvers", nargs="+", default=[DEFAULT_SOLVER, "hybrid"])
    ap.add_argument("--threads", type=int, default=min(2, available_threads()),
                    help="threads of the anneal's parallel speed-up (default: 2, or 1 CPU)")
    a = ap.parse_args()
    warm_up()
    out = Path("results/benchmarks")
    out.mkdir(parents=True, exist_ok=True)
    print("kernels (one run):")
    k = kernels()
    _print(k)
    print(f"  Metropolis trial {k['ns_per_metropolis_trial'] / 1e3:.3f} us (bar 0.35 us); raster "
          f"{k['ms_raster_10k_cells_8_fields_256px']:.1f} ms (bar 20 ms)")
    if a.threads > 1:
        p = parallel_speedup(a.threads)
        print(f"\nthe anneal on {a.threads} threads (wall, interleaved, medians of 5):")
        _print(p)
        k.update(p)
    with open(out / "bench_simulator.csv", "w", newline="") as fh:
        w = csv.writer(fh)
        w.writerow(k.keys())
        w.writerow(k.values())
    rows = solve_costs(a.scene, a.seed, a.solvers)
    print(f"\nsolves ({a.scene} scene, mould 0 of seed {a.seed}):")
    print("| solver | cells | evaluation-equivalents | CPU s | ms per evaluation | max force | "
          "E/cell | status |")
    print("|---|---|---|---|---|---|---|---|")
    for r in rows:
        print(f"| {r['solver']} | {r['n_cells']} | {r['evaluations']:.0f} | {r['seconds']:.1f} | "
              f"{r['ms_per_evaluation']:.2f} | {r['max_force']:.2g} | {r['energy_per_cell']:.6f} "
              f"| {r['status']} |")
    with open(out / f"solve_cost_{a.scene}.csv", "w", newline="") as fh:
        w = csv.DictWriter(fh, fieldnames=list(rows[0]))
        w.writeheader()
        w.writerows(rows)
    print("\nL-BFGS convergence:")
    _print(lbfgs_convergence(a.scene, a.seed))
    print("\nresidual forces at the walls (20 x 10 rectangle, two posts, depth 4):")
    print("| solver | seed | evaluations | max force | cells on posts | max force on posts |")
    print("|---|---|---|---|---|---|")
    for r in wall_residuals(a.solvers):
        print(f"| {r['solver']} | {r['seed']} | {r['evaluations']:.0f} | {r['max_force']:.2g} | "
              f"{r['cells_on_posts']} | {r['max_force_on_posts']:.2g} |")


if __name__ == "__main__":
    main()
