"""Speed against accuracy of the solvers, and the scene convergence study (tables and charts).

`sweep` runs, for each mould, every method of a list (anneal budgets over several decades, the
minimiser, the hybrid, looser tolerances) plus two references, and compares them:
  * the long-anneal reference: the longest affordable anneal (seed 0), whose own result is
    reported as a method too, followed by FIRE to a tight force tolerance;
  * the tight minimiser: FIRE from the lattice (seed 0) to the same tight tolerance.
Energies are compared with the lowest energy any run of that mould reached (`rel_energy`,
E / E_best - 1) and with the long-anneal reference (`rel_energy_ref`); fields (normalised,
fields * N_p / N_c) by their mean absolute error against the reference's (`field_mae`, mean
over the 8 channels and pixels). Two converged states from different starts differ by their
orientation domains; the tight minimiser's MAE against the reference measures that floor.

`convergence` measures how the fields change with the number of layers (depth) and with the
box size (the default scene is the paper's geometry at half scale), against a seed-to-seed
noise baseline: the same configuration simulated with another seed.

Times are CPU seconds (time.process_time) of the solve, single thread.
"""

from __future__ import annotations

import math
from dataclasses import dataclass
from pathlib import Path

import numpy as np
import pandas as pd

from condor.energy import random_orientations
from condor.fields import FIELD_NAMES, cell_fields, normalise
from condor.lattice import HALF, build_lattice
from condor.scenes import Scene, get_scene
from condor.simulate import simulate, simulate_lattice

TIGHT_FTOL = 1.0e-5  # kappa0 l0, force tolerance of the references
TIGHT_MAX_ITER = 8000  # evaluations of the references' FIRE (energy settled to ~1e-5 by then)
REFERENCE_SEED = 0


@dataclass(frozen=True)
class Method:
    """One point of the sweep: a solver with its budget and force tolerance."""

    label: str
    solver: str
    budget: float | None = None
    ftol: float | None = None


def default_methods(anneal_budgets=(10, 100, 1000), other_ftol: float = 1e-4) -> list[Method]:
    """Anneals over `anneal_budgets` (moves per cell), minimiser and hybrid at the default
    tolerance (minimise.FTOL) and at `other_ftol`."""
    methods = [Method(f"anneal {b:g}", "anneal", float(b)) for b in anneal_budgets]
    for solver in ("minimise", "hybrid"):
        methods.append(Method(solver, solver))
        methods.append(Method(f"{solver} ftol {other_ftol:g}", solver, None, other_ftol))
    return methods


def _scene(scene) -> Scene:
    return scene if isinstance(scene, Scene) else get_scene(scene)


def _moulds(scene: Scene, mould_ids, moulds, dataset_seed: int) -> list:
    if moulds is not None:
        return list(moulds)
    from condor.moulds import generate_mould

    return [generate_mould(dataset_seed, int(i), scene.box) for i in mould_ids]


def normalised_fields(result, box: float, pixels: int, sigma: float) -> np.ndarray:
    """Fields * N_p / N_c (8, pixels, pixels) float64 of a SimResult."""
    f = cell_fields(result.positions, result.orientations, result.tension, box, pixels, sigma)
    return normalise(f.astype(np.float64), result.n_cells)


def _row(scene: Scene, mould, method: Method, result, role: str, seconds: float) -> dict:
    return dict(
        scene=scene.name, mould=int(mould.mould_id), n_cells=result.n_cells, seed=result.seed,
        method=method.label, solver=method.solver, budget=result.budget,
        ftol=method.ftol, role=role, seconds=seconds, energy_per_cell=result.energy_per_cell,
        evaluations=result.info.get("min_iterations", 0), status=result.status,
    )


