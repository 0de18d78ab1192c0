"""Confirm searched designs with the simulator: predicted against simulated objective.

`select_for_confirmation` picks the designs to simulate: the best designs that are distinct
by a stated rule (`distinct`: footprints differing in DISTINCT_FOOTPRINT of the pixels either
covers, or posts in DISTINCT_POSTS of theirs), every one of which is simulated and drawn, and
a random sample of the others, stratified over the predicted objective (one draw per
equal-width bin) so that the rank correlation measures how the surrogate orders the range
of designs the search saw, not only the seed noise among near-equal top designs.

`simulate_designs` simulates each with replicas (condor.model.simulate.simulate, seeds by the
replica convention, `replica_seeds`) and computes the simulated objective from the
replica-mean normalised fields (the expected organisation), plus the spread of the
per-replica objective. `baseline_objectives` does the same for a set of already simulated
moulds (e.g. the dataset's random test moulds). `agreement` and `design_summary` report the
Spearman rank correlation and bias between predicted and simulated objective (with bootstrap
intervals and the replicas' own noise ceiling) and the improvement of the designs over the
best baseline mould. Everything returns pandas DataFrames; nothing is drawn.
"""

from __future__ import annotations

import sys
from dataclasses import dataclass

import numpy as np
import pandas as pd
from tqdm.auto import tqdm

from condor.measures.estimators import BOOTSTRAP_SAMPLES, bootstrap_interval, pearson_r
from condor.data.fields import cell_fields, normalise
from condor.moulds.mould import Mould, input_channels
from condor.data.seeds import replica_seed
from condor.model.scenes import same_length
from condor.model.simulate import default_budget, simulate

from .objectives import Objective
from .search import SearchResult


def replica_seeds(seed: int, mould_id: int, replicas: int) -> list[int]:
    """Simulation seeds of replicas 0..replicas-1 of mould `mould_id` under global seed
    `seed`: condor.data.seeds.replica_seed, the store's convention (replica 0 is the stream of a
    dataset's own sample)."""
    if isinstance(replicas, bool) or not isinstance(replicas, (int, np.integer)) or replicas < 1:
        raise ValueError(f"replicas = {replicas!r} must be a positive integer")
    return [replica_seed(int(seed), int(mould_id), r) for r in range(replicas)]


# --------------------------------------------------------------------------- selection

# Two designs are distinct (the k best that design confirms and draws are pairwise distinct)
# when their footprints (mould and posts, on the surrogate's grid) differ in at least
# DISTINCT_FOOTPRINT of the pixels either covers, or their posts in at least DISTINCT_POSTS of
# the post pixels either has (a post moved by its own radius, or one more or fewer): less
# cannot be told apart in a drawing, and confirms nothing new.
DISTINCT_FOOTPRINT = 0.10
DISTINCT_POSTS = 0.5


def distinct(a: np.ndarray, b: np.ndarray) -> bool:
    """Whether two designs' input channels (2, H, W) are distinct by the rule above."""
    footprint = _difference(a.any(axis=0), b.any(axis=0))
    posts = _difference(a[1].astype(bool), b[1].astype(bool))
    return footprint >= DISTINCT_FOOTPRINT or posts >= DISTINCT_POSTS


def select_for_confirmation(result: SearchResult, n_top: int, n_random: int,
                            seed: int = 0) -> pd.DataFrame:
    """Rows of result.designs to simulate, with a `role` column ("top" or "random").

    top: the best-ranked feasible designs, each distinct (`distinct`) from every design
    already picked (fewer than n_top when the search found fewer distinct ones). random: from the remaining distinct designs with a defined
    objective, one uniform draw in each of `n_random` equal-width bins of the predicted
    objective, topped up by uniform draws when bins are empty (default_rng([seed, 1])). Most
    of a search's evaluations crowd near its optimum, so equal-width bins (rather than
    equal-count ones) are what spreads the sample over the range the search saw.
    """
    for name, value in (("n_top", n_top), ("n_random", n_random)):
        if isinstance(value, bool) or not isinstance(value, (int, np.integer)) or value < 0:
            raise ValueError(f"{name} = {value!r} must be a non-negative integer")
    candidates = result.ranked(distinct=True)
    candidates = candidates[np.isfinite(candidates["objective"].to_numpy(dtype=float))]
    pixels = result.pixels
    picked, rasters = [], []
    for row in candidates[candidates["feasible"]].itertuples():
        if len(picked) >= n_top:
            break
        channels = input_channels(result.mould(row.design), pixels)
        if all(distinct(channels, other) for other in rasters):
            picked.append(row.design)
            rasters.append(channels)
    rest = candidates[~candidates["design"].isin(picked)]
    chosen_random = _stratified_sample(rest["design"].to_numpy(), rest["objective"].to_numpy(),
                                       n_random, np.random.default_rng([int(seed), 1]))
    table = pd.concat([
        candidates.set_index("design").loc[picked].reset_index().assign(role="top"),
        candidates.set_index("design").loc[chosen_random].reset_index().assign(role="random"),
    ], ignore_index=True)
    return table[["design", "role"] + [c for c in table.columns if c not in ("design", "role")]]


