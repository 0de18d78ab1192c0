"""Solver variants side by side: evaluations to reach a force tolerance, and the energy there.

Every variant starts from the same state as `simulate` (the lattice, isotropic random
orientations of the store's replica seeds, condor.data.seeds.replica_seed) and runs to --ftol; its
trace (energy and largest residual force per evaluation) gives, for each tolerance in --report, the
evaluation-equivalents spent when the largest residual force first fell below it and the
energy per cell there (what a run with that ftol returns). Energies are compared with the
reference ensemble of bench_solver_ensemble when its cache holds the mould (--reference, the
mean E/cell of its replicas), else with the first variant.

Variants (--variants, any of):
  lbfgs           condor.model.lbfgs as in simulate (memory 10, bond-stiffness preconditioner)
  lbfgs-plain     the same without the preconditioner (H0 = gamma I)
  lbfgs-m5, lbfgs-m20   memory 5 or 20 pairs
  anneal30+lbfgs  30 moves per cell of the paper's anneal first (counted: bonds evaluated)
  coarse+lbfgs    coarse-to-fine: L-BFGS on the network of shells 1-2 only (a third of the
                  bonds, counted as a third of an evaluation) to max force 1e-2, then the full one
  fire            the legacy FIRE of condor.model.minimise (soft walls; its own force measure)
  fire2           FIRE 2.0 (Guenole et al. 2020: delayed dt growth, half step back on uphill,
                  mixing after the Euler update) with the exact walls of condor.model.walls

    OPENBLAS_NUM_THREADS=1 python experiments/same_minimum/variants.py --scene default \
        --moulds 8 --replicas 2 --variants lbfgs lbfgs-plain fire2
"""

from __future__ import annotations

import argparse
import dataclasses
import math
import time
from pathlib import Path

import numba
import numpy as np

from condor.config import Config
from condor.model.anneal import anneal
from condor.model.energy import DELTA, random_orientations
from condor.model.lattice import build_lattice
from condor.model.lbfgs import minimise_lbfgs
from condor.model.minimise import minimise
from condor.moulds.paper import generate_mould
from condor.model.scenes import get_scene
from condor.data.seeds import replica_seed
from condor.model.walls import SLIDE, hold_on_walls, place, project_state
from condor.model.lbfgs import _gradients

MAX_EVALUATIONS = 30000