def sweep(scene="default", mould_ids=(0, 1), seeds=(1,), methods=None,
          reference_budget: float = 1e4, tight_ftol: float = TIGHT_FTOL, dataset_seed: int = 0,
          moulds=None, log=None) -> pd.DataFrame:
    """Speed/accuracy table: one row per (mould, method, seed) plus the reference rows.

    scene: a Scene or preset name; moulds: Mould objects (default: generate_mould(dataset_seed,
    id, scene.box) for mould_ids); seeds: simulation seeds of the methods (the references use
    seed 0); reference_budget: moves per cell of the long anneal. Columns: scene, mould,
    n_cells, seed, method, solver, budget, ftol, role ("method", "long anneal", "reference",
    "tight minimiser"), seconds, energy_per_cell, evaluations, status, rel_energy,
    rel_energy_ref, field_mae, mae_<field>.
    """
    scene = _scene(scene)
    methods = default_methods() if methods is None else list(methods)
    rows, fields = [], []
    for mould in _moulds(scene, mould_ids, moulds, dataset_seed):
        start = len(rows)
        for row, result in _reference_runs(scene, mould, reference_budget, tight_ftol):
            rows.append(row)
            fields.append(normalised_fields(result, scene.box, scene.pixels, scene.sigma))
            _log(log, row)
        for seed in seeds:
            for method in methods:
                r = simulate(mould.polygon, mould.tethers, scene.depth, method.solver,
                             method.budget, seed, method.ftol)
                rows.append(_row(scene, mould, method, r, "method", r.seconds))
                fields.append(normalised_fields(r, scene.box, scene.pixels, scene.sigma))
                _log(log, rows[-1])
        _compare(rows[start:], fields[start:])
    return pd.DataFrame(rows)


def _reference_runs(scene: Scene, mould, reference_budget: float, tight_ftol: float):
    """The long anneal, the long anneal + tight FIRE (the reference) and the tight minimiser."""
    lattice = build_lattice(mould.polygon, mould.tethers, scene.depth)
    ori = random_orientations(lattice.n_cells, np.random.default_rng([REFERENCE_SEED, 1]))
    long = simulate_lattice(lattice, lattice.positions, ori, "anneal", reference_budget,
                            REFERENCE_SEED)
    label = f"anneal {reference_budget:g}"
    yield _row(scene, mould, Method(label, "anneal", reference_budget), long, "long anneal",
               long.seconds), long
    ref = simulate_lattice(lattice, long.positions, long.orientations, "minimise",
                           TIGHT_MAX_ITER, REFERENCE_SEED, tight_ftol)
    ref.info["start_energy"] = long.info["start_energy"]
    method = Method(f"{label} + FIRE {tight_ftol:g}", "hybrid", reference_budget, tight_ftol)
    row = _row(scene, mould, method, ref, "reference", long.seconds + ref.seconds)
    row["budget"] = reference_budget
    yield row, ref
    tight = simulate_lattice(lattice, lattice.positions, ori, "minimise", TIGHT_MAX_ITER,
                             REFERENCE_SEED, tight_ftol)
    yield _row(scene, mould, Method(f"minimise ftol {tight_ftol:g}", "minimise", None,
                                    tight_ftol), tight, "tight minimiser", tight.seconds), tight


def _compare(rows: list[dict], fields: list[np.ndarray]) -> None:
    """Fill the energy and field comparisons of one mould's rows (in place)."""
    ok = [r["energy_per_cell"] for r in rows if r["status"] == "ok"]
    best = min(ok) if ok else math.nan
    ref_index = next(k for k, r in enumerate(rows) if r["role"] == "reference")
    ref_energy, ref_fields = rows[ref_index]["energy_per_cell"], fields[ref_index]
    for row, f in zip(rows, fields):
        row["rel_energy"] = row["energy_per_cell"] / best - 1.0
        row["rel_energy_ref"] = row["energy_per_cell"] / ref_energy - 1.0
        mae = np.abs(f - ref_fields).mean(axis=(1, 2))
        row["field_mae"] = float(mae.mean())
        row.update({f"mae_{name}": float(v) for name, v in zip(FIELD_NAMES, mae)})


def _log(log, row: dict) -> None:
    if log is not None:
        log(f"{row['scene']} mould {row['mould']} seed {row['seed']} {row['method']:28s} "
            f"{row['n_cells']:6d} cells {row['seconds']:8.2f} s  E/cell "
            f"{row['energy_per_cell']:.6f} {row['status']}")


def summary(df: pd.DataFrame) -> pd.DataFrame:
    """Medians (and ranges) per scene and method: seconds, energies, field MAE."""
    g = df.groupby(["scene", "role", "method"], sort=False)
    out = g.agg(
        runs=("seconds", "size"), n_cells=("n_cells", "median"),
        seconds=("seconds", "median"), seconds_max=("seconds", "max"),
        rel_energy=("rel_energy", "median"), rel_energy_max=("rel_energy", "max"),
        rel_energy_ref=("rel_energy_ref", "median"),
        field_mae=("field_mae", "median"), ok=("status", lambda s: int((s == "ok").sum())),
    )
    return out.reset_index()


