"""Simulate one tethered mould with the CONDOR model: orchestration and failure detection.

`simulate(polygon, tethers, depth, solver, budget, seed)` builds the FCC lattice, draws
isotropic random orientations, runs a solver and checks the result. Solvers and the meaning
and default of `budget` (DEFAULT_BUDGET) and `ftol` (DEFAULT_FTOL):

  * "lbfgs":    L-BFGS with exact walls (`condor.model.lbfgs`) from the lattice (the
                quench); budget = energy+gradient evaluations; ftol = largest residual force.
                About 0.6x the default's cost, but it samples another family of states than
                the paper's anneal (one simulation's scatter away from it).
  * "anneal":   the paper's Metropolis annealing; budget = moves per mobile cell
                (the paper's is 1e6).
  * "minimise": FIRE (soft walls, then projected inside) from the lattice; budget =
                energy+gradient evaluations.
  * "hybrid":   a short anneal (budget = its moves per cell) that lets orientations find
                better domains, then FIRE to convergence (MAX_ITER evaluations at most).
  * "relaxed_anneal" (the default, DEFAULT_SOLVER = FAITHFUL_SOLVER):
                `condor.model.anneal.relaxed_anneal` over the temperatures where the
                orientation order forms (RELAXED_WINDOW), its positions relaxed by L-BFGS after
                every RELAXED_MOVES moves a cell (`relaxation_schedule`: a long first
                relaxation, then short ones), then L-BFGS to ftol (RELAXED_FTOL); budget = its
                moves per cell. It samples the paper's annealed ensemble at about 1.45x the
                quench's evaluations (docs/model.md, "The paper's CONDOR, and a fast sampler
                of it").

`simulate_lattice` runs a solver from a given start state (used by condor.studies.stability and
condor.studies).

Cost in machine-independent units: info["evaluations"] counts energy+gradient
evaluation-equivalents of the whole solve. A minimiser's evaluation is one; an anneal counts
the bond energies its trials evaluated over the bonds of one evaluation
(`anneal_evaluations`; measured: a Metropolis trial costs about what its bonds cost in an
evaluation, docs/model.md). info["max_force"] is the largest residual force of the final state
(`condor.model.walls.residual_forces`: projected on walls and posts, tangent for orientations,
kappa0 l0), whatever the solver.

It raises ValueError for bad input only (including a non-finite start state or bonded cells
at the same point, which have no bond direction). A failed simulation returns a result whose
`status` says why it must not be used (checked in this order):
  * "nonfinite": NaN or inf in positions, orientations or energy (also a bond that collapsed
    to zero length during the solve);
  * "runaway energy": the final energy exceeds the energy of the starting lattice;
  * "escaped": a mobile cell ended more than ESCAPE_TOL outside the allowed region (before
    the minimiser's final projection onto it);
  * "folded": more than FOLD_FRACTION of the nearest-neighbour tetrahedra are inverted
    (signed volume <= 0), or a nearest-neighbour bond collapsed below COLLAPSE_LENGTH
    (no rest length is below 1 - Delta = 0.7 l0).
"""

from __future__ import annotations

import json
import math
import time
from dataclasses import dataclass, field
from pathlib import Path

import numpy as np

from condor.files import atomic_path
from condor.model import anneal as anneal_mod
from condor.model import lbfgs as lbfgs_mod
from condor.model import minimise as minimise_mod
from condor.model.energy import DELTA, cell_tension, lattice_energy, random_orientations
from condor.model.lattice import Lattice, build_lattice, signed_volumes
from condor.model.scenes import PRESETS
from condor.model.walls import residual_forces

