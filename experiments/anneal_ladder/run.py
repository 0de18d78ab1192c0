"""The anneal ladder (issue 15, item 4): does the fast solver sample the paper's ensemble?

For each mould, ensembles of replicas of
  * the paper's anneal at rising budgets (moves per cell; the paper's is 1e6), each followed by
    tight FIRE (`--ftol`, default 1e-5), so that every rung ends at a minimum, and
  * the quench: solver "hybrid" with its defaults (a short anneal, then FIRE), the name the
    stored tables in this folder give it. It was the simulator's default when the ladder was
    measured; the default is now `condor.model.simulate.DEFAULT_SOLVER` ("lbfgs"), which samples
    the hybrid's ensemble (docs/model.md, "The same minimum?"),
with the store's replica seeds (`condor.data.seeds.replica_seed`): replica r of every method
starts from the same random orientations. Each ensemble's mean normalised fields estimate its
expected fields; the noise-corrected distance between two ensembles' means
(`estimators.ensemble_distance`) is set against the spread of one simulation about its
ensemble's mean (`estimators.noise_ceiling`), both as RMS over pixels and the 8 fields. An
exact permutation test (the replicas of two ensembles pooled and re-split) says whether the
distance is resolved beyond replica noise.

Outputs (small CSVs under --out, default this folder; the suffix is the scene and --tag):
  anneal_ladder_runs_<scene>.csv     one row per run: energies, diagnostics, seeds
  anneal_ladder_<scene>.csv          per mould and method: E/cell, distances, spreads, p
  anneal_ladder_fields_<scene>.csv   per field: distance of each method to the reference rung
  anneal_ladder_trace_<scene>_m<id>_<budget>.csv   (--trace) one anneal at checkpoints
Runs are cached under --cache (one .npz each), so an interrupted ladder resumes and the tables
are rebuilt from whatever has finished (--tables-only).

Run (single-threaded, niced; the long rungs take minutes per run):
  python experiments/anneal_ladder/run.py --scene tiny --moulds 7 12 15 47 \
      --rungs 1e3 1e4 1e5 1e6 --seeds 3 --hybrid-seeds 8
  python experiments/anneal_ladder/run.py --scene default --moulds 7 12 15 47 \
      --rungs 1e3 1e4 1e5 --seeds 3 --hybrid-seeds 8
  python experiments/anneal_ladder/run.py --scene default --trace 12 1e5
The anneal before its step-amplitude clamp (commit a70ce9e's parent) is measured by putting
that commit's src first on PYTHONPATH and passing --tag legacy.
"""

from __future__ import annotations

import argparse
import itertools
import json
import math
import os
import time
from dataclasses import dataclass
from pathlib import Path

os.environ.setdefault("OPENBLAS_NUM_THREADS", "1")
os.environ.setdefault("NUMBA_NUM_THREADS", "1")

import numpy as np  # noqa: E402
import pandas as pd  # noqa: E402

from condor.config import Config  # noqa: E402
from condor.model import anneal as anneal_mod  # noqa: E402
from condor.model import metropolis  # noqa: E402
from condor.model.energy import DELTA, cell_tension, lattice_energy, random_orientations  # noqa: E402
from condor.measures.estimators import (  # noqa: E402
    bootstrap_interval, ensemble_distance, noise_ceiling, root_mean,
)
from condor.data.fields import FIELD_NAMES, cell_fields, normalise  # noqa: E402
from condor.model.lattice import build_lattice, signed_volumes  # noqa: E402
from condor.model.minimise import minimise  # noqa: E402
from condor.moulds.paper import generate_mould  # noqa: E402
from condor.model.scenes import get_scene  # noqa: E402
from condor.data.seeds import replica_seed  # noqa: E402
from condor.model.simulate import SimResult, diagnose, simulate, simulate_lattice, warm_up  # noqa: E402

DATASET_SEED = Config.default().seed  # the default config's global seed (--seed changes it)
HYBRID = "hybrid"
P_RESOLVED = 0.05  # a distance is resolved beyond replica noise below this permutation p


