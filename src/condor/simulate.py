"""Simulate one tethered mould with the CONDOR model: orchestration and failure detection.

`simulate(polygon, tethers, depth, solver, budget, seed)` builds the FCC lattice, draws
isotropic random orientations, runs a solver and checks the result. Solvers and the meaning
and default of `budget`:

  * "anneal":   the paper's Metropolis annealing; budget = moves per mobile cell
                (default DEFAULT_BUDGET["anneal"]; the paper's is 1e6).
  * "minimise": FIRE from the lattice; budget = energy+gradient evaluations.
  * "hybrid":   a short anneal (budget = its moves per cell) that lets orientations find
                better domains, then FIRE to convergence (MAX_ITER evaluations at most).

It raises ValueError for bad input only. A failed simulation returns a result whose `status`
says why it must not be used (checked in this order):
  * "nonfinite": NaN or inf in positions, orientations or energy;
  * "runaway energy": the final energy exceeds the energy of the starting lattice;
  * "escaped": a mobile cell ended more than ESCAPE_TOL outside the allowed region (before
    the minimiser's final projection onto it);
  * "folded": more than FOLD_FRACTION of the nearest-neighbour tetrahedra are inverted
    (signed volume <= 0), or a nearest-neighbour bond collapsed below COLLAPSE_LENGTH
    (no rest length is below 1 - Delta = 0.7 l0).
"""

from __future__ import annotations

import json
import time
from dataclasses import dataclass, field
from pathlib import Path

import numpy as np

from condor import anneal as anneal_mod
from condor import minimise as minimise_mod
from condor.energy import DELTA, cell_tension, lattice_energy, random_orientations
from condor.lattice import Lattice, build_lattice, signed_volumes

SOLVERS = ("anneal", "minimise", "hybrid")
DEFAULT_BUDGET = {"anneal": 1.0e3, "minimise": float(minimise_mod.MAX_ITER), "hybrid": 30.0}
ESCAPE_TOL = 0.25  # l0
FOLD_FRACTION = 0.01  # of tetrahedra
COLLAPSE_LENGTH = 0.35  # l0, nearest-neighbour bonds

_WARM = False


@dataclass
class SimResult:
    """Final state of one mould (lengths in l0, energies in kappa0 l0^2)."""

    positions: np.ndarray  # (N, 3) float64
    orientations: np.ndarray  # (N, 3) float64 unit vectors
    fixed: np.ndarray  # (N,) bool
    tension: np.ndarray  # (N,) float64, tau_i
    energy: float  # final CONDOR energy, no penalty terms
    solver: str
    budget: float | None
    seed: int
    seconds: float  # CPU seconds of the solve (lattice build excluded)
    status: str  # "ok" or why the result must not be used
    info: dict = field(default_factory=dict)  # JSON-safe extras

    @property
    def n_cells(self) -> int:
        return len(self.positions)

    @property
    def energy_per_cell(self) -> float:
        return self.energy / max(self.n_cells, 1)

    def save(self, path) -> None:
        """Write a lossless .npz (arrays as stored, scalars and info as JSON)."""
        meta = {
            "energy": self.energy, "solver": self.solver, "budget": self.budget,
            "seed": self.seed, "seconds": self.seconds, "status": self.status, "info": self.info,
        }
        with open(path, "wb") as fh:
            np.savez(
                fh, positions=self.positions, orientations=self.orientations, fixed=self.fixed,
                tension=self.tension, meta=np.array(json.dumps(meta)),
            )

    @classmethod
    def load(cls, path) -> "SimResult":
        with np.load(Path(path), allow_pickle=False) as data:
            meta = json.loads(str(data["meta"]))
            return cls(
                positions=data["positions"], orientations=data["orientations"],
                fixed=data["fixed"], tension=data["tension"], **meta,
            )


def warm_up() -> None:
    """Compile (or load from cache) every kernel on a tiny mould, once per process."""
    global _WARM
    if _WARM:
        return
    from shapely.geometry import box

    lattice = build_lattice(box(0, 0, 3, 3), np.zeros((0, 3)), 1.5)
    ori = random_orientations(lattice.n_cells, np.random.default_rng(0))
    anneal_mod.anneal(lattice, lattice.positions, ori, 1, [0])
    minimise_mod.minimise(lattice, lattice.positions, ori, max_iter=2)
    cell_tension(lattice.positions, ori, lattice.bond_i, lattice.bond_j, lattice.bond_kbar,
                 lattice.bond_rest, DELTA)
    _WARM = True


