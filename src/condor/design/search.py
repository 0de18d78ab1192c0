"""Search the design space with CMA-ES (`cma`), scoring batches of candidates with the surrogate.

One generation = one batch: decode each vector into a mould (condor.design.space), rasterise
it at the predictor's native size (condor.moulds.mould.input_channels), predict the fields, and
score the normalised fields with the objective:

    score = objective - penalty * constraint violation - repair_weight * repair

(a design whose objective is undefined, e.g. a region without cells, gets the worst score).
The search starts from the best of `n_init` random vectors (standard normal, which also
gives the confirmation a spread of designs), runs CMA-ES from there, and restarts from the
best design so far with the initial step size whenever CMA-ES stops before the budget is
spent. Identical rasters (two vectors repaired to one mould) are predicted once.

Deterministic for a seed: CMA-ES draws from numpy's global generator, so its state is kept
inside the search and swapped in around every call to `cma` (no side effect on the caller's
global state). Progress is a tqdm bar on stderr, shown when stderr is a terminal.
"""

from __future__ import annotations

import contextlib
import hashlib
import math
import sys
import time
from dataclasses import dataclass, field

import cma
import numpy as np
import pandas as pd
from tqdm.auto import tqdm

from condor.moulds.mould import Mould, input_channels
from condor.model.scenes import SIGMA_L0, same_length
from condor.surrogate.answer import spread_draws

from .objectives import Objective
from .space import DesignSpace


# Monte Carlo draws of the objective's spread per searched design (objective_spread), when
# the surrogate has a spread map; predict_designs uses more for the designs it reports.
SEARCH_SPREAD_DRAWS = 16


class DesignSearchError(ValueError):
    """A search that cannot run as asked (a predictor for another box, a bad budget)."""


@dataclass
class SearchResult:
    """Every design the search evaluated, best first.

    designs: one row per evaluated design, sorted by `rank` (1 = best score). Columns:
      design (the evaluation index, also the row of `vectors` and the mould id), rank,
      generation (0 = the random probe), restart, score, objective, feasible, violation,
      repair, n_tethers, shrink, duplicate (same surrogate inputs as a better-ranked design),
      raster (raster_hash of the masks and, for a surrogate that reads them, N_c and the
      lattice channels), one column per objective quantity, and
      predicted_spread (objective_spread, the predicted standard deviation of one
      simulation's objective) when the surrogate has a spread map.
    vectors: (n, dim) design vectors in evaluation order.
    history: one row per generation: evaluations so far, best and median score, CMA sigma.
    """

    objective: Objective
    space: DesignSpace
    seed: int
    pixels: int  # the predictor's grid side: designs were rasterised at it
    designs: pd.DataFrame
    vectors: np.ndarray
    history: pd.DataFrame
    seconds: float  # wall time
    cpu_seconds: float  # CPU time of this process (all its threads): robust on a busy machine
    n_predicted: int  # distinct rasters sent to the predictor

    @property
    def evaluations(self) -> int:
        return len(self.vectors)

    @property
    def designs_per_minute(self) -> float:
        """Per minute of wall time."""
        return 60.0 * self.evaluations / self.seconds if self.seconds > 0 else math.inf

    @property
    def designs_per_cpu_minute(self) -> float:
        """Per CPU minute of this process (all threads): on a machine shared with other jobs
        this is what the search itself costs."""
        return 60.0 * self.evaluations / self.cpu_seconds if self.cpu_seconds > 0 else math.inf

    def mould(self, design: int) -> Mould:
        """The mould of design `design` (its mould_id is the design index; seed the search's)."""
        return self.space.mould(self.vectors[int(design)], mould_id=int(design), seed=self.seed)

    def moulds(self, designs) -> list[Mould]:
        return [self.mould(d) for d in designs]

    def ranked(self, distinct: bool = True, feasible_only: bool = False) -> pd.DataFrame:
        """The designs best first; `distinct` drops repeats of a raster already listed."""
        table = self.designs
        if distinct:
            table = table[~table["duplicate"]]
        if feasible_only:
            table = table[table["feasible"]]
        return table

    def top(self, n: int, distinct: bool = True) -> pd.DataFrame:
        return self.ranked(distinct).head(n)