@dataclass(frozen=True)
class Method:
    """One ensemble's recipe. budget None: the hybrid solver (the default before L-BFGS, not
    the current DEFAULT_SOLVER), with FIRE to `ftol` (None: its default); else the paper's
    anneal of `budget` moves per cell, over the temperatures `window` = (T_hi, T_lo) if given
    (else T_INIT to T_INIT / T_RATIO), then tight FIRE."""

    budget: float | None = None
    window: tuple[float, float] | None = None
    ftol: float | None = None

    @property
    def name(self) -> str:
        """'hybrid', 'hybrid ftol 1e-05', 'anneal 1e5' or 'anneal 1e4 T 0.02-0.002'."""
        if self.budget is None:
            return HYBRID if self.ftol is None else f"{HYBRID} ftol {self.ftol:g}"
        name = f"anneal {self.budget:.0e}".replace("e+0", "e")
        return name if self.window is None else f"{name} T {self.window[0]:g}-{self.window[1]:g}"


def method_name(budget: float | None) -> str:
    return Method(budget).name


def orientation_order(lattice, orientations) -> tuple[float, float]:
    """(nn_order, global_order) of the mobile cells: the mean P2(s_i . s_j) over nearest-
    neighbour bonds (1 inside one orientation domain, 0 for random orientations) and the
    nematic order S (largest eigenvalue of the mean Q = 3/2 s s^T - 1/2 I)."""
    mobile = ~lattice.fixed
    nn = (lattice.bond_shell == 0) & mobile[lattice.bond_i] & mobile[lattice.bond_j]
    dots = np.einsum("ij,ij->i", orientations[lattice.bond_i[nn]],
                     orientations[lattice.bond_j[nn]])
    s = orientations[mobile]
    q = 1.5 * (s.T @ s) / len(s) - 0.5 * np.eye(3)
    return float(np.mean(1.5 * dots**2 - 0.5)), float(np.linalg.eigvalsh(q)[-1])


def state_row(lattice, result) -> dict:
    """Diagnostics of a final state (a SimResult on `lattice`)."""
    nn_order, global_order = orientation_order(lattice, result.orientations)
    s2 = result.orientations**2
    return {
        "energy_per_cell": result.energy_per_cell,
        "inverted_fraction": result.info.get("inverted_fraction"),
        "min_nn_length": result.info.get("min_nn_length"),
        "nn_order": nn_order,
        "global_order": global_order,
        "mean_tension": float(result.tension.mean()),
        "mean_sx2": float(s2[:, 0].mean()),
        "mean_sy2": float(s2[:, 1].mean()),
        "mean_sz2": float(s2[:, 2].mean()),
        "status": result.status,
    }


def run_one(scene, mould_id: int, method: Method, replica: int, ftol: float,
            max_iter: int) -> tuple[dict, np.ndarray]:
    """One replica of one method: (row, normalised fields (8, H, W) float32). ftol and
    max_iter: the FIRE that follows an anneal."""
    mould = generate_mould(DATASET_SEED, mould_id, scene)
    seed = replica_seed(DATASET_SEED, mould_id, replica)
    budget, window = method.budget, method.window
    row = {"scene": scene.name, "mould": mould_id, "method": method.name,
           "budget": budget, "replica": replica, "seed": seed,
           "t_init": anneal_mod.T_INIT if window is None else window[0],
           "t_final": anneal_mod.T_INIT / anneal_mod.T_RATIO if window is None else window[1]}
    if budget is None:
        result = simulate(mould.polygon, mould.tethers, scene.depth, solver=HYBRID, seed=seed,
                          ftol=method.ftol)
        lattice = build_lattice(mould.polygon, mould.tethers, scene.depth)
        row.update(cpu_s=result.seconds, fire_ftol=method.ftol)
    else:
        lattice = build_lattice(mould.polygon, mould.tethers, scene.depth)
        if window is None:
            annealed = simulate(mould.polygon, mould.tethers, scene.depth, solver="anneal",
                                budget=budget, seed=seed)
        else:  # simulate's start state and streams, the schedule over the window
            start = random_orientations(lattice.n_cells, np.random.default_rng([seed, 1]))
            annealed = window_anneal(lattice, start, budget, seed, window)
        before = state_row(lattice, annealed)
        row.update({f"anneal_{k}": before[k] for k in
                    ("energy_per_cell", "inverted_fraction", "min_nn_length", "nn_order")})
        row["anneal_status"] = annealed.status
        result = simulate_lattice(lattice, annealed.positions, annealed.orientations,
                                  "minimise", budget=max_iter, seed=seed, ftol=ftol)
        result.info.update({k: v for k, v in annealed.info.items() if k.startswith("anneal_")})
        row.update(cpu_s=annealed.seconds + result.seconds, anneal_cpu_s=annealed.seconds,
                   fire_ftol=ftol)
    info = result.info
    row.update(
        n_cells=result.n_cells,
        accept_pos=info.get("anneal_accept_pos"), accept_ori=info.get("anneal_accept_ori"),
        final_step_pos=info.get("anneal_final_step_pos"),
        final_step_ori=info.get("anneal_final_step_ori"),  # absent before the clamp
        fire_iterations=info.get("min_iterations"), max_force=info.get("min_max_force"),
    )
    row.update(state_row(lattice, result))
    fields = cell_fields(result.positions, result.orientations, result.tension, scene.box,
                         scene.pixels, scene.sigma)
    return row, normalise(fields, result.n_cells).astype(np.float32)