SOLVERS = ("lbfgs", "anneal", "minimise", "hybrid", "relaxed_anneal")
FAITHFUL_SOLVER = "relaxed_anneal"  # samples the paper's ensemble (docs/model.md)
DEFAULT_SOLVER = FAITHFUL_SOLVER
RELAXED_WINDOW = (0.03, 0.001)  # kappa0 l0^2: T_hi, T_lo of the relaxed anneal
RELAXED_MOVES = 10  # moves a cell between two relaxations of the positions (5 sweeps)
# L-BFGS evaluations of the relaxations: the first carries the lattice to its elastic balance
# and grows with the box's side (RELAXED_FIRST_RELAX at DEFAULT_BUDGET's 200 moves a cell,
# times sqrt(budget / 200): the budget grows with the box's area); every later one only follows
# the orientations (RELAXED_RELAX), except in a mould without posts (RELAXED_RELAX_FREE): a
# free slab stands up only through the collective contraction the relaxations carry, and with
# 20 some of its runs stayed part flat at the paper scene. Then L-BFGS to RELAXED_FTOL. Against
# 40 evaluations after every segment and 3e-4, the same fidelity or better at 0.7x the
# evaluations (experiments/fast_sampler: schedule_1e6.csv, seeds16_1e6.csv,
# paper_schedule_1e6.csv, tether_free_1e6.csv).
RELAXED_FIRST_RELAX = 100
RELAXED_RELAX = 20
RELAXED_RELAX_FREE = 40
RELAXED_FTOL = 1.0e-3  # kappa0 l0
DEFAULT_BUDGET = {"lbfgs": float(lbfgs_mod.MAX_ITER), "anneal": 1.0e3,
                  "minimise": float(minimise_mod.MAX_ITER), "hybrid": 30.0,
                  "relaxed_anneal": 200.0}
DEFAULT_FTOL = {"lbfgs": lbfgs_mod.FTOL, "anneal": None, "minimise": minimise_mod.FTOL,
                "hybrid": minimise_mod.FTOL, "relaxed_anneal": RELAXED_FTOL}
# The relaxed anneal's budget grows with the box's area. The orientation order it forms spans
# the box, and moves of one cell carry it over ~L^2 sweeps; the positions' long modes are the
# relaxations' (RELAXED_RELAX). DEFAULT_BUDGET's 200 moves a cell were validated in the default
# scene's box (BUDGET_BOX) and 800 in the paper scene's, twice its side, where 200 left the
# cells of a tether-free mould flat (experiments/fast_sampler, paper_budget_1e6.csv). A smaller
# box keeps the default's 200: in the tiny scene's (half the side) 50 moves left a tether-free
# mould's cells flat where 200 did not (tiny_budget_1e6.csv).
BUDGET_BOX = PRESETS["default"].box  # l0
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
        """Write a lossless .npz (arrays as stored, scalars and info as JSON), whole or not at
        all (condor.files.atomic_path)."""
        meta = {
            "energy": self.energy, "solver": self.solver, "budget": self.budget,
            "seed": self.seed, "seconds": self.seconds, "status": self.status, "info": self.info,
        }
        with atomic_path(path) as tmp, open(tmp, "wb") as fh:
            np.savez(
                fh, positions=self.positions, orientations=self.orientations, fixed=self.fixed,
                tension=self.tension, meta=np.array(json.dumps(meta)),
            )

    @classmethod
    def load(cls, path) -> "SimResult":
        """Read a result file; ValueError naming the file when it is truncated or foreign."""
        path = Path(path)
        if path.is_dir():
            raise ValueError(f"{path} is a directory, not a simulation result (.npz)")
        try:
            with np.load(path, allow_pickle=False) as data:
                meta = json.loads(str(data["meta"]))
                result = cls(positions=data["positions"], orientations=data["orientations"],
                             fixed=data["fixed"], tension=data["tension"], **meta)
        except FileNotFoundError:
            raise
        except Exception as err:  # zipfile, KeyError, JSON and dataclass errors alike
            raise ValueError(f"{path} is not a readable condor simulation result "
                             f"({type(err).__name__}: {err})") from err
        n = len(result.positions)
        if any(np.shape(a)[:1] != (n,) for a in (result.orientations, result.fixed, result.tension)):
            raise ValueError(f"{path}: per-cell arrays disagree in length (truncated?)")
        return result


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
    lbfgs_mod.minimise_lbfgs(lattice, lattice.positions, ori, max_iter=3, ftol=1e-3)
    residual_forces(lattice, lattice.positions, ori)
    cell_tension(lattice.positions, ori, lattice.bond_i, lattice.bond_j, lattice.bond_kbar,
                 lattice.bond_rest, DELTA)
    _WARM = True


