"""Stability cases of the simulator: hard inputs, and what each solver does with them.

Each case is a small mould (depth 2 l0, a few hundred cells) with, optionally, a start state
other than the lattice and per-solver budgets. `run_cases` runs every case with every solver
and tabulates the outcome: `status` (simulate's "ok" or the reason it flags, or
"rejected: ..." when the input raised ValueError), the energy per cell, and in words what
happened. `Case.expect` is the outcome the design promises (a status prefix); `as_expected`
says whether it held.

Cases (see CASES): a schedule far too fast; a mould with no tethers; a thin neck; a tether
touching the wall; a lattice forced to fold (half the network mirrored through the mid-plane,
a distance-preserving reflection that no local move can undo); two cells at the same point
(a zero-length bond: no direction, so no force); NaN input (a NaN tether, and a NaN start state).
"""

from __future__ import annotations

import time
from dataclasses import dataclass, field
from typing import Callable

import numpy as np
import pandas as pd
from shapely.geometry import Polygon, box

from condor.model.energy import random_orientations
from condor.model.lattice import build_lattice
from condor.model.simulate import SOLVERS, simulate_lattice

DEPTH = 2.0  # l0: 3 layers, a few hundred cells per case
SQUARE = box(0, 0, 8, 6)
TWO_POSTS = np.array([[2.0, 3.0, 0.8], [6.0, 3.0, 0.8]])
NECK = box(0, 0, 5, 5).union(box(9, 0, 14, 5)).union(box(5, 2.2, 9, 2.8))  # 0.6 l0 neck
NECK_POSTS = np.array([[2.5, 2.5, 0.8], [11.5, 2.5, 0.8]])
UNRELAXED_RATIO = 2.0  # E/cell above this many times the converged minimum: "unrelaxed"


def _lattice_start(lattice, seed: int):
    return lattice.positions, random_orientations(lattice.n_cells, np.random.default_rng([seed, 1]))


def _folded_start(lattice, seed: int):
    """Cells left of the centre reflected through the mid-plane z -> z_top - z.

    The (001) layers are mirror-symmetric about the mid-plane, so each cell lands on a lattice
    site: the left half is an intact mirror image (every tetrahedron inverted), strained only
    at the seam. The energy cannot tell a mirror image apart, so no solver unfolds it.
    """
    pos, ori = _lattice_start(lattice, seed)
    pos = pos.copy()
    x_mid = 0.5 * (pos[:, 0].min() + pos[:, 0].max())
    left = (pos[:, 0] < x_mid) & ~lattice.fixed
    pos[left, 2] = pos[:, 2].max() - pos[left, 2]
    return pos, ori


def _coincident_start(lattice, seed: int):
    """One mobile cell moved onto its first nearest neighbour (a zero-length bond)."""
    pos, ori = _lattice_start(lattice, seed)
    pos = pos.copy()
    mobile = np.flatnonzero(~lattice.fixed)
    nn = (lattice.bond_shell == 0) & np.isin(lattice.bond_i, mobile)
    b = np.flatnonzero(nn)[0]
    pos[lattice.bond_i[b]] = pos[lattice.bond_j[b]]
    return pos, ori


def _nan_start(lattice, seed: int):
    pos, ori = _lattice_start(lattice, seed)
    ori = ori.copy()
    ori[np.flatnonzero(~lattice.fixed)[0]] = np.nan
    return pos, ori


@dataclass(frozen=True)
class Case:
    """A stability case: the mould, the start state, the budgets and the promised outcome."""

    name: str
    polygon: Polygon
    tethers: np.ndarray
    start: Callable = _lattice_start  # (lattice, seed) -> (positions, orientations)
    budgets: dict = field(default_factory=dict)  # solver -> budget (default: the solver's)
    expect: str = "ok"  # status prefix, or "rejected"
    compare_converged: bool = False  # report E/cell against a converged minimisation