def _stratified_sample(designs: np.ndarray, values: np.ndarray, n: int,
                       rng: np.random.Generator) -> list[int]:
    """One uniform draw in each of n equal-width bins of `values` (empty bins skipped), then
    uniform draws from the rest until n are chosen (or none is left)."""
    if n == 0 or len(designs) == 0:
        return []
    edges = np.linspace(values.min(), values.max(), n + 1)
    bins = np.clip(np.searchsorted(edges, values, side="right") - 1, 0, n - 1)
    chosen = [int(rng.choice(designs[bins == b])) for b in range(n) if np.any(bins == b)]
    left = designs[~np.isin(designs, chosen)]
    extra = rng.choice(left, size=min(n - len(chosen), len(left)), replace=False)
    return chosen + [int(d) for d in extra]


def _difference(a: np.ndarray, b: np.ndarray) -> float:
    union = np.count_nonzero(a | b)
    return np.count_nonzero(a ^ b) / union if union else 0.0


# --------------------------------------------------------------------------- simulation


@dataclass
class SimulatedDesigns:
    """Simulations of a list of moulds.

    table: one row per mould: mould_id, n_replicas, n_ok, simulated objective and quantities
      from the replica-mean normalised fields, objective_std (standard deviation of the
      per-replica objective, ddof 1), seconds (solver CPU seconds, summed).
    replicas: one row per (mould_id, replica): seed, status, n_cells, seconds, objective and
      quantities of that replica alone.
    mean_fields: (n, 8, H, W) replica-mean normalised fields (NaN where no replica is ok).
    """

    table: pd.DataFrame
    replicas: pd.DataFrame
    mean_fields: np.ndarray


def _simulate_one(task):
    """One replica (top level, so that a process pool can run it), rasterised on the scene's
    grid as the dataset's fields are."""
    mould, scene, solver, budget, seed = task
    if budget is None:  # the scene's, as the dataset's simulations get it
        budget = default_budget(solver, scene.box)
    result = simulate(mould.polygon, mould.tethers, scene.depth, solver=solver, budget=budget,
                      seed=seed)
    fields = None
    if result.status == "ok":
        fields = cell_fields(result.positions, result.orientations, result.tension, scene.box,
                             scene.pixels, scene.sigma)
    if fields is not None and not np.all(np.isfinite(fields)):
        return None, result.n_cells, "non-finite fields", result.seconds
    return fields, result.n_cells, result.status, result.seconds