def window_anneal(lattice, orientations, budget: float, seed: int, window):
    """anneal() over the temperatures window = (T_hi, T_lo), as a SimResult (diagnosed)."""
    t0 = time.process_time()
    pos, ori, info = anneal_mod.anneal(lattice, lattice.positions, orientations, budget,
                                       [seed, 2], t_init=window[0],
                                       t_ratio=window[0] / window[1])
    seconds = time.process_time() - t0
    energy = lattice_energy(lattice, pos, ori)
    info.update(diagnose(lattice, pos, ori, energy,
                         lattice_energy(lattice, lattice.positions, orientations), info))
    tension = cell_tension(pos, ori, lattice.bond_i, lattice.bond_j, lattice.bond_kbar,
                           lattice.bond_rest, DELTA)
    return SimResult(positions=pos, orientations=ori, fixed=lattice.fixed.copy(),
                     tension=tension, energy=float(energy), solver="anneal", budget=budget,
                     seed=seed, seconds=seconds, status=info.pop("status_reason"), info=info)


def run_path(cache: Path, mould_id, method: Method, replica) -> Path:
    return cache / f"m{mould_id}_{method.name.replace(' ', '_')}_r{replica}.npz"


def cached_run(cache: Path, scene, mould_id, method: Method, replica, ftol, max_iter, log):
    path = run_path(cache, mould_id, method, replica)
    if path.exists():
        with np.load(path) as data:
            return json.loads(str(data["row"])), data["fields"]
    t0 = time.time()
    row, fields = run_one(scene, mould_id, method, replica, ftol, max_iter)
    path.parent.mkdir(parents=True, exist_ok=True)
    tmp = path.with_suffix(".tmp.npz")
    np.savez(tmp, row=np.array(json.dumps(row)), fields=fields)
    tmp.replace(path)
    log(f"  mould {mould_id} {row['method']} r{replica}: E/cell {row['energy_per_cell']:.6f} "
        f"{row['status']} ({time.time() - t0:.0f} s wall, {row['cpu_s']:.0f} s CPU)")
    return row, fields


def permutation_p(a: np.ndarray, b: np.ndarray) -> float:
    """Exact permutation p of |mean_a - mean_b|^2 (replicas (Ra, ...), (Rb, ...)): the share
    of all re-splits of the pooled replicas whose distance is at least the observed one."""
    pooled = np.concatenate([a, b]).reshape(len(a) + len(b), -1).astype(np.float64)
    total = pooled.sum(axis=0)
    n, ra = len(pooled), len(a)

    def distance(idx):
        sa = pooled[list(idx)].sum(axis=0)
        return float(np.mean((sa / ra - (total - sa) / (n - ra)) ** 2))

    observed = distance(range(ra))
    splits = [distance(idx) for idx in itertools.combinations(range(n), ra)]
    return float(np.mean(np.array(splits) >= observed * (1 - 1e-12)))