def simulate(polygon, tethers, depth: float, solver: str = "hybrid",
             budget: float | None = None, seed: int = 0) -> SimResult:
    """Simulate one mould (polygon and tethers (n, 3) x, y, radius in l0; depth in l0)."""
    if solver not in SOLVERS:
        raise ValueError(f"unknown solver {solver!r}; choose one of {SOLVERS}")
    if budget is not None and (not np.isfinite(budget) or budget < 0):
        raise ValueError(f"budget must be a non-negative number or None, got {budget!r}")
    seed = int(seed)
    lattice = build_lattice(polygon, tethers, depth)  # validates the rest
    warm_up()
    used_budget = DEFAULT_BUDGET[solver] if budget is None else float(budget)
    orientations = random_orientations(lattice.n_cells, np.random.default_rng([seed, 1]))
    start_energy = lattice_energy(lattice, lattice.positions, orientations)

    t0 = time.process_time()
    pos, ori, info = _solve(lattice, orientations, solver, used_budget, seed)
    seconds = time.process_time() - t0

    energy = lattice_energy(lattice, pos, ori)
    tension = cell_tension(pos, ori, lattice.bond_i, lattice.bond_j, lattice.bond_kbar,
                           lattice.bond_rest, DELTA)
    checks = diagnose(lattice, pos, ori, energy, start_energy, info)
    status = checks.pop("status_reason")
    info.update(checks)
    info.update(n_bonds=int(lattice.n_bonds), n_tets=int(len(lattice.tets)),
                n_fixed=int(lattice.fixed.sum()), start_energy=float(start_energy),
                n_empty_tethers=int(lattice.n_empty_tethers),
                n_widened_tethers=int(lattice.n_widened_tethers))
    return SimResult(
        positions=pos, orientations=ori, fixed=lattice.fixed.copy(), tension=tension,
        energy=float(energy), solver=solver, budget=used_budget, seed=seed, seconds=seconds,
        status=status, info=_json_safe(info),
    )


def _solve(lattice: Lattice, orientations: np.ndarray, solver: str, budget: float, seed: int):
    """Run one solver from the lattice; return (positions, orientations, info)."""
    pos, ori, info = lattice.positions, orientations, {}
    if solver in ("anneal", "hybrid"):
        pos, ori, info_a = anneal_mod.anneal(lattice, pos, ori, budget, [seed, 2])
        info.update(info_a)
    if solver == "minimise":
        pos, ori, info_m = minimise_mod.minimise(lattice, pos, ori, max_iter=max(int(budget), 1))
        info.update(info_m)
    elif solver == "hybrid":
        pos, ori, info_m = minimise_mod.minimise(lattice, pos, ori)
        info.update(info_m)
    return pos, ori, info


def diagnose(lattice: Lattice, pos, ori, energy: float, start_energy: float, info: dict) -> dict:
    """Failure checks of a final state; returns measures and 'status_reason' ('ok' or why)."""
    finite = bool(np.all(np.isfinite(pos)) and np.all(np.isfinite(ori)) and np.isfinite(energy))
    out = {"finite": finite}
    if not finite:
        out["status_reason"] = "nonfinite: NaN or inf in the final state"
        return out
    mobile = ~lattice.fixed
    escape = float(lattice.region.violation(pos[mobile]).max(initial=0.0))
    escape = max(escape, float(info.get("min_wall_penetration", 0.0)))
    vol = signed_volumes(pos, lattice.tets)
    inverted = float(np.mean(vol <= 0)) if len(vol) else 0.0
    nn = lattice.bond_shell == 0
    nn_len = np.linalg.norm(pos[lattice.bond_j[nn]] - pos[lattice.bond_i[nn]], axis=1)
    min_nn = float(nn_len.min(initial=np.inf)) if nn_len.size else float("nan")
    out.update(max_escape=escape, inverted_fraction=inverted, min_nn_length=min_nn)
    if energy > start_energy * (1 + 1e-9) + 1e-9:
        reason = f"runaway energy: final {energy:.6g} > start {start_energy:.6g}"
    elif escape > ESCAPE_TOL:
        reason = f"escaped: a cell ended {escape:.3g} l0 outside the mould"
    elif inverted > FOLD_FRACTION:
        reason = f"folded: {inverted:.2%} of tetrahedra inverted"
    elif nn_len.size and min_nn < COLLAPSE_LENGTH:
        reason = f"folded: a nearest-neighbour bond collapsed to {min_nn:.3g} l0"
    else:
        reason = "ok"
    out["status_reason"] = reason
    return out


def _json_safe(info: dict) -> dict:
    """Plain Python scalars only (numpy scalars converted), so json.dumps works."""
    return json.loads(json.dumps(info, default=lambda v: v.item() if hasattr(v, "item") else str(v)))