@numba.njit(cache=True)
def fire2_kernel(pos, ori, mobile, bond_i, bond_j, kbar, rest, delta, phi, x0, y0, h, posts,
                 depth, max_eval, ftol, trace):
    """FIRE 2.0 over positions and tangent orientations, exact walls. Returns evaluations."""
    dt_init, dt_max, dt_min = 0.05, 0.2, 0.002
    n_delay, f_inc, f_dec, alpha0, f_alpha = 20, 1.1, 0.5, 0.25, 0.99
    n = pos.shape[0]
    nm = len(mobile)
    grad_pos = np.zeros((n, 3))
    grad_ori = np.zeros((n, 3))
    g = np.zeros((nm, 6))
    gp = np.zeros((nm, 6))
    mode = np.zeros(nm, np.int64)
    wall = np.zeros(nm, np.int64)
    normal = np.zeros((nm, 2))
    clear = np.full(nm, -1.0)  # always exact
    v = np.zeros((nm, 6))
    dt = dt_init
    alpha = alpha0
    n_pos = 0
    evals = 0
    it = 0
    while evals < max_eval:
        clear[:] = -1.0
        e, fmax = _gradients(pos, ori, mobile, bond_i, bond_j, kbar, rest, delta, phi, x0, y0,
                             h, posts, depth, grad_pos, grad_ori, g, gp, mode, wall, normal,
                             clear)
        if evals < trace.shape[0]:
            trace[evals, 0] = e
            trace[evals, 1] = fmax
        evals += 1
        if fmax < ftol or not math.isfinite(e):
            break
        hold_on_walls(v, mode, normal)  # keep velocities of held cells on their walls
        power = 0.0
        for m in range(nm):
            for a in range(6):
                power -= gp[m, a] * v[m, a]
        if power > 0.0:
            n_pos += 1
            if n_pos > n_delay:
                dt = min(dt * f_inc, dt_max)
                alpha *= f_alpha
        else:
            n_pos = 0
            if it >= n_delay:
                dt = max(dt * f_dec, dt_min)
                alpha = alpha0
            for m in range(nm):  # half step back (kept inside, on the sphere)
                c = mobile[m]
                ox, oy = pos[c, 0], pos[c, 1]
                x, y = place(phi, x0, y0, h, posts, ox - 0.5 * dt * v[m, 0],
                             oy - 0.5 * dt * v[m, 1], -1, ox, oy)
                pos[c, 0] = x
                pos[c, 1] = y
                pos[c, 2] = min(max(pos[c, 2] - 0.5 * dt * v[m, 2], 0.0), depth)
                norm = 0.0
                for a in range(3):
                    ori[c, a] -= 0.5 * dt * v[m, 3 + a]
                    norm += ori[c, a] * ori[c, a]
                for a in range(3):
                    ori[c, a] /= math.sqrt(norm)
            v[:] = 0.0
        it += 1
        vnorm = 0.0
        fnorm = 0.0
        for m in range(nm):
            for a in range(6):
                v[m, a] -= dt * gp[m, a]
                vnorm += v[m, a] * v[m, a]
                fnorm += gp[m, a] * gp[m, a]
        vnorm = math.sqrt(vnorm)
        fnorm = math.sqrt(fnorm)
        for m in range(nm):
            c = mobile[m]
            for a in range(6):
                v[m, a] = (1.0 - alpha) * v[m, a] - alpha * vnorm * gp[m, a] / fnorm
            ox, oy = pos[c, 0], pos[c, 1]
            x, y = place(phi, x0, y0, h, posts, ox + dt * v[m, 0], oy + dt * v[m, 1],
                         wall[m] if mode[m] & 3 == SLIDE else -1, ox, oy)
            pos[c, 0] = x
            pos[c, 1] = y
            pos[c, 2] = min(max(pos[c, 2] + dt * v[m, 2], 0.0), depth)
            norm = 0.0
            for a in range(3):
                ori[c, a] += dt * v[m, 3 + a]
                norm += ori[c, a] * ori[c, a]
            norm = math.sqrt(norm)
            dot = 0.0
            for a in range(3):
                ori[c, a] /= norm
                dot += ori[c, a] * v[m, 3 + a]
            for a in range(3):
                v[m, 3 + a] -= dot * ori[c, a]
    return evals


def fire2(lattice, positions, orientations, max_iter, ftol, trace):
    pos = np.array(positions, dtype=np.float64, order="C")
    ori = np.array(orientations, dtype=np.float64, order="C")
    mobile = np.flatnonzero(~lattice.fixed).astype(np.int64)
    r = lattice.region
    project_state(pos, mobile, r.phi, r.phi_x0, r.phi_y0, r.phi_h, r.posts, r.depth)
    evals = fire2_kernel(pos, ori, mobile, lattice.bond_i, lattice.bond_j, lattice.bond_kbar,
                         lattice.bond_rest, DELTA, r.phi, r.phi_x0, r.phi_y0, r.phi_h, r.posts,
                         r.depth, int(max_iter), float(ftol), trace)
    return pos, ori, evals


def sub_network(lattice, shells):
    """The lattice with only the bonds of `shells` (cell lists are not needed by L-BFGS)."""
    keep = np.isin(lattice.bond_shell, shells)
    return dataclasses.replace(lattice, bond_i=lattice.bond_i[keep], bond_j=lattice.bond_j[keep],
                               bond_kbar=lattice.bond_kbar[keep],
                               bond_rest=lattice.bond_rest[keep],
                               bond_shell=lattice.bond_shell[keep])