def combined_permutation_p(pairs: list[tuple[np.ndarray, np.ndarray]], draws: int = 4000,
                           seed: int = 0) -> float:
    """Monte Carlo permutation p over moulds of the sum of per-mould squared distances, each
    scaled by its pooled variance (so that quiet moulds count as much as noisy ones)."""
    rng = np.random.default_rng(seed)
    prepared = []
    for a, b in pairs:
        pooled = np.concatenate([a, b]).reshape(len(a) + len(b), -1).astype(np.float64)
        prepared.append((pooled, len(a), float(pooled.var(axis=0, ddof=1).mean())))

    def statistic(perms):
        out = 0.0
        for (pooled, ra, scale), order in zip(prepared, perms):
            d = pooled[order[:ra]].mean(axis=0) - pooled[order[ra:]].mean(axis=0)
            out += float(np.mean(d * d)) / scale
        return out

    observed = statistic([np.arange(len(p)) for p, _, _ in prepared])
    hits = sum(statistic([rng.permutation(len(p)) for p, _, _ in prepared]) >= observed
               for _ in range(draws))
    return (hits + 1) / (draws + 1)


def summarise(runs: pd.DataFrame, fields: dict, reference: str) -> tuple[pd.DataFrame,
                                                                         pd.DataFrame]:
    """Per mould and method, and over moulds ('all'): energies, distances to the hybrid and
    to the reference rung, spreads, permutation p. Distances and spreads are RMS over the
    8 normalised fields' pixels; a noise-corrected squared distance below 0 reads as 0."""
    methods = list(dict.fromkeys(runs["method"]))
    moulds = sorted(runs["mould"].unique())
    # Energy against the hybrid run of the same seed: the posts keep their random start
    # orientations, which shift a seed's energy by up to ~15% at every budget, so only
    # same-seed ratios resolve a solver's energy (median over replicas, %).
    hybrid_energy = runs[runs["method"] == HYBRID].set_index(["mould", "replica"])[
        "energy_per_cell"]
    runs = runs.assign(e_vs_hybrid=[
        100 * (e / hybrid_energy[(m, r)] - 1) if (m, r) in hybrid_energy.index else np.nan
        for m, r, e in zip(runs["mould"], runs["replica"], runs["energy_per_cell"])])
    rows, per_field = [], []
    for method in methods:
        for m in moulds:
            if (m, method) not in fields:
                continue
            sel = runs[(runs["mould"] == m) & (runs["method"] == method)]
            ens = fields[(m, method)]
            row = {"scene": sel["scene"].iloc[0], "mould": m, "method": method, "n": len(ens),
                   "e_median": sel["energy_per_cell"].median(),
                   "e_min": sel["energy_per_cell"].min(), "e_max": sel["energy_per_cell"].max(),
                   "e_vs_hybrid_pct": sel["e_vs_hybrid"].median(),
                   "mean_sx2": sel["mean_sx2"].mean(),
                   "spread": math.sqrt(float(noise_ceiling(ens[None])[0])) if len(ens) > 1
                   else float("nan"),
                   "nn_order": sel["nn_order"].median(),
                   "mean_tension": sel["mean_tension"].mean(),
                   "mean_sz2": sel["mean_sz2"].mean(),
                   "accept_ori": sel["accept_ori"].median(),
                   "final_step_ori": sel["final_step_ori"].median()
                   if "final_step_ori" in sel else float("nan"),
                   "inverted_max": sel["inverted_fraction"].max(),
                   "min_nn_length": sel["min_nn_length"].min(),
                   "max_force": sel["max_force"].max(),
                   "cpu_s": sel["cpu_s"].median()}
            for target, tag in ((HYBRID, "hybrid"), (reference, "ref")):
                if (m, target) in fields and target != method and len(ens) > 1:
                    other = fields[(m, target)]
                    d = ensemble_distance(ens[None], other[None])
                    row[f"d_{tag}"] = math.sqrt(max(float(d.corrected[0]), 0.0))
                    row[f"d_{tag}_plain"] = math.sqrt(float(d.plain[0]))
                    # the distance two samples of one ensemble would show (replica noise)
                    row[f"d_{tag}_noise"] = math.sqrt(float(d.plain[0] - d.corrected[0]))
                    row[f"p_{tag}"] = permutation_p(ens, other)
            rows.append(row)
        # over moulds, with bootstrap intervals
        mine = [m for m in moulds if (m, method) in fields and len(fields[(m, method)]) > 1]
        if not mine:
            continue
        sel = runs[runs["method"] == method]
        ens_all = np.stack([fields[(m, method)] for m in mine])
        agg = {"scene": sel["scene"].iloc[0], "mould": "all", "method": method,
               "n": ens_all.shape[1], "e_median": sel["energy_per_cell"].median(),
               "e_min": sel["energy_per_cell"].min(), "e_max": sel["energy_per_cell"].max(),
               "e_vs_hybrid_pct": sel["e_vs_hybrid"].median(),
               "mean_sx2": sel["mean_sx2"].mean(), "mean_sz2": sel["mean_sz2"].mean(),
               "spread": root_mean(noise_ceiling(ens_all)),
               "nn_order": sel["nn_order"].median(), "cpu_s": sel["cpu_s"].median(),
               "accept_ori": sel["accept_ori"].median(),
               "inverted_max": sel["inverted_fraction"].max(),
               "min_nn_length": sel["min_nn_length"].min(), "max_force": sel["max_force"].max()}
        for target, tag in ((HYBRID, "hybrid"), (reference, "ref")):
            both = [m for m in mine if (m, target) in fields]
            if target == method or not both or len(both) != len(mine):
                continue
            other = np.stack([fields[(m, target)] for m in both])
            d = ensemble_distance(ens_all, other)
            est, lo, hi = bootstrap_interval(d.corrected)
            agg.update({f"d_{tag}": est, f"d_{tag}_lo": lo, f"d_{tag}_hi": hi,
                        f"d_{tag}_plain": root_mean(d.plain),
                        f"d_{tag}_noise": root_mean(d.plain - d.corrected),
                        f"p_{tag}": combined_permutation_p(
                            [(fields[(m, method)], fields[(m, target)]) for m in both])})
            if tag == "ref":
                df = ensemble_distance(ens_all, other, per_field=True)
                ceiling = noise_ceiling(other, per_field=True)
                own = noise_ceiling(ens_all, per_field=True)
                for f, name in enumerate(FIELD_NAMES):
                    e, lo, hi = bootstrap_interval(df.corrected[:, f])
                    mean_diff = float(np.mean(ens_all[:, :, f].mean(axis=(1, 2, 3))
                                              - other[:, :, f].mean(axis=(1, 2, 3))))
                    per_field.append({
                        "scene": agg["scene"], "method": method, "reference": reference,
                        "field": name, "d_ref": e, "d_ref_lo": lo, "d_ref_hi": hi,
                        "spread_ref": root_mean(ceiling[:, f]),
                        "spread_method": root_mean(own[:, f]),
                        "mean_difference": mean_diff,
                        "moulds": len(both)})
        rows.append(agg)
    return pd.DataFrame(rows), pd.DataFrame(per_field)