CASES: dict[str, Case] = {c.name: c for c in (
    Case("schedule far too fast", SQUARE, TWO_POSTS,
         budgets={"anneal": 1.0, "minimise": 10.0, "hybrid": 1.0, "lbfgs": 10.0,
                  "relaxed_anneal": 1.0}, compare_converged=True),
    Case("no tethers", SQUARE, np.zeros((0, 3)), compare_converged=True),
    Case("thin neck (0.6 l0)", NECK, NECK_POSTS),
    Case("tether touching the wall", SQUARE, np.array([[1.0, 3.0, 1.0], [7.5, 3.0, 1.0]])),
    Case("lattice forced to fold", SQUARE, TWO_POSTS, start=_folded_start, expect="folded"),
    Case("two cells at the same point", SQUARE, TWO_POSTS, start=_coincident_start,
         expect="rejected"),
    Case("NaN tether radius", SQUARE, np.array([[2.0, 3.0, np.nan]]), expect="rejected"),
    Case("NaN start orientation", SQUARE, TWO_POSTS, start=_nan_start, expect="rejected"),
)}


def run_case(case: Case, solver: str, seed: int = 0, converged_energy: float | None = None):
    """Run one case with one solver; return (row dict, SimResult or None if rejected)."""
    row = dict(case=case.name, solver=solver, budget=case.budgets.get(solver), expect=case.expect)
    t0 = time.process_time()
    try:
        lattice = build_lattice(case.polygon, case.tethers, DEPTH)
        pos, ori = case.start(lattice, seed)
        result = simulate_lattice(lattice, pos, ori, solver, case.budgets.get(solver), seed)
    except ValueError as err:
        row.update(status=f"rejected: {err}", energy_per_cell=np.nan, n_cells=0,
                   seconds=time.process_time() - t0, what=f"raised ValueError: {err}")
        row["as_expected"] = case.expect == "rejected"
        return row, None
    info = result.info
    row.update(status=result.status, energy_per_cell=result.energy_per_cell,
               n_cells=result.n_cells, seconds=result.seconds,
               max_escape=info.get("max_escape"), inverted_fraction=info.get("inverted_fraction"),
               min_nn_length=info.get("min_nn_length"), converged=info.get("min_converged"))
    row["what"] = _describe(result, lattice, converged_energy)
    row["as_expected"] = result.status.startswith(case.expect)
    return row, result


def _describe(result, lattice, converged_energy: float | None) -> str:
    """What happened, in words."""
    info = result.info
    if result.status != "ok":
        return f"flagged, {result.status}"
    start = info["start_energy"] / result.n_cells
    words = [f"valid: E/cell {start:.3g} -> {result.energy_per_cell:.3g}"]
    if converged_energy:
        ratio = result.energy_per_cell / converged_energy
        state = "unrelaxed" if ratio > UNRELAXED_RATIO else "relaxed"
        words.append(f"{ratio:.3g}x the converged minimum ({state})")
    if not lattice.fixed.any():
        words.append(f"free network, mean |tension| {np.abs(result.tension).mean():.2g}")
    words.append(f"max escape {info['max_escape']:.2g} l0, "
                 f"{info['inverted_fraction']:.1%} tetrahedra inverted, "
                 f"shortest nn bond {info['min_nn_length']:.2f} l0")
    return "; ".join(words)


def converged_energy_per_cell(case: Case, seed: int = 0) -> float:
    """E/cell of the default minimiser from the lattice start (the 'converged' yardstick)."""
    lattice = build_lattice(case.polygon, case.tethers, DEPTH)
    pos, ori = _lattice_start(lattice, seed)
    return simulate_lattice(lattice, pos, ori, "minimise", None, seed).energy_per_cell


def run_cases(solvers=SOLVERS, cases=None, seed: int = 0) -> pd.DataFrame:
    """Every case (default: all of CASES) with every solver; one row each.

    Columns: case, solver, budget, expect, status, energy_per_cell, n_cells, seconds,
    max_escape, inverted_fraction, min_nn_length, converged, what, as_expected.
    """
    cases = list(CASES.values()) if cases is None else [CASES[c] if isinstance(c, str) else c
                                                         for c in cases]
    rows = []
    for case in cases:
        converged = converged_energy_per_cell(case, seed) if case.compare_converged else None
        for solver in solvers:
            rows.append(run_case(case, solver, seed, converged)[0])
    return pd.DataFrame(rows)