@contextlib.contextmanager
def _private_global_rng(holder: dict):
    """Run with numpy's global RNG state set to holder["state"]; store it back afterwards and
    restore the caller's state."""
    outer = np.random.get_state()
    try:
        if holder.get("state") is not None:
            np.random.set_state(holder["state"])
        yield
    finally:
        holder["state"] = np.random.get_state()
        np.random.set_state(outer)


def _native_pixels(predictor, space: DesignSpace) -> int:
    pixels = getattr(predictor, "native", None)
    if isinstance(pixels, bool) or not isinstance(pixels, (int, np.integer)) or pixels < 1:
        raise DesignSearchError(f"predictor {predictor!r} has no native grid size (`native`)")
    box = getattr(predictor, "box", None)
    if box is not None and not same_length(box, space.box):
        raise DesignSearchError(f"the predictor was trained on a {float(box):g} l0 box but the "
                                f"design space's box is {space.box:g} l0: use the scene the "
                                "checkpoint was trained on")
    return int(pixels)


def raster_hash(inputs: np.ndarray, extra: dict | None = None) -> str:
    """A short stable hash of what the surrogate reads of one design: its input channels
    (2, H, W) and `extra`, its share of mould_arguments (N_c, lattice channels), so that two
    designs with the same masks but other cells are predicted apart."""
    digest = hashlib.blake2b(np.ascontiguousarray(inputs, dtype=np.uint8).tobytes(),
                             digest_size=8)
    for key in sorted(extra or {}):
        digest.update(key.encode())
        digest.update(np.ascontiguousarray(extra[key], dtype=np.float64).tobytes())
    return digest.hexdigest()


@dataclass
class _Evaluator:
    objective: Objective
    space: DesignSpace
    predictor: object
    pixels: int
    penalty: float
    repair_weight: float
    seed: int
    cache: dict = field(default_factory=dict)  # raster hash -> objective row (dict)
    rows: list = field(default_factory=list)
    vectors: list = field(default_factory=list)
    n_predicted: int = 0

    def __call__(self, vectors: np.ndarray, generation: int, restart: int) -> np.ndarray:
        """Evaluate a batch; return scores (higher is better; -inf where undefined)."""
        decoded = [self.space.decode(x, mould_id=len(self.vectors) + k, seed=self.seed)
                   for k, x in enumerate(vectors)]
        inputs = [input_channels(d.mould, self.pixels) for d in decoded]
        extra = mould_arguments(self.predictor, [d.mould for d in decoded])
        hashes = [raster_hash(channels, {key: value[k] for key, value in extra.items()})
                  for k, channels in enumerate(inputs)]
        new = [i for i, h in enumerate(hashes) if h not in self.cache]
        new = [i for k, i in enumerate(new) if hashes[i] not in {hashes[j] for j in new[:k]}]
        if new:
            prediction = self.predictor(np.stack([inputs[i] for i in new]),
                                        **{key: np.asarray(value)[new]
                                           for key, value in extra.items()})
            normalised = np.asarray(prediction.normalised, dtype=np.float64)
            table = self.objective.evaluate(normalised)
            spread = prediction_spread(prediction)
            if spread is not None:  # a surrogate with a reproducibility map
                sigma_px = SIGMA_L0 * self.pixels / self.space.box
                table["predicted_spread"] = objective_spread(
                    self.objective, normalised, spread, sigma_px, SEARCH_SPREAD_DRAWS, self.seed)
            for i, row in zip(new, table.to_dict("records")):
                self.cache[hashes[i]] = row
            self.n_predicted += len(new)
        scores = np.empty(len(vectors))
        for k, (x, d, h) in enumerate(zip(vectors, decoded, hashes)):
            row = dict(self.cache[h])
            score = row["objective"] - self.penalty * row["violation"] \
                - self.repair_weight * d.repair
            scores[k] = score if np.isfinite(score) else -np.inf
            self.rows.append({"design": len(self.vectors), "generation": generation,
                              "restart": restart, "score": scores[k], **row,
                              "repair": d.repair, "n_tethers": d.mould.n_tethers,
                              "shrink": d.shrink, "raster": h})
            self.vectors.append(np.array(x, dtype=np.float64))
        return scores