def simulate(polygon, tethers, depth: float, solver: str | None = DEFAULT_SOLVER,
             budget: float | None = None, seed: int = 0, ftol: float | None = None,
             threads: int = 1) -> SimResult:
    """Simulate one mould (polygon and tethers (n, 3) x, y, radius in l0; depth in l0).

    ftol: the minimiser's force tolerance, kappa0 l0 (None: DEFAULT_FTOL[solver]); ignored by
    "anneal".
    solver None: DEFAULT_SOLVER.
    threads: the anneal's (the same result on any number; `condor.model.anneal`).
    """
    solver = solver or DEFAULT_SOLVER
    _check_solver(solver, budget, ftol)
    lattice = build_lattice(polygon, tethers, depth)  # validates the rest
    orientations = random_orientations(lattice.n_cells, np.random.default_rng([int(seed), 1]))
    return simulate_lattice(lattice, lattice.positions, orientations, solver, budget, seed, ftol,
                            threads=threads)


def simulate_lattice(lattice: Lattice, positions, orientations, solver: str | None = DEFAULT_SOLVER,
                     budget: float | None = None, seed: int = 0,
                     ftol: float | None = None, checkpoint=None, log=None,
                     threads: int = 1) -> SimResult:
    """Run a solver on `lattice` from a given start state (positions, orientations (N, 3)).

    `simulate` starts from the lattice with random orientations; this entry point serves
    studies that start elsewhere (a folded or NaN state in `condor.studies.stability`). The start
    energy (for the runaway check) is that of the given state.
    checkpoint, log: the anneal's (solvers "anneal" and "hybrid"; `condor.model.anneal.anneal`): a
    long anneal saves its state there and resumes from it. `seconds` is then the anneal's
    process time over every resumption plus this call's minimiser.
    """
    solver = solver or DEFAULT_SOLVER
    _check_solver(solver, budget, ftol)
    seed = int(seed)
    warm_up()
    used_budget = DEFAULT_BUDGET[solver] if budget is None else float(budget)
    pos0 = np.array(positions, dtype=np.float64, order="C")
    ori0 = np.array(orientations, dtype=np.float64, order="C")
    if pos0.shape != lattice.positions.shape or ori0.shape != lattice.positions.shape:
        raise ValueError(f"start state shapes {pos0.shape}, {ori0.shape} do not match the "
                         f"lattice's {lattice.positions.shape}")
    for name, array in (("positions", pos0), ("orientations", ori0)):
        if not np.all(np.isfinite(array)):
            bad = np.argwhere(~np.isfinite(array))[0]
            raise ValueError(f"start {name} must be finite, got {array[tuple(bad)]} "
                             f"at {bad.tolist()}")
    lengths = np.linalg.norm(pos0[lattice.bond_j] - pos0[lattice.bond_i], axis=1)
    if np.any(lengths == 0):
        b = int(np.argmin(lengths))
        i, j = lattice.bond_i[b], lattice.bond_j[b]
        raise ValueError(f"start positions put bonded cells {i} and {j} at the same point "
                         f"{pos0[i].tolist()}")
    start_energy = lattice_energy(lattice, pos0, ori0)

    t0 = time.process_time()
    try:
        pos, ori, info = _solve(lattice, pos0, ori0, solver, used_budget, seed,
                                DEFAULT_FTOL[solver] if ftol is None else float(ftol),
                                checkpoint, log, threads)
    except ZeroDivisionError:  # numba's 1/|l| on a bond that collapsed to zero length
        pos, ori, info = np.full_like(pos0, np.nan), ori0, {"error": "zero-length bond"}
    seconds = time.process_time() - t0
    seconds += info.get("anneal_resumed_seconds", 0.0)  # a resumed anneal's earlier part

    info["evaluations"] = float(info.get("anneal_evaluations", 0.0)
                                + info.get("min_evaluations", info.get("min_iterations", 0)))
    energy = lattice_energy(lattice, pos, ori)
    if np.all(np.isfinite(pos)) and np.all(np.isfinite(ori)):
        info["max_force"] = float(residual_forces(lattice, pos, ori).max(initial=0.0))
    else:
        info["max_force"] = float("nan")
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