def simulate_designs(objective: Objective, moulds: list[Mould], scene,
                     replicas: int | None = None, seed: int = 0,
                     seeds: list[list[int]] | None = None,
                     solver: str | None = None, budget: float | None = None, map_fn=map,
                     progress: bool | None = None) -> SimulatedDesigns:
    """Simulate every mould `replicas` times and score the replica-mean normalised fields.

    replicas: simulations a mould (the caller's: the workflow config's design/replicas is
        their one home), or seeds: explicit simulation seeds per mould (a list of lists;
        default replica_seeds(seed, mould.mould_id, replicas)).
    map_fn: how to run the replicas, e.g. a concurrent.futures executor's `map` (default:
        serially). progress: a tqdm bar on stderr; None = when stderr is a terminal.
    """
    moulds = list(moulds)
    if seeds is None:
        if replicas is None:
            raise ValueError("simulate_designs needs replicas (or explicit seeds)")
        seeds = [replica_seeds(seed, m.mould_id, replicas) for m in moulds]
    elif len(seeds) != len(moulds):
        raise ValueError(f"seeds has {len(seeds)} lists for {len(moulds)} moulds")
    tasks = [(m, scene, solver, budget, int(s)) for m, mould_seeds in zip(moulds, seeds)
             for s in mould_seeds]
    show = sys.stderr.isatty() if progress is None else bool(progress)
    with tqdm(total=len(tasks), desc="confirm (simulations)", unit="sim", disable=not show,
              file=sys.stderr) as bar:
        outcomes = []
        for outcome in map_fn(_simulate_one, tasks):
            outcomes.append(outcome)
            bar.update(1)
    rows, replica_rows, means = [], [], []
    k = 0
    shape = (8, scene.pixels, scene.pixels)
    for mould, mould_seeds in zip(moulds, seeds):
        normalised, seconds = [], 0.0
        for r, s in enumerate(mould_seeds):
            fields, n_cells, status, secs = outcomes[k]
            k += 1
            seconds += secs
            row = {"mould_id": mould.mould_id, "replica": r, "seed": int(s), "status": status,
                   "n_cells": int(n_cells), "seconds": secs}
            if fields is not None:
                normalised.append(normalise(fields.astype(np.float64), n_cells))
                row.update(objective.evaluate(normalised[-1]).iloc[0].to_dict())
            replica_rows.append(row)
        mean = np.mean(normalised, axis=0) if normalised else np.full(shape, np.nan)
        means.append(mean)
        row = {"mould_id": mould.mould_id, "n_replicas": len(mould_seeds),
               "n_ok": len(normalised)}
        row.update(objective.evaluate(mean).iloc[0].to_dict())
        per_replica = [objective.evaluate(f)["objective"].iloc[0] for f in normalised]
        row["objective_std"] = float(np.std(per_replica, ddof=1)) if len(per_replica) > 1 \
            else float("nan")
        row["seconds"] = seconds
        rows.append(row)
    return SimulatedDesigns(pd.DataFrame(rows), pd.DataFrame(replica_rows), np.array(means))


def baseline_objectives(objective: Objective, fields: np.ndarray, n_cells,
                        mould_ids=None) -> pd.DataFrame:
    """The simulated objective of already simulated moulds (e.g. the random test moulds):
    fields (M, 8, H, W) or (M, R, 8, H, W) raw (as stored), n_cells (M,). One row per
    mould: mould_id, n_replicas, objective and quantities of the replica-mean normalised
    fields."""
    fields = np.asarray(fields, dtype=np.float64)
    if fields.ndim == 4:
        fields = fields[:, None]
    if fields.ndim != 5 or fields.shape[2] != 8:
        raise ValueError(f"fields must be (M, 8, H, W) or (M, R, 8, H, W), got {fields.shape}")
    n_cells = np.asarray(n_cells, dtype=np.float64).reshape(-1)
    if n_cells.shape != (fields.shape[0],):
        raise ValueError(f"n_cells has shape {n_cells.shape}, expected ({fields.shape[0]},)")
    mean = normalise(fields, np.repeat(n_cells[:, None], fields.shape[1], axis=1)).mean(axis=1)
    table = objective.evaluate(mean)
    ids = np.arange(len(mean)) if mould_ids is None else np.asarray(mould_ids)
    table.insert(0, "n_replicas", fields.shape[1])
    table.insert(0, "mould_id", ids)
    return table


def dataset_baseline(objective: Objective, ds, split: str = "test") -> pd.DataFrame:
    """The simulated objective of the moulds of one split of a dataset store opened with
    xarray (condor.data.store's layout: per sample fields, n_cells, status, split, and mould /
    replica when the store holds replicas): per mould, the objective of the mean of its ok
    replicas' normalised fields. One row per mould: mould_id, n_replicas, objective and
    quantities."""
    status = np.asarray(ds["status"].values).astype(str)
    keep = (status == "ok") & (np.asarray(ds["split"].values).astype(str) == split)
    index = np.flatnonzero(keep)
    if not index.size:
        raise ValueError(f"the dataset has no simulated ('ok') {split!r} moulds")
    moulds = np.asarray(ds["mould"].values)[index] if "mould" in ds else index
    ids, means, counts = [], [], []
    n_cells = np.asarray(ds["n_cells"].values, dtype=np.float64)
    for mould in np.unique(moulds):
        samples = index[moulds == mould]
        raw = np.asarray(ds["fields"].isel(sample=samples).values, dtype=np.float64)
        means.append(normalise(raw, n_cells[samples]).mean(axis=0))
        ids.append(int(mould))
        counts.append(len(samples))
    table = objective.evaluate(np.stack(means))
    table.insert(0, "n_replicas", counts)
    table.insert(0, "mould_id", ids)
    return table