def trace(scene, mould_id: int, budget: float, segments: int, replica: int, ftol: float,
          max_iter: int, log) -> pd.DataFrame:
    """One anneal of `budget` moves per cell cut into `segments` equal stretches (equal
    factors of T), with at each checkpoint the running energy, the acceptances and steps of
    the stretch, the folds, the orientation order, and the energy FIRE reaches from there.

    Each stretch is one anneal_kernel call with the amplitudes carried over and its own RNG
    stream: the same schedule and adaptation as `anneal`, not bit-identical to it."""
    mould = generate_mould(DATASET_SEED, mould_id, scene)
    lattice = build_lattice(mould.polygon, mould.tethers, scene.depth)
    seed = replica_seed(DATASET_SEED, mould_id, replica)
    pos = lattice.positions.copy()
    ori = random_orientations(lattice.n_cells, np.random.default_rng([seed, 1]))
    mobile = np.flatnonzero(~lattice.fixed).astype(np.int64)
    sweeps = int(round(budget / segments))
    ratio = anneal_mod.T_RATIO ** (1.0 / segments)
    amp = np.array([anneal_mod.INIT_AMP_POS, anneal_mod.INIT_AMP_ORI])
    region = lattice.region
    neighbours = anneal_mod.neighbour_lists(lattice)  # the per-cell bond lists anneal() builds
    temp = anneal_mod.T_INIT
    rows = []
    nn = lattice.bond_shell == 0
    for k in range(segments):
        stream = int(np.random.default_rng([seed, 2, k]).integers(1, 2**63 - 1))
        n_trials = sweeps * len(mobile)
        energy, acc_pos, acc_ori, _, _ = anneal_mod.anneal_kernel(
            pos, ori, mobile, lattice.bond_i, lattice.bond_j, lattice.bond_kbar,
            lattice.bond_rest, lattice.cell_ptr, lattice.cell_bonds, *neighbours, DELTA,
            region.phi, region.phi_x0, region.phi_y0, region.phi_h, region.posts, region.depth,
            n_trials, temp, ratio, stream, amp)
        temp /= ratio
        quench_pos, quench_ori, quench = minimise(lattice, pos, ori, ftol=ftol,
                                                  max_iter=max_iter)
        nn_len = np.linalg.norm(pos[lattice.bond_j[nn]] - pos[lattice.bond_i[nn]], axis=1)
        row = {
            "scene": scene.name, "mould": mould_id, "budget": budget, "seed": seed,
            "segment": k, "temperature_end": temp,
            "energy_per_cell": energy / lattice.n_cells,
            "accept_pos": acc_pos / (n_trials / 2), "accept_ori": acc_ori / (n_trials / 2),
            "amp_pos": float(amp[0]), "amp_ori": float(amp[1]),
            "step_pos": min(float(amp[0]) * math.sqrt(temp), metropolis.MAX_STEP_POS),
            "step_ori": min(float(amp[1]) * math.sqrt(temp), metropolis.MAX_STEP_ORI),
            "inverted_fraction": float(np.mean(signed_volumes(pos, lattice.tets) <= 0)),
            "min_nn_length": float(nn_len.min()),
            "nn_order": orientation_order(lattice, ori)[0],
            "mean_sz2": float(np.mean(ori[:, 2] ** 2)),
            "quenched_energy_per_cell": lattice_energy(lattice, quench_pos, quench_ori)
            / lattice.n_cells,
            "quenched_nn_order": orientation_order(lattice, quench_ori)[0],
            "quenched_mean_sz2": float(np.mean(quench_ori[:, 2] ** 2)),
            "quench_iterations": quench["min_iterations"],
        }
        rows.append(row)
        log(f"  T {temp:.2e} E/cell {row['energy_per_cell']:.5f} accept {row['accept_pos']:.2f}"
            f"/{row['accept_ori']:.2f} ds {row['step_ori']:.2e} (amp {amp[1]:.2e}) "
            f"quenched {row['quenched_energy_per_cell']:.6f} order {row['nn_order']:.3f} "
            f"sz2 {row['mean_sz2']:.3f} quenched sz2 {row['quenched_mean_sz2']:.3f}")
    return pd.DataFrame(rows)


