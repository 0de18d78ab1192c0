"""The recipes every study shares, each written once.

- `anneal_then_relax`: the paper's anneal for `budget` moves per cell from the lattice (random
  orientations of `seed`), then the dataset's minimiser (L-BFGS with exact walls) to a tight
  force tolerance. It is the accuracy study's "long anneal" and every rung of the anneal
  ladder. The finish was FIRE (soft walls) before: on default-scene moulds 7 and 12 after an
  anneal of 1e3 moves per cell, L-BFGS reached 1e-5 in 1,565-1,940 evaluations (2.4-2.8 s),
  FIRE had not in 15,000-20,000 (21-24 s; its projection then left 1.2-1.6 on the cells at the
  walls); and the same walls as the dataset's solver keep wall treatment out of every
  comparison with it.
- `reference_ensemble`: what every accuracy figure is measured against. The expected fields
  of a mould are the mean of its replicas, the same mould simulated with several seeds; the
  dataset store keeps them (the test split's replicas), so the ensemble is read, never re-run.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np
import xarray as xr

from condor.model.energy import random_orientations
from condor.data.fields import normalise
from condor.model.lattice import build_lattice
from condor.model.simulate import SimResult, simulate_lattice
from condor.data.store import open_store

TIGHT_FTOL = 1.0e-5  # kappa0 l0: the references' force tolerance
TIGHT_MAX_ITER = 20000  # minimiser evaluations at most after the anneal
RELAX_SOLVER = "lbfgs"  # the finish: exact walls, as the dataset's solver
MIN_REPLICAS = 4  # fewer ok replicas than this and a mould is left out of the ensemble


def anneal_then_relax(mould, depth: float, budget: float, seed: int,
                      ftol: float = TIGHT_FTOL, checkpoint=None, log=None) -> SimResult:
    """Anneal `budget` moves per cell, then RELAX_SOLVER to `ftol`; `seconds` and
    `info["evaluations"]` are the sums of both. checkpoint, log: the anneal's
    (`condor.model.anneal.anneal`): a long anneal saves its state there and resumes from it."""
    lattice = build_lattice(mould.polygon, mould.tethers, depth)
    start = random_orientations(lattice.n_cells, np.random.default_rng([int(seed), 1]))
    annealed = simulate_lattice(lattice, lattice.positions, start, "anneal", budget, seed,
                                checkpoint=checkpoint, log=log)
    if annealed.status != "ok":
        return annealed
    result = simulate_lattice(lattice, annealed.positions, annealed.orientations, RELAX_SOLVER,
                              TIGHT_MAX_ITER, seed, ftol)
    result.seconds += annealed.seconds
    result.info["evaluations"] += annealed.info["evaluations"]
    result.budget = float(budget)
    result.info["anneal_seconds"] = annealed.seconds
    result.info["anneal_energy"] = annealed.energy
    result.info.update({k: v for k, v in annealed.info.items() if k.startswith("anneal_")})
    return result


@dataclass(frozen=True)
class Ensemble:
    """Replicas of M moulds: raw fields (M, R, 8, H, W), cell counts N_c (M,), inputs
    (M, 2, H, W) (the masks), the pixel side in l0, per replica (M, R) its CPU seconds and
    energy per cell, and the lattice channels (M, 2, H, W; condor.data.inputs). A mould with fewer
    replicas than R is NaN-padded after its own (condor.measures.estimators), as the tether-free test
    moulds hold more."""

    moulds: np.ndarray
    raw: np.ndarray
    n_cells: np.ndarray
    inputs: np.ndarray
    pixel_size: float
    seconds: np.ndarray
    energy_per_cell: np.ndarray
    lattice: np.ndarray | None = None

    @property
    def normalised(self) -> np.ndarray:
        """Fields x N_p / N_c (M, R, 8, H, W), float64."""
        return normalise(self.raw.astype(np.float64), self.n_cells[:, None].repeat(
            self.raw.shape[1], axis=1))

    @property
    def n_replicas(self) -> int:
        """R, the most replicas a mould holds."""
        return int(self.raw.shape[1])

    @property
    def replica_counts(self) -> np.ndarray:
        """Replicas each mould holds (M,): those not NaN-padded."""
        return (~np.isnan(self.raw.reshape(self.raw.shape[:2] + (-1,))[:, :, 0])).sum(axis=1)

    def describe_replicas(self) -> str:
        """'4 replicas', or '4-20 replicas' when moulds hold different numbers."""
        lo, hi = int(self.replica_counts.min()), int(self.replica_counts.max())
        return f"{lo} replicas" if lo == hi else f"{lo}-{hi} replicas"


def reference_ensemble(store, moulds=None, max_moulds: int | None = None) -> Ensemble:
    """The ok replicas of `moulds` (default: every replicated mould) from the store, every ok
    replica of each (NaN-padded to the largest count: Ensemble; a mould with fewer than
    MIN_REPLICAS ok replicas is left out). ValueError when no mould is left."""
    ds = store if isinstance(store, xr.Dataset) else open_store(store)
    mould_of = ds["mould"].values
    replica_of = ds["replica"].values
    ok = ds["status"].values.astype(str) == "ok"
    if moulds is None:
        moulds = [int(m) for m in ds["replicated"].values] if "replicated" in ds.coords else []
    chosen = []
    for m in moulds:
        samples = np.flatnonzero((mould_of == m) & ok)
        if len(samples) >= MIN_REPLICAS:
            chosen.append((int(m), samples[np.argsort(replica_of[samples])]))
    chosen = chosen[:max_moulds]
    if not chosen:
        raise ValueError(f"{store}: no mould has {MIN_REPLICAS} or more ok replicas (raise "
                         "simulation.replicas.test in the config)")
    r = max(len(s) for _, s in chosen)
    samples = np.stack([np.pad(s, (0, r - len(s)), constant_values=-1) for _, s in chosen])
    present = samples >= 0
    flat = samples[present]
    raw = np.full(samples.shape + ds["fields"].shape[1:], np.nan, dtype=ds["fields"].dtype)
    raw[present] = ds["fields"].isel(sample=flat).values

    def per_replica(values):
        out = np.full(samples.shape, np.nan)
        out[present] = values[flat]
        return out

    return Ensemble(
        moulds=np.array([m for m, _ in chosen]), raw=raw,
        n_cells=ds["n_cells"].values[samples[:, 0]].astype(np.float64),
        inputs=ds["inputs"].isel(sample=samples[:, 0]).values,
        pixel_size=float(ds.attrs["pixel_size"]),
        seconds=per_replica(ds["solver_seconds"].values.astype(np.float64)),
        energy_per_cell=per_replica(ds["energy"].values / ds["n_cells"].values),
        lattice=ds["lattice"].isel(sample=samples[:, 0]).values)