# --------------------------------------------------------------------------- agreement


def spearman(a, b) -> float:
    """Spearman rank correlation (average ranks for ties); NaN for fewer than 3 pairs."""
    a, b = pd.Series(np.asarray(a, float)), pd.Series(np.asarray(b, float))
    if len(a) < 3 or a.nunique() < 2 or b.nunique() < 2:
        return float("nan")
    return float(np.corrcoef(a.rank().to_numpy(), b.rank().to_numpy())[0, 1])


def _pairs_spearman(pairs: np.ndarray) -> float:
    return spearman(pairs[:, 0], pairs[:, 1])


def agreement(predicted, simulated, n_boot: int = BOOTSTRAP_SAMPLES, seed: int = 0) -> dict:
    """Predicted against simulated objective over n designs: spearman (with a percentile
    bootstrap interval over designs, condor.measures.estimators.bootstrap_interval), pearson, bias =
    mean(predicted - simulated) (with its interval), median_difference, relative_bias =
    median(predicted / simulated - 1) (NaN unless every simulated value is positive: the
    objective may change sign)."""
    p, s = np.asarray(predicted, float), np.asarray(simulated, float)
    keep = np.isfinite(p) & np.isfinite(s)
    p, s = p[keep], s[keep]
    n = len(p)
    out = {"n": n, "pearson": pearson_r(p, s) if n >= 3 else float("nan"),
           "median_difference": float(np.median(p - s)) if n else float("nan"),
           "relative_bias": float(np.median(p / s - 1)) if n and np.all(s > 0) else float("nan")}
    if n >= 3:
        rho = bootstrap_interval(np.stack([p, s], axis=1), _pairs_spearman, n_boot, seed=seed)
        bias = bootstrap_interval(p - s, np.mean, n_boot, seed=seed)
    else:
        rho = (spearman(p, s), float("nan"), float("nan"))
        bias = (float(np.mean(p - s)) if n else float("nan"), float("nan"), float("nan"))
    for name, (value, low, high) in (("spearman", rho), ("bias", bias)):
        out[name], out[f"{name}_low"], out[f"{name}_high"] = value, low, high
    return out


def replica_ceiling(replicas: pd.DataFrame, column: str = "objective") -> float:
    """The noise ceiling of the rank correlation: the mean over replicas r of Spearman between
    replica r's objective and the mean of the other replicas' (designs with all replicas ok).
    What one simulation achieves against the expected organisation; NaN below 2 replicas."""
    wide = replicas.pivot(index="mould_id", columns="replica", values=column).dropna()
    if wide.shape[1] < 2 or len(wide) < 3:
        return float("nan")
    values = wide.to_numpy()
    rhos = [spearman(values[:, r], np.delete(values, r, axis=1).mean(axis=1))
            for r in range(values.shape[1])]
    return float(np.nanmean(rhos))


def confirmation_table(selection: pd.DataFrame, simulated: SimulatedDesigns) -> pd.DataFrame:
    """One row per confirmed design: design, role, predicted_* (the search's columns) and
    simulated_* (replica-mean) objective and quantities, simulated objective_std, n_ok."""
    quantities = [c for c in simulated.table.columns
                  if c not in ("mould_id", "n_replicas", "n_ok", "objective_std", "seconds")]
    predicted = selection.rename(columns={c: f"predicted_{c}" for c in quantities
                                          if c in selection.columns})
    sim = simulated.table.rename(columns={c: f"simulated_{c}" for c in quantities})
    sim = sim.rename(columns={"objective_std": "simulated_objective_std",
                              "seconds": "simulation_seconds"})
    table = predicted.merge(sim, left_on="design", right_on="mould_id", how="left")
    return table.drop(columns=["mould_id"])