def verdict(summary: pd.DataFrame, fields_table: pd.DataFrame, reference: str) -> str:
    allrow = summary[(summary["mould"] == "all") & (summary["method"] == HYBRID)]
    lines = [f"Reference ensemble: {reference} (+ tight FIRE), the longest rung run."]
    if allrow.empty or "d_ref" not in allrow:
        return "\n".join(lines + ["(no hybrid/reference pair to compare yet)"])
    a = allrow.iloc[0]
    lines.append(
        f"hybrid vs {reference}: noise-corrected RMS distance of the expected fields "
        f"{a['d_ref']:.4f} [{a['d_ref_lo']:.4f}, {a['d_ref_hi']:.4f}] against a spread of one "
        f"simulation of {a['spread']:.4f} (hybrid); replica noise in the plain distance "
        f"{a['d_ref_noise']:.4f}; permutation p = {a['p_ref']:.3f}.")
    ref = summary[(summary["mould"] == "all") & (summary["method"] == reference)]
    if not ref.empty:
        lines.append(f"Spread within the reference ensemble: {ref.iloc[0]['spread']:.4f}.")
    if a["p_ref"] >= P_RESOLVED:
        lines.append("Verdict: the hybrid solver samples the reference ensemble within the "
                     "resolution of these replicas.")
    else:
        lines.append("Verdict: the hybrid solver's expected fields differ from the "
                     "reference's beyond replica noise. Per field (RMS distance / spread of "
                     "one reference simulation, mean difference hybrid - reference):")
        hyb = fields_table[fields_table["method"] == HYBRID]
        for _, f in hyb.iterrows():
            lines.append(f"  {f['field']:5s} {f['d_ref']:.4f} / {f['spread_ref']:.4f}  "
                         f"mean diff {f['mean_difference']:+.4f}")
    return "\n".join(lines)