def mould_arguments(predictor, moulds) -> dict:
    """What a predictor takes of moulds beyond their masks (Predictor.mould_arguments: the
    exact N_c and lattice channels); nothing for one without it (AnalyticPredictor)."""
    method = getattr(predictor, "mould_arguments", None)
    return method(moulds) if method is not None else {}


def _to_minimise(scores: np.ndarray) -> list[float]:
    """CMA-ES minimises; undefined designs rank below every defined one."""
    finite = scores[np.isfinite(scores)]
    worst = (finite.min() if finite.size else 0.0) - 1.0
    return [float(-s) if np.isfinite(s) else float(-worst) for s in scores]


def search_designs(objective: Objective, space: DesignSpace, predictor, budget: int,
           seed: int = 0, popsize: int | None = None, sigma0: float = 0.5,
           n_init: int | None = None, penalty: float = 10.0, repair_weight: float = 0.05,
           progress: bool | None = None) -> SearchResult:
    """Maximise `objective` over `space` with CMA-ES, scoring with `predictor`.

    predictor: a condor.surrogate.predict.Predictor, or any callable inputs (S, 2, H, W) uint8
        -> object with `.normalised` (S, 8, H, W), with `native` (its grid side in px) and
        optionally `box` (l0; must match the space's box).
    budget: designs evaluated in all (the random probe included).
    popsize: CMA-ES population (one predictor batch); default max(16, 4 + 3 ln dim).
    sigma0: initial CMA-ES step size in gene units (vectors of the probe are N(0, 1)).
    n_init: random probe size; default 2 * popsize (at most half the budget).
    penalty, repair_weight: see the module docstring.
    progress: show a tqdm bar; None = when stderr is a terminal.
    Raises ObjectiveError (regions) and DesignSearchError before evaluating anything.
    """
    pixels = _native_pixels(predictor, space)
    objective.check(pixels, space.max_extent)
    if isinstance(budget, bool) or not isinstance(budget, (int, np.integer)) or budget < 2:
        raise DesignSearchError(f"budget = {budget!r} must be an integer >= 2 (designs)")
    if not (isinstance(sigma0, (int, float)) and sigma0 > 0):
        raise DesignSearchError(f"sigma0 = {sigma0!r} must be positive")
    dim = space.dim
    if dim == 0:
        raise DesignSearchError("the design space has no parameters")
    popsize = int(popsize or max(16, 4 + int(3 * math.log(dim))))
    if popsize < 2:
        raise DesignSearchError(f"popsize = {popsize} must be at least 2")
    n_init = int(min(n_init if n_init is not None else 2 * popsize, budget // 2))
    n_init = max(n_init, 1)
    rng = np.random.default_rng([int(seed), 0xDE5])
    evaluate = _Evaluator(objective, space, predictor, pixels, penalty, repair_weight, int(seed))
    history = []
    show = sys.stderr.isatty() if progress is None else bool(progress)
    start, cpu_start = time.perf_counter(), time.process_time()
    with tqdm(total=budget, desc=f"design {objective.label}", unit="design",
              disable=not show, file=sys.stderr) as bar:
        probe = space.random_vectors(rng, n_init)
        scores = evaluate(probe, generation=0, restart=0)
        all_scores = list(scores)
        bar.update(len(probe))
        history.append(_generation_row(0, 0, len(all_scores), scores, all_scores, float("nan")))
        best = int(np.argmax(np.where(np.isfinite(scores), scores, -np.inf)))
        x0 = probe[best]
        generation, restart = 0, 0
        state: dict = {}
        while len(all_scores) < budget:
            with _private_global_rng(state):
                es = cma.CMAEvolutionStrategy(x0, sigma0, {
                    "popsize": popsize, "seed": int(rng.integers(1, 2**31 - 1)),
                    "verbose": -9, "verb_log": 0, "verb_disp": 0})
            stop = False
            while len(all_scores) < budget and not stop:
                with _private_global_rng(state):
                    candidates = np.asarray(es.ask())[: budget - len(all_scores)]
                generation += 1
                scores = evaluate(candidates, generation, restart)
                all_scores.extend(scores)
                if len(candidates) == popsize:  # a truncated last generation updates nothing
                    with _private_global_rng(state):
                        es.tell(list(candidates), _to_minimise(scores))
                        stop = bool(es.stop())
                history.append(_generation_row(generation, restart, len(all_scores), scores,
                                               all_scores, float(es.sigma)))
                bar.update(len(candidates))
                bar.set_postfix(best=f"{np.max(all_scores):.4g}")
            restart += 1
            x0 = evaluate.vectors[int(np.argmax(all_scores))]
    seconds, cpu_seconds = time.perf_counter() - start, time.process_time() - cpu_start
    designs = _ranked_table(evaluate.rows)
    return SearchResult(objective, space, int(seed), pixels, designs, np.array(evaluate.vectors),
                        pd.DataFrame(history), seconds, cpu_seconds, evaluate.n_predicted)


def _generation_row(generation, restart, evaluations, scores, all_scores, sigma) -> dict:
    finite = np.asarray(scores)[np.isfinite(scores)]
    return {"generation": generation, "restart": restart, "evaluations": evaluations,
            "best_score": float(np.max(all_scores)),
            "generation_best": float(finite.max()) if finite.size else float("nan"),
            "generation_median": float(np.median(finite)) if finite.size else float("nan"),
            "sigma": sigma}


def _ranked_table(rows: list[dict]) -> pd.DataFrame:
    table = pd.DataFrame(rows)
    table = table.sort_values(["score", "design"], ascending=[False, True], kind="mergesort")
    table.insert(1, "rank", np.arange(1, len(table) + 1))
    table["duplicate"] = table["raster"].duplicated(keep="first")
    front = ["design", "rank", "generation", "restart", "score", "objective", "feasible",
             "violation", "repair", "n_tethers", "shrink", "duplicate", "raster"]
    rest = [c for c in table.columns if c not in front]
    return table[front + rest].reset_index(drop=True)


# --------------------------------------------------------------------------- given designs

# Names a reproducibility map may have on a prediction (per pixel and field: how far one
# simulation scatters around the expected field, in the units of `raw`).
SPREAD_ATTRIBUTES = ("spread", "std", "scale", "sigma")


def prediction_spread(prediction) -> np.ndarray | None:
    """The prediction's reproducibility map in normalised units (S, 8, H, W), or None when
    the surrogate has none. `spread_normalised` is used as is; a map in raw units (one of
    SPREAD_ATTRIBUTES) is scaled like the fields, by N_pixels / N_cells."""
    direct = getattr(prediction, "spread_normalised", None)
    if direct is not None:
        return np.asarray(direct, dtype=np.float64)
    raw = np.asarray(prediction.raw)
    for name in SPREAD_ATTRIBUTES:
        spread = getattr(prediction, name, None)
        if spread is not None and np.shape(spread) == raw.shape:
            n_cells = getattr(prediction, "n_cells", None)
            if n_cells is None:
                n_cells = raw[..., 0, :, :].sum(axis=(-2, -1))
            factor = raw.shape[-1] * raw.shape[-2] / np.asarray(n_cells, dtype=np.float64)
            return np.asarray(spread, np.float64) * np.reshape(factor, np.shape(factor) + (1,) * 3)
    return None


# The whole-mould statistics of condor.surrogate.answer whose spreads are calibrated
# (condor.findings' "spread_calibration"), by the objective quantity that equals them.
CALIBRATED_QUANTITIES = {"alignment": "alignment_x", "mean_tension": "mean_tension"}


def calibrated_statistic(objective: Objective) -> str | None:
    """The calibrated whole-mould statistic (condor.surrogate.answer.statistics) that the
    objective is a multiple of, so that its predicted spread takes that statistic's factor;
    None when it is none. Only a single term over the whole box counts: alignment along x
    or y (alignment:y = -alignment_x) and mean_tension; constraints do not change the value."""
    if len(objective.terms) != 1:
        return None
    _, quantity = objective.terms[0]
    if not quantity.region.is_everything or quantity.name not in CALIBRATED_QUANTITIES:
        return None
    if quantity.name == "alignment":
        quarter = 2 * quantity.angle / math.pi  # 0 along x, 1 along y
        if not math.isclose(quarter, round(quarter), abs_tol=1e-9):
            return None
    return CALIBRATED_QUANTITIES[quantity.name]


def objective_spread(objective: Objective, normalised: np.ndarray, spread: np.ndarray,
                     sigma_px: float, draws: int = 64, seed: int = 0) -> np.ndarray:
    """Predicted standard deviation (S,) of one simulation's objective, from a spread map.

    A Monte Carlo estimate: `draws` samples normalised + spread * z, z a unit-variance
    Gaussian noise smoothed by the fields' kernel (sigma_px), independent between fields and
    pixels further apart than the kernel. The map gives no correlations beyond that, so this
    is an approximation; the confirmation's replica spread (simulated_objective_std) checks it.
    """
    values = [objective.evaluate(draw)["objective"].to_numpy()
              for draw in spread_draws(normalised, spread, sigma_px, draws, seed)]
    return np.std(np.array(values), axis=0, ddof=1)


@dataclass
class DesignPrediction:
    """The surrogate's view of given designs.

    table: one row per mould: mould_id, objective, feasible, violation, quantities, and
      predicted_spread (objective_spread; NaN when the surrogate has no spread map).
    inputs (S, 2, H, W) uint8, raw and normalised fields (S, 8, H, W); spread (S, 8, H, W)
    in normalised units, or None.
    """

    table: pd.DataFrame
    inputs: np.ndarray
    raw: np.ndarray
    normalised: np.ndarray
    spread: np.ndarray | None


def predict_designs(objective: Objective, moulds: list[Mould], predictor,
                    sigma_px: float | None = None, draws: int = 64,
                    seed: int = 0, n_cells=None) -> DesignPrediction:
    """Predict the fields and objective of `moulds` (rasterised at the predictor's native
    size). sigma_px: the fields' kernel width in pixels, for objective_spread (default: the
    scene kernel condor.model.scenes.SIGMA_L0 at the moulds' box). n_cells: each mould's cell count
    (its lattice count), for a predictor that takes one."""
    moulds = list(moulds)
    if not moulds:
        raise ValueError("no moulds to predict")
    pixels = getattr(predictor, "native", None)
    if pixels is None:
        raise DesignSearchError(f"predictor {predictor!r} has no native grid size (`native`)")
    inputs = np.stack([input_channels(m, int(pixels)) for m in moulds])
    extra = mould_arguments(predictor, moulds)
    if n_cells is not None:  # a surrogate that conserves cells predicts with each mould's count
        extra["n_cells"] = np.asarray(n_cells, dtype=np.float64)
    prediction = predictor(inputs, **extra)
    normalised = np.asarray(prediction.normalised, dtype=np.float64)
    table = objective.evaluate(normalised)
    table.insert(0, "mould_id", [m.mould_id for m in moulds])
    spread = prediction_spread(prediction)
    if spread is not None:
        if sigma_px is None:
            sigma_px = SIGMA_L0 / (moulds[0].box / int(pixels))
        table["predicted_spread"] = objective_spread(objective, normalised, spread, sigma_px,
                                                     draws, seed)
    else:
        table["predicted_spread"] = np.nan
    return DesignPrediction(table, inputs, np.asarray(prediction.raw), normalised, spread)