def _family(method: str, role: str) -> str:
    if role in ("reference", "tight minimiser"):
        return role
    return method.split(" ")[0] if not method.startswith("anneal") else "anneal"


def chart(df: pd.DataFrame, path) -> None:
    """Two panels against CPU seconds (log x): energy per cell above the best found
    (log y, floored at 1e-6), and field MAE against the long-anneal reference."""
    plt = _pyplot()
    fig, axes = plt.subplots(1, 2, figsize=(11, 4.2))
    colours = {"anneal": "tab:red", "minimise": "tab:blue", "hybrid": "tab:green",
               "reference": "black", "tight minimiser": "tab:purple"}
    markers = dict(zip(sorted(df["scene"].unique()), "os^Dv"))
    for (scene, method, role), g in df.groupby(["scene", "method", "role"], sort=False):
        family = _family(method, role)
        style = dict(color=colours.get(family, "grey"), marker=markers[scene], alpha=0.75,
                     s=22, edgecolors="none")
        seconds = g["seconds"].clip(lower=1e-3)
        axes[0].scatter(seconds, g["rel_energy"].clip(lower=1e-6), **style)
        axes[1].scatter(seconds, g["field_mae"].clip(lower=1e-6), **style)
        if family == "anneal":
            axes[0].annotate(method.split(" ")[1], (seconds.median(), g["rel_energy"].median()),
                             fontsize=6, xytext=(3, 3), textcoords="offset points")
    axes[0].axhline(0.01, color="grey", lw=0.8, ls=":")
    axes[0].set_yscale("log")
    axes[0].set_ylabel("energy per cell / best found - 1 (0 shown at 1e-6)")
    axes[1].set_ylabel("field MAE vs long-anneal reference")
    for ax in axes:
        ax.set_xscale("log")
        ax.set_xlabel("CPU seconds (one core)")
        ax.grid(alpha=0.3, which="both", lw=0.4)
    floor = df[df["role"] == "tight minimiser"].groupby("scene")["field_mae"].median()
    for scene, value in floor.items():
        axes[1].axhline(value, color="tab:purple", lw=0.8, ls="--")
        axes[1].annotate(f"converged vs converged ({scene})", (0.02, value), fontsize=6,
                         color="tab:purple", xycoords=("axes fraction", "data"),
                         xytext=(0, 2), textcoords="offset points")
    handles = [plt.Line2D([], [], color=c, marker="o", ls="", label=k) for k, c in colours.items()]
    handles += [plt.Line2D([], [], color="grey", marker=m, ls="", label=f"scene {s}")
                for s, m in markers.items()]
    axes[1].legend(handles=handles, fontsize=7, loc="upper right")
    fig.tight_layout()
    _save(fig, path, plt)


# ------------------------------------------------------------------ scene convergence study


def n_layers(depth: float) -> int:
    """FCC (001) layers that fit in 0 <= z <= depth (l0)."""
    return int(math.floor(depth / HALF + 1e-9)) + 1


def convergence(scene="default", mould_ids=(0,), seeds=(0, 1), depths=(2.0, 3.0, 4.0),
                box_scales=(1.0, 2.0), solver: str = "hybrid", dataset_seed: int = 0,
                moulds=None, log=None) -> pd.DataFrame:
    """How the fields change with depth (layers) and box size, against seed-to-seed noise.

    Depth study: each mould at every depth of `depths`, compared on the scene's grid with the
    deepest configuration at seeds[0]. Box study: the mould generated in a box scale x the
    scene's (generate_mould scales the whole geometry, tether radii included), rasterised in
    box-relative coordinates (same pixels, sigma scaled with the box) and compared with the
    largest box at seeds[0] (moulds are regenerated from their seed and id with the default
    generator parameters). The reference configuration at the other seeds gives the noise
    baseline (`baseline` True). Columns: study, mould, value (depth or box), layers, n_cells,
    seed, baseline, seconds, energy_per_cell, status, rel_<field> (MAE / mean |reference|, of
    fields normalised per cell) and rel_mean (mean over P, T, Sx2, Sy2, Sz2).
    """
    from condor.moulds import generate_mould

    scene = _scene(scene)
    if len(seeds) < 2:
        raise ValueError(f"convergence needs at least 2 seeds for the noise baseline, got {seeds}")
    rows = []
    for mould in _moulds(scene, mould_ids, moulds, dataset_seed):
        runs = {}
        for depth in depths:
            for seed in seeds:
                r = simulate(mould.polygon, mould.tethers, depth, solver, None, seed)
                f = normalised_fields(r, scene.box, scene.pixels, scene.sigma)
                runs[depth, seed] = (r, f)
        rows += _study_rows("depth", mould.mould_id, runs, max(depths), seeds, log)
        runs = {}
        for scale in box_scales or ():
            box = scene.box * scale
            scaled = generate_mould(mould.seed, mould.mould_id, box)
            for seed in seeds:
                r = simulate(scaled.polygon, scaled.tethers, scene.depth, solver, None, seed)
                f = normalised_fields(r, box, scene.pixels, scene.sigma * scale)
                runs[box, seed] = (r, f)
        if runs:
            rows += _study_rows("box", mould.mould_id, runs, scene.box * max(box_scales), seeds,
                                log)
    return pd.DataFrame(rows)