def markdown(summary: pd.DataFrame, per_field: pd.DataFrame) -> str:
    """The ladder and per-field tables as Markdown (for docs/anneal_ladder.md)."""
    def num(v, fmt):
        return "" if v is None or (isinstance(v, float) and math.isnan(v)) else format(v, fmt)

    lines = ["| mould | method | n | E/cell median (range) | E vs hybrid, same seed | "
             "d to hybrid (p) | d to reference (p) | noise | spread | <sz^2> | ori. accept "
             "| CPU s |", "|" + "---|" * 12]
    for _, r in summary.iterrows():
        energy = f"{r['e_median']:.5f} ({r['e_min']:.5f}-{r['e_max']:.5f})"
        d_h = (f"{num(r.get('d_hybrid'), '.3f')} ({num(r.get('p_hybrid'), '.3f')})"
               if pd.notna(r.get("d_hybrid")) else "")
        d_r = (f"{num(r.get('d_ref'), '.3f')} ({num(r.get('p_ref'), '.3f')})"
               if pd.notna(r.get("d_ref")) else "")
        noise = r.get("d_ref_noise") if pd.notna(r.get("d_ref_noise")) else r.get("d_hybrid_noise")
        e_rel = "" if r["method"] == HYBRID else f"{r['e_vs_hybrid_pct']:+.2f}%"
        lines.append(f"| {r['mould']} | {r['method']} | {r['n']} | {energy} | {e_rel} | {d_h} | "
                     f"{d_r} | {num(noise, '.3f')} | {num(r['spread'], '.3f')} | "
                     f"{num(r['mean_sz2'], '.3f')} | {num(r['accept_ori'], '.3f')} | "
                     f"{num(r['cpu_s'], '.1f')} |")
    lines += ["", "| method | field | d to reference [95%] | spread of one reference run | "
              "mean difference |", "|" + "---|" * 5]
    for _, f in per_field.iterrows():
        lines.append(f"| {f['method']} | {f['field']} | {f['d_ref']:.4g} [{f['d_ref_lo']:.3g}, "
                     f"{f['d_ref_hi']:.3g}] | {f['spread_ref']:.4g} | "
                     f"{f['mean_difference']:+.3g} |")
    return "\n".join(lines)