def default_budget(solver: str | None, box: float) -> float:
    """The budget a solver gets in a square box of side `box` (l0) when none is asked for:
    DEFAULT_BUDGET's, and for the relaxed anneal that times (box / BUDGET_BOX)^2 where the box
    is larger than the default scene's (see BUDGET_BOX)."""
    solver = solver or DEFAULT_SOLVER
    budget = DEFAULT_BUDGET[solver]
    if solver == "relaxed_anneal":
        budget *= max(1.0, (box / BUDGET_BOX) ** 2)
    return float(budget)


def relaxation_schedule(budget: float, tethered: bool = True) -> list[int]:
    """The relaxed anneal's L-BFGS evaluations after each of its segments (one a RELAXED_MOVES
    moves a cell of `budget`, at least one): RELAXED_FIRST_RELAX x sqrt(budget /
    DEFAULT_BUDGET's) after the first, then RELAXED_RELAX after every other
    (RELAXED_RELAX_FREE in a mould without posts); the first never fewer than the others."""
    segments = max(1, int(round(budget / RELAXED_MOVES)))
    later = RELAXED_RELAX if tethered else RELAXED_RELAX_FREE
    scale = math.sqrt(max(budget, 0.0) / DEFAULT_BUDGET["relaxed_anneal"])
    first = max(later, int(round(RELAXED_FIRST_RELAX * scale)))
    return [first] + [later] * (segments - 1)


def solver_recipe(solver: str | None) -> str:
    """What a solver's name does not say of its recipe, for a store to record (a store built by
    another recipe is refused, not mixed): the relaxed anneal's window, segment, relaxations and
    tolerance; "" for the others."""
    if (solver or DEFAULT_SOLVER) != "relaxed_anneal":
        return ""
    return (f"relax:{RELAXED_WINDOW[0]}:{RELAXED_WINDOW[1]}:{RELAXED_MOVES}:"
            f"{RELAXED_FIRST_RELAX}+{RELAXED_RELAX},{RELAXED_RELAX_FREE}:{RELAXED_FTOL}")


def _check_solver(solver: str, budget, ftol) -> None:
    if solver not in SOLVERS:
        raise ValueError(f"unknown solver {solver!r}; choose one of {SOLVERS}")
    if budget is not None and (not np.isfinite(budget) or budget < 0):
        raise ValueError(f"budget must be a non-negative number or None, got {budget!r}")
    if ftol is not None and (not np.isfinite(ftol) or ftol <= 0):
        raise ValueError(f"ftol must be a positive force (kappa0 l0) or None, got {ftol!r}")


def _solve(lattice: Lattice, pos, ori, solver: str, budget: float, seed: int, ftol: float,
           checkpoint=None, log=None, threads: int = 1):
    """Run one solver from (pos, ori); return (positions, orientations, info)."""
    info = {}
    if solver in ("anneal", "hybrid"):
        pos, ori, info_a = anneal_mod.anneal(lattice, pos, ori, budget, [seed, 2],
                                             checkpoint=checkpoint, log=log, threads=threads)
        info.update(info_a)
    if solver == "relaxed_anneal":
        schedule = relaxation_schedule(budget, bool(lattice.fixed.any()))
        pos, ori, info_a = anneal_mod.relaxed_anneal(lattice, pos, ori, [seed, 2],
                                                     *RELAXED_WINDOW, len(schedule),
                                                     RELAXED_MOVES, schedule, threads=threads)
        info.update(info_a)
        pos, ori, info_m = lbfgs_mod.minimise_lbfgs(lattice, pos, ori, lbfgs_mod.MAX_ITER, ftol)
        info.update(info_m)
    if solver == "lbfgs":
        pos, ori, info_m = lbfgs_mod.minimise_lbfgs(lattice, pos, ori,
                                                    max_iter=max(int(budget), 1), ftol=ftol)
        info.update(info_m)
    elif solver == "minimise":
        pos, ori, info_m = minimise_mod.minimise(lattice, pos, ori, max_iter=max(int(budget), 1),
                                                 ftol=ftol)
        info.update(info_m)
    elif solver == "hybrid":
        pos, ori, info_m = minimise_mod.minimise(lattice, pos, ori, ftol=ftol)
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