def _study_rows(study: str, mould_id: int, runs: dict, ref_value: float, seeds, log) -> list:
    ref = runs[ref_value, seeds[0]][1]
    scale = np.abs(ref).mean(axis=(1, 2))
    out = []
    for (value, seed), (r, f) in runs.items():
        if value == ref_value and seed == seeds[0]:
            continue
        rel = np.abs(f - ref).mean(axis=(1, 2)) / scale
        row = dict(study=study, mould=int(mould_id), value=float(value),
                   layers=n_layers(value) if study == "depth" else None, n_cells=r.n_cells,
                   seed=seed, baseline=bool(value == ref_value),
                   seconds=r.seconds, energy_per_cell=r.energy_per_cell, status=r.status)
        row.update({f"rel_{n}": float(v) for n, v in zip(FIELD_NAMES, rel)})
        row["rel_mean"] = float(np.mean(rel[:5]))
        out.append(row)
        if log is not None:
            log(f"{study} mould {mould_id} value {value:g} seed {seed} cells {r.n_cells} "
                f"{r.seconds:.1f} s rel P {rel[0]:.3f} T {rel[1]:.3f} mean {row['rel_mean']:.3f}")
    return out


def convergence_summary(df: pd.DataFrame, slack: float = 1.25) -> pd.DataFrame:
    """Median relative MAE per study and value, with the seed-to-seed noise of that study
    (`noise`: the baseline's rel_mean) and `within_noise`: every channel of P, T, Sx2, Sy2,
    Sz2 within `slack` x the same channel's noise (a reduction this passes is justified)."""
    cols = [c for c in df.columns if c.startswith("rel_")]
    med = df.groupby(["study", "value", "baseline"])[cols + ["n_cells", "seconds"]].median()
    med = med.reset_index()
    base = med[med["baseline"]].set_index("study")
    med["noise"] = med["study"].map(base["rel_mean"])
    channels = [f"rel_{n}" for n in FIELD_NAMES[:5]]
    within = np.ones(len(med), dtype=bool)
    for c in channels:
        within &= (med[c] <= slack * med["study"].map(base[c])).to_numpy()
    med["within_noise"] = within
    return med


def convergence_chart(df: pd.DataFrame, path) -> None:
    """Relative field change per channel against depth and box size; dashed: the noise."""
    plt = _pyplot()
    studies = list(dict.fromkeys(df["study"]))
    fig, axes = plt.subplots(1, len(studies), figsize=(5.2 * len(studies), 3.8), squeeze=False)
    channels = ["P", "T", "Sx2", "Sy2", "Sz2"]
    for ax, study in zip(axes[0], studies):
        d = df[(df["study"] == study) & ~df["baseline"]]
        base = df[(df["study"] == study) & df["baseline"]]
        for k, ch in enumerate(channels):
            med = d.groupby("value")[f"rel_{ch}"].median()
            line, = ax.plot(med.index, med.values, marker="o", label=ch, color=f"C{k}")
            if len(base):
                ax.axhline(base[f"rel_{ch}"].median(), color=line.get_color(), ls="--", lw=0.8)
        ax.set_xlabel("depth, l0" if study == "depth" else "box side, l0")
        ax.set_ylabel("relative MAE vs reference configuration")
        ax.set_title(f"{study} (dashed: same configuration, other seed)", fontsize=9)
        ax.set_ylim(bottom=0)
        ax.grid(alpha=0.3)
        ax.legend(fontsize=7)
    fig.tight_layout()
    _save(fig, path, plt)


def _pyplot():
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    return plt


def _save(fig, path, plt) -> None:
    Path(path).parent.mkdir(parents=True, exist_ok=True)
    fig.savefig(path, dpi=120)
    plt.close(fig)