def design_summary(table: pd.DataFrame, baseline: pd.DataFrame | None = None,
                   replicas: pd.DataFrame | None = None, n_boot: int = BOOTSTRAP_SAMPLES,
                   seed: int = 0) -> pd.DataFrame:
    """One row: agreement of predicted and simulated objective over the confirmed designs
    (`confirmation_table`), the replicas' noise ceiling of the rank correlation, the best
    confirmed design (by simulated objective) and the top predicted one, and, with a
    baseline (`baseline_objectives`), the best baseline mould and the improvements
    best_simulated - best_baseline and top_predicted_simulated - best_baseline."""
    row = agreement(table["predicted_objective"], table["simulated_objective"], n_boot, seed)
    row["ceiling_spearman"] = replica_ceiling(replicas) if replicas is not None else float("nan")
    simulated = table["simulated_objective"].to_numpy(dtype=float)
    defined = np.isfinite(simulated)
    if defined.any():
        best = int(np.nanargmax(np.where(defined, simulated, -np.inf)))
        row["best_design"] = int(table["design"].iloc[best])
        row["best_simulated"] = float(simulated[best])
        row["best_predicted"] = float(table["predicted_objective"].iloc[best])
    top = int(np.argmax(table["predicted_objective"].to_numpy(dtype=float)))
    row["top_predicted_design"] = int(table["design"].iloc[top])
    row["top_predicted_objective"] = float(table["predicted_objective"].iloc[top])
    row["top_predicted_simulated"] = float(simulated[top])
    if baseline is not None and len(baseline):
        values = baseline["objective"].to_numpy(dtype=float)
        b = int(np.nanargmax(values))
        row["n_baseline"] = int(np.isfinite(values).sum())
        row["best_baseline_mould"] = int(baseline["mould_id"].iloc[b])
        row["best_baseline"] = float(values[b])
        row["median_baseline"] = float(np.nanmedian(values))
        row["improvement"] = row.get("best_simulated", float("nan")) - row["best_baseline"]
        row["improvement_top"] = row["top_predicted_simulated"] - row["best_baseline"]
    return pd.DataFrame([row])


@dataclass
class Confirmation:
    """What `confirm` returns: the per-design table, the one-row summary, the simulations."""

    table: pd.DataFrame
    summary: pd.DataFrame
    simulated: SimulatedDesigns


def confirm_designs(result: SearchResult, scene, n_top: int, n_random: int,
            replicas: int, baseline: pd.DataFrame | None = None,
            solver: str | None = None, budget: float | None = None, seed: int | None = None,
            map_fn=map, progress: bool | None = None) -> Confirmation:
    """select_for_confirmation + simulate_designs + confirmation_table + design_summary.

    Replica seeds follow `replica_seeds(seed, design, r)` with `seed` the search's seed unless
    given (designs are numbered by evaluation, so their ids are distinct).
    """
    seed = result.seed if seed is None else int(seed)
    if scene.pixels != result.pixels or not same_length(scene.box, result.space.box):
        raise ValueError(f"scene {scene.name!r} ({scene.box:g} l0, {scene.pixels} px) is not the "
                         f"search's ({result.space.box:g} l0, {result.pixels} px)")
    selection = select_for_confirmation(result, n_top, n_random, seed)
    moulds = result.moulds(selection["design"])
    simulated = simulate_designs(result.objective, moulds, scene, replicas, seed, solver=solver,
                                 budget=budget, map_fn=map_fn, progress=progress)
    table = confirmation_table(selection, simulated)
    summary = design_summary(table, baseline, simulated.replicas, seed=seed)
    return Confirmation(table, summary, simulated)



def design_table(result: SearchResult, confirmation: Confirmation | None = None,
                 n: int | None = 10) -> pd.DataFrame:
    """The table `condor design` writes: the `n` best distinct designs (all when None) and
    every confirmed design, best predicted first, with predicted_* columns (the search's
    objective, score and quantities), simulated_* columns where confirmed (NaN elsewhere)
    and `role` ("top", "random" or "ranked": listed but not simulated)."""
    ranked = result.ranked(distinct=True)
    chosen = ranked if n is None else ranked.head(n)
    if confirmation is not None:
        chosen = ranked[ranked["design"].isin(set(chosen["design"])
                                              | set(confirmation.table["design"]))]
    quantities = ["objective", "feasible", "violation"] + [q.label for q in
                                                           result.objective.quantities]
    table = chosen.rename(columns={c: f"predicted_{c}" for c in quantities})
    if confirmation is None:
        return table.assign(role="ranked").reset_index(drop=True)
    simulated = confirmation.table[["design", "role"] + [
        c for c in confirmation.table.columns if c.startswith("simulated_")
        or c in ("n_replicas", "n_ok", "simulation_seconds")]]
    table = table.merge(simulated, on="design", how="left")
    table["role"] = table["role"].fillna("ranked")
    return table
