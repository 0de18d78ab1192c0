"""Simulation methods run on one mould: the answers the accuracy study scores.

A method is a solver with its budget and force tolerance: the long anneal (the paper's
algorithm at the longest budget affordable, then tight relaxation: `recipes.anneal_then_relax`),
short anneals that stop unconverged, the minimiser, and the converged hybrid (ftol 1e-4). Each
runs once per mould with a study seed (`condor.data.seeds.study_seed`), independent of the
dataset's replicas, which are the truth it is scored against. The dataset's own solver needs
no run here: its replicas are the "single simulation" and "mean of k simulations" answers.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from condor.data.fields import cell_fields
from condor.progress import progress
from condor.data.seeds import study_seed
from condor.model.simulate import SimResult, simulate
from condor.studies.recipes import anneal_then_relax

CONVERGED_FTOL = 1.0e-4  # the hybrid "converged" rung (kappa0 l0)


@dataclass(frozen=True)
class Method:
    """One simulation method: label (as charts and tables name it), family (its colour),
    solver, budget (moves per cell for anneals), ftol, and whether a tight relaxation follows a long anneal."""

    label: str
    family: str
    solver: str
    budget: float | None = None
    ftol: float | None = None
    long_anneal: bool = False


def study_methods(reference_budget: float, anneal_budgets, converged_ftol: float = CONVERGED_FTOL
                  ) -> list[Method]:
    """The long anneal, the short anneals, the minimiser, the hybrid at its own tolerance (the
    dataset's solver before L-BFGS) and converged."""
    methods = [Method(f"long anneal {reference_budget:g}", "long anneal", "anneal",
                      float(reference_budget), long_anneal=True)]
    methods += [Method(f"anneal {b:g}", "anneal", "anneal", float(b)) for b in anneal_budgets]
    methods.append(Method("minimise", "minimise", "minimise"))
    methods.append(Method("hybrid (old default)", "hybrid", "hybrid"))
    methods.append(Method(f"hybrid ftol {converged_ftol:g}", "hybrid", "hybrid", None,
                          converged_ftol))
    return methods


def run_method(mould, scene, method: Method, seed: int) -> SimResult:
    """One run of `method` on `mould` in `scene`."""
    if method.long_anneal:
        return anneal_then_relax(mould, scene.depth, method.budget, seed)
    return simulate(mould.polygon, mould.tethers, scene.depth, method.solver, method.budget,
                    seed, method.ftol)


def evaluations(result: SimResult) -> int:
    """Energy+gradient evaluations the solve used (the minimiser's iterations)."""
    return int(result.info.get("evaluations", result.info.get("min_iterations", 0)))


def run_methods(mould, scene, methods, dataset_seed: int, log=None):
    """Every method on `mould` (study seeds of `dataset_seed`): (rows, raw fields (K, 8, H, W)
    float32 with NaN for a failed run)."""
    rows, fields = [], []
    for k, method in enumerate(progress(methods, desc=f"mould {mould.mould_id}", unit="method")):
        result = run_method(mould, scene, method, study_seed(dataset_seed, mould.mould_id, k))
        rows.append({"mould": int(mould.mould_id), "method": method.label,
                     "family": method.family, "seed": result.seed, "cpu_s": result.seconds,
                     "evaluations": evaluations(result), "n_cells": result.n_cells,
                     "energy_per_cell": result.energy_per_cell, "status": result.status})
        if result.status == "ok":
            fields.append(cell_fields(result.positions, result.orientations, result.tension,
                                      scene.box, scene.pixels, scene.sigma))
        else:
            fields.append(np.full((8, scene.pixels, scene.pixels), np.nan, np.float32))
        if log is not None:
            r = rows[-1]
            log(f"mould {r['mould']} {r['method']:24s} {r['cpu_s']:8.2f} s  E/cell "
                f"{r['energy_per_cell']:.6f}  {r['status']}")
    return rows, np.stack(fields)