def run_variant(name, lattice, ori, seed, ftol):
    """Returns (trace (K, 2) energies and max forces per evaluation-equivalent step, offset
    evaluations spent before the trace, scale of each traced evaluation)."""
    trace = np.full((MAX_EVALUATIONS, 2), np.nan)
    pos0 = lattice.positions
    offset = 0.0
    if name.startswith("anneal30+"):
        pos0, ori, info = anneal(lattice, pos0, ori, 30, [seed, 2])
        offset = info["anneal_evaluations"]
    if name.startswith("coarse+"):
        coarse = sub_network(lattice, (0, 1))
        pos0, ori, info = minimise_lbfgs(coarse, pos0, ori, MAX_EVALUATIONS, 1e-2)
        offset = info["min_evaluations"] * coarse.n_bonds / lattice.n_bonds
    base = name.split("+")[-1]
    if base == "fire":
        _, _, info = minimise(lattice, pos0, ori, MAX_EVALUATIONS, ftol, trace=trace)
        count = info["min_iterations"]
    elif base == "fire2":
        _, _, count = fire2(lattice, pos0, ori, MAX_EVALUATIONS, ftol, trace)
    else:
        options = {"lbfgs": {}, "lbfgs-plain": {"precondition": False},
                   "lbfgs-m5": {"memory": 5}, "lbfgs-m20": {"memory": 20}}[base]
        _, _, info = minimise_lbfgs(lattice, pos0, ori, MAX_EVALUATIONS, ftol, trace=trace,
                                    **options)
        count = info["min_evaluations"]
    return trace[:count], offset


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--scene", default="default")
    parser.add_argument("--seed", type=int, default=Config.default().seed)
    parser.add_argument("--first-mould", type=int, default=0)
    parser.add_argument("--moulds", type=int, default=8)
    parser.add_argument("--replicas", type=int, default=2)
    parser.add_argument("--variants", nargs="+", default=["lbfgs", "lbfgs-plain", "fire2"])
    parser.add_argument("--ftol", type=float, default=1e-4)
    parser.add_argument("--report", type=float, nargs="+", default=[1e-3, 3e-4, 1e-4])
    parser.add_argument("--reference", type=Path,
                        default=Path("results/benchmarks/solver_ensemble/hybrid_ftol0.0001"))
    args = parser.parse_args()

    scene = get_scene(args.scene)
    rows = {v: [] for v in args.variants}
    for i in range(args.first_mould, args.first_mould + args.moulds):
        mould = generate_mould(args.seed, i, scene)
        lattice = build_lattice(mould.polygon, mould.tethers, scene.depth)
        ref_files = sorted(args.reference.glob(f"{scene.name}_s{args.seed}_m{i:03d}_r*.npz"))
        ref = (np.mean([float(np.load(f)["energy_per_cell"]) for f in ref_files])
               if ref_files else None)
        for r in range(args.replicas):
            seed = replica_seed(args.seed, i, r)
            ori = random_orientations(lattice.n_cells, np.random.default_rng([seed, 1]))
            for name in args.variants:
                t0 = time.process_time()
                trace, offset = run_variant(name, lattice, ori, seed, args.ftol)
                cpu = time.process_time() - t0
                energy = trace[:, 0] / lattice.n_cells
                row = {"cpu": cpu}
                for tol in args.report:
                    below = np.flatnonzero(trace[:, 1] < tol)
                    k = below[0] if below.size else len(trace) - 1
                    row[tol] = (offset + k + 1, energy[k], bool(below.size))
                rows[name].append((i, ref, row))
                print(f"mould {i} replica {r} {name}: " + ", ".join(
                    f"{tol:g}: {row[tol][0]:.0f} ev E/cell {row[tol][1]:.7f}"
                    for tol in args.report) + f" ({cpu:.1f} s)", flush=True)
    base = args.variants[0]
    print(f"\n{scene.name} scene, moulds {args.first_mould}-{args.first_mould + args.moulds - 1}"
          f" of seed {args.seed} x {args.replicas} replicas; energies against "
          f"{'the reference ensemble' if rows[base][0][1] is not None else base}")
    print("| variant | " + " | ".join(f"ftol {t:g}: evaluations median (max), dE/cell median"
                                      for t in args.report) + " | CPU s median |")
    print("|---|" + "---|" * (len(args.report) + 1))
    for name, data in rows.items():
        cells = []
        for tol in args.report:
            ev = np.array([row[tol][0] for _, _, row in data])
            reached = all(row[tol][2] for _, _, row in data)
            de = []
            for n, (i, ref, row) in enumerate(data):
                yard = ref if ref is not None else rows[base][n][2][tol][1]
                de.append(row[tol][1] / yard - 1)
            cells.append(f"{np.median(ev):.0f} ({ev.max():.0f}{'' if reached else ', cap'}), "
                         f"{100 * np.median(de):+.2f}%")
        cpu = np.median([row["cpu"] for _, _, row in data])
        print(f"| {name} | " + " | ".join(cells) + f" | {cpu:.1f} |")


if __name__ == "__main__":
    main()