def main():
    ap = argparse.ArgumentParser(description=__doc__.split("\n")[0])
    ap.add_argument("--scene", default="tiny", choices=("tiny", "default", "paper"))
    ap.add_argument("--moulds", type=int, nargs="+", default=[7, 12, 15, 47])
    ap.add_argument("--rungs", type=float, nargs="*", default=[1e3, 1e4, 1e5],
                    help="anneal budgets, moves per cell")
    ap.add_argument("--seeds", type=int, default=3, help="replicas per anneal rung")
    ap.add_argument("--hybrid-seeds", type=int, default=8, help="replicas of the hybrid")
    ap.add_argument("--ftol", type=float, default=1e-5, help="FIRE tolerance after the anneal")
    ap.add_argument("--max-iter", type=int, default=60000, help="FIRE evaluations at most")
    ap.add_argument("--reference", type=float, default=None,
                    help="the rung standing for the paper's anneal (default: the largest)")
    ap.add_argument("--tag", default="", help="suffix of the outputs (e.g. legacy)")
    ap.add_argument("--cache", type=Path, default=Path("results/benchmarks/anneal_ladder"))
    ap.add_argument("--out", type=Path, default=Path(__file__).resolve().parent)
    ap.add_argument("--tables-only", action="store_true", help="no new runs: tables from cache")
    ap.add_argument("--trace", nargs=2, metavar=("MOULD", "BUDGET"), default=None,
                    help="trace one anneal at checkpoints instead of the ladder")
    ap.add_argument("--segments", type=int, default=14, help="checkpoints of --trace")
    ap.add_argument("--markdown", action="store_true", help="also print the tables as Markdown")
    ap.add_argument("--window", type=float, nargs=2, metavar=("T_HI", "T_LO"), default=None,
                    help="temperature window of the --window-rungs anneals")
    ap.add_argument("--window-rungs", type=float, nargs="*", default=[],
                    help="budgets (moves per cell) annealed over --window only, then FIRE")
    ap.add_argument("--hybrid-tight", action="store_true",
                    help="also the hybrid with its FIRE run on to --ftol (same seeds)")
    a = ap.parse_args()
    scene = get_scene(a.scene)
    suffix = a.scene + (f"_{a.tag}" if a.tag else "")
    log = lambda s: print(s, flush=True)  # noqa: E731
    a.out.mkdir(parents=True, exist_ok=True)
    warm_up()
    if a.trace:
        mould_id, budget = int(a.trace[0]), float(a.trace[1])
        table = trace(scene, mould_id, budget, a.segments, 0, 1e-4, a.max_iter, log)
        rung = method_name(budget).split()[1]
        path = a.out / f"anneal_ladder_trace_{suffix}_m{mould_id}_{rung}.csv"
        table.to_csv(path, index=False, float_format="%.6g")
        log(f"wrote {path}")
        return

    cache = a.cache / suffix
    if a.window_rungs and a.window is None:
        ap.error("--window-rungs needs --window T_HI T_LO")
    window = tuple(a.window) if a.window else None
    plan = [(m, Method(), r) for m in a.moulds for r in range(a.hybrid_seeds)]
    plan += [(m, Method(b), r) for b in sorted(a.rungs) for m in a.moulds
             for r in range(a.seeds)]
    plan += [(m, Method(b, window), r) for b in sorted(a.window_rungs) for m in a.moulds
             for r in range(a.seeds)]
    if a.hybrid_tight:
        plan += [(m, Method(ftol=a.ftol), r) for m in a.moulds for r in range(a.hybrid_seeds)]
    rows, fields = [], {}
    for mould_id, method, replica in plan:
        if a.tables_only and not run_path(cache, mould_id, method, replica).exists():
            continue
        row, f = cached_run(cache, scene, mould_id, method, replica, a.ftol, a.max_iter, log)
        rows.append(row)
        fields.setdefault((mould_id, row["method"]), []).append(f)
    if not rows:
        log("no runs yet")
        return
    fields = {k: np.stack(v) for k, v in fields.items()}
    runs = pd.DataFrame(rows)
    budgets = sorted(runs.loc[runs["method"].str.fullmatch(r"anneal \S+"), "budget"].unique())
    reference = method_name(a.reference if a.reference is not None else budgets[-1])
    summary, per_field = summarise(runs, fields, reference)
    runs.to_csv(a.out / f"anneal_ladder_runs_{suffix}.csv", index=False, float_format="%.6g")
    summary.to_csv(a.out / f"anneal_ladder_{suffix}.csv", index=False, float_format="%.5g")
    per_field.to_csv(a.out / f"anneal_ladder_fields_{suffix}.csv", index=False,
                     float_format="%.5g")
    show = ["mould", "method", "n", "e_median", "e_vs_hybrid_pct", "d_hybrid", "p_hybrid",
            "d_ref", "d_ref_noise", "p_ref", "spread", "mean_sx2", "mean_sz2", "nn_order",
            "accept_ori", "inverted_max", "min_nn_length", "max_force", "cpu_s"]
    with pd.option_context("display.width", 250, "display.max_columns", 30):
        log(summary[[c for c in show if c in summary]].to_string(index=False,
                                                                 float_format="%.4g"))
    log(verdict(summary, per_field, reference))
    if a.markdown:
        log(markdown(summary, per_field))


if __name__ == "__main__":
    main()
