"""A prediction that checks itself by simulation (`condor predict --check N`, and
`check_prediction` in Python).

At the default scene one simulation of a mould costs seconds, so the truth for one user's
mould is cheap: simulate it N times with the product's solver (the dataset's: relaxed_anneal,
its default budget), each replica with its own seed, and score the surrogate's prediction
against the replicas' mean with the finite-replica noise removed (condor.measures.estimators,
as every accuracy figure of the project), beside one simulation's scatter about that mean (the
noise ceiling). The whole-mould statistics are given both ways, under the same names
(condor.surrogate.answer.statistics): predicted, and simulated (mean and standard deviation of
the replicas). `predict` then answers with the best estimate of the prediction and the
replicas' mean, weighed by their measured errors (`best_estimate`, `checked_answer`). The
surrogate's worth is in ranking thousands of moulds; a check is how a user trusts it on theirs
(docs/user_moulds.md).
"""

from __future__ import annotations

import math
import time
from dataclasses import dataclass, replace

import numpy as np
import pandas as pd

from condor.data.fields import FIELD_NAMES, cell_fields, normalise
from condor.data.seeds import replica_seed
from condor.data.statistics import axial_difference, axial_mean_sd
from condor.measures import estimators as est
from condor.model.scenes import Scene
from condor.model.simulate import DEFAULT_SOLVER
from condor.stages.build import simulate_mould
from condor.surrogate.answer import statistics

CHECK_SEED = 0x0C4EC  # the dataset seed of a check's replica streams (no dataset uses it)
MIN_CHECK = 2  # replicas: the noise needs two; three or more for a steadier figure
AUTO = "auto"  # `condor predict`'s default: AUTO_CHECK simulations where they are cheap
AUTO_CHECK = 4  # simulations of an automatic check (experiments/check_verdict)
# an automatic check runs where the mould holds at most this many cells: the default scene's
# moulds (1,000-2,500 cells, 0.3-1 CPU s a simulation) and the tiny scene's, not the paper
# scene's (about 9,300 cells at 800 moves a cell: minutes for a check)
AUTO_CHECK_MAX_CELLS = 4000


@dataclass
class Check:
    """A prediction against N simulations of the same mould: `error` the prediction's field
    error against the replicas' expected fields (noise removed; RMS over the 8 normalised
    fields and the pixels), `ceiling` one simulation's (its scatter about the mean), `table`
    per statistic: predicted, simulated mean and standard deviation, and the difference in
    simulated standard deviations; `failed` the replicas that failed, with their status."""

    n: int
    error: float
    ceiling: float
    table: pd.DataFrame
    failed: list
    seconds: float
    simulated: np.ndarray | None = None  # the replicas' mean raw fields (8, H, W)
    simulated_sd: np.ndarray | None = None  # their standard deviation about it (8, H, W)
    simulated_normalised: np.ndarray | None = None  # the mean of their normalised fields
    best_normalised: np.ndarray | None = None  # the prediction and that mean combined
    weight: float = math.nan  # the prediction's weight in it: density and orientation
    tension_weight: float = math.nan  # and tension (best_estimate, WEIGHT_GROUPS)
    automatic: bool = False  # run by default (`--check auto`), not asked for
    n_cells: float = math.nan  # the simulated mould's cells (each replica's sum P)
    verdict: str | None = None  # what moulds that checked alike were found to be (with_verdict)
    flagged: bool | None = None  # the surrogate may be off: the ratio at or above the threshold

    @property
    def ratio(self) -> float:
        """The prediction's error over one simulation's scatter (above 1: the surrogate is
        farther from the simulations' mean than one simulation is)."""
        return self.error / self.ceiling if self.ceiling > 0 else math.nan

    def attributes(self) -> dict:
        """The check as JSON-ready attributes (a prediction store's `check`)."""
        return {"simulations": self.n, "error": self.error, "ceiling": self.ceiling,
                "ratio": self.ratio, "flagged": self.flagged, "best_weight": self.weight,
                "best_tension_weight": self.tension_weight, "automatic": self.automatic,
                "seconds": self.seconds,
                "seeds": f"condor.data.seeds.replica_seed({CHECK_SEED}, 0, k), k = 0..",
                "failed": [[int(s), str(why)] for s, why in self.failed],
                "statistics": self.table.to_dict(orient="records")}

    def lines(self) -> list[str]:
        ratio = self.ratio
        words = ("closer to the simulations' mean than one simulation is" if ratio < 1 else
                 "farther from the simulations' mean than one simulation is")
        lines = [f"checked by {self.n} simulations ({self.seconds:.0f} s): the prediction lies "
                 f"{self.error:.3g} from their mean fields (noise removed), one simulation "
                 f"{self.ceiling:.3g}: {ratio:.2f}x, {words}",
                 "  statistic         predicted    simulated (mean +- sd)   difference"]
        for row in self.table.itertuples():
            diff = (f"{row.difference_in_sd:+.1f} sd" if np.isfinite(row.difference_in_sd)
                    else "")
            lines.append(f"  {row.statistic:<16} {row.predicted:>10.4g}    "
                         f"{row.simulated:>10.4g} +- {row.simulated_sd:<9.3g}  {diff}")
        if self.failed:
            lines.append(f"  {len(self.failed)} simulation(s) failed: "
                         + "; ".join(f"seed {s}: {why}" for s, why in self.failed))
        if ratio > 1:
            lines.append(f"  the surrogate is off on this mould: the {self.n} simulations' mean "
                         "is the better guide (`simulated` in the .zarr, the row of simulated "
                         "panels in the .png)")
        if self.verdict is not None:
            lines.append(f"  {self.verdict}")
        if math.isfinite(self.weight):
            lines.append("  the answer written (`raw` and `normalised` in the .zarr, the top "
                         "panels of the .png) is the best estimate: the prediction and the "
                         "simulations' mean weighed by their measured errors, "
                         f"{100 * self.weight:.0f}% the prediction's in density and "
                         f"orientation, {100 * self.tension_weight:.0f}% in tension (the "
                         "surrogate's alone: `surrogate_raw`, `surrogate_normalised`)")
        if self.automatic:
            lines.append("  (checked by default where a simulation takes seconds: --check 0 "
                         "skips it, --check N runs N)")
        return lines


# The fields weighed together in the best estimate: the tension apart, the density and the
# orientation tensor together, so that Sx2 + Sy2 + Sz2 = P and the tensor's positivity hold in
# the combination as in each part. T is apart because its normalised values are so small that
# it adds nothing to the 8 fields' error: weighed with them, a prediction close in P and S but
# off in T kept its weight and carried its tension error (experiments/generalisation/checked:
# per-mould mean tension off by up to 23% against 4% weighed apart, the field error the same).
WEIGHT_GROUPS = (("T",), ("P", "Sx2", "Sy2", "Sz2", "SxSy", "SxSz", "SySz"))


def with_verdict(check: Check, finding=None) -> Check:
    """`check` with what moulds that checked alike were found to be: from the `check_verdict`
    finding (condor.findings; experiments/check_verdict: moulds checked by as many simulations
    and scored against 8 others), `flagged` when its ratio is at or above the finding's
    threshold, and `verdict`, a line on how many moulds whose check read in the same bin lay
    above one simulation's scatter. `check` as it is when it ran another number of simulations
    than the finding's (the calibration does not hold for it) or when no finding is shipped."""
    if finding is None:
        from condor.findings import load_findings
        finding = load_findings().get("check_verdict")
    if (finding is None or check.n != int(finding.values["n_check"])
            or not math.isfinite(check.ratio)):
        return check
    threshold, ratio = float(finding.values["threshold"]), check.ratio
    rows = finding.frame()
    row = rows[(rows.ratio_lo <= ratio) & (ratio < rows.ratio_hi)].iloc[0]
    flagged = ratio >= threshold
    band = (f"{row.ratio_lo:.2g}x and above" if not math.isfinite(row.ratio_hi) else
            f"{row.ratio_lo:.2g}-{row.ratio_hi:.2g}x")
    measured = (f"of {int(row.n_moulds)} moulds whose check of {check.n} read {band}, "
                f"{int(row.n_above)} lay above one simulation's scatter by 8 more simulations "
                f"({finding.provenance})")
    if flagged and ratio <= 1:
        measured = (f"the surrogate MAY be off on this mould (flagged at a check of "
                    f"{threshold:.2g}x and above): {measured}")
    return replace(check, verdict=measured, flagged=bool(flagged))


def best_estimate(predicted: np.ndarray, replicas: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """(the prediction and the replicas' mean combined, the prediction's weight per field
    (8,)): w p + (1 - w) m for each group of WEIGHT_GROUPS, with w = (c^2 / N) / (e^2 + c^2 /
    N) the weight that minimises the expected squared error of the two combined when their
    errors are independent: e^2 the prediction's squared error against the replicas' expected
    fields over the group (noise removed, floored at 0), c^2 / N the noise of the mean m of
    the N replicas (one simulation's scatter c^2 over N). A prediction off by as much as the
    mean's noise gets half the weight; one far off, little."""
    reps = np.asarray(replicas, dtype=np.float64)  # (R, 8, H, W)
    p = np.asarray(predicted, dtype=np.float64)
    mean = reps.mean(axis=0)
    best, weights = np.empty_like(p), np.empty(len(FIELD_NAMES))
    for group in WEIGHT_GROUPS:
        f = [FIELD_NAMES.index(name) for name in group]
        error = max(float(est.mse_against_expected(p[None][:, f], reps[None][:, :, f])
                          .corrected[0]), 0.0)
        noise = float(est.noise_ceiling(reps[None][:, :, f])[0]) / len(reps)
        weight = noise / (error + noise) if error + noise > 0 else 0.5
        best[f] = weight * p[f] + (1.0 - weight) * mean[f]
        weights[f] = weight
    return best, weights


def checked_answer(prediction, check):
    """The fields `predict` writes as its answer: after a check, the best estimate
    (`check.best_normalised`, raw = normalised x N_c / N_pixels with N_c the simulated
    mould's cells, the spread the prediction's), else `prediction` itself (a
    condor.surrogate.predict.Prediction either way)."""
    if check is None or check.best_normalised is None:
        return prediction
    best = np.asarray(check.best_normalised, dtype=np.float64)
    n_cells = check.n_cells if math.isfinite(check.n_cells) else float(prediction.n_cells)
    raw = best * n_cells / (best.shape[-2] * best.shape[-1])
    dtype = np.asarray(prediction.raw).dtype
    return replace(prediction, raw=raw.astype(dtype), normalised=best.astype(dtype),
                   n_cells=n_cells)


def check_count(check, n_cells: float, scene: Scene) -> int:
    """How many simulations `predict`'s `check` asks for: an integer as given; AUTO, AUTO_CHECK
    where the mould holds at most AUTO_CHECK_MAX_CELLS cells (`n_cells`) and the scene can be
    simulated (its depth is known), else 0. ValueError names any other value."""
    if isinstance(check, str) and check == AUTO:
        cheap = math.isfinite(scene.depth) and float(n_cells) <= AUTO_CHECK_MAX_CELLS
        return AUTO_CHECK if cheap else 0
    if isinstance(check, bool) or not isinstance(check, (int, np.integer)) or check < 0:
        raise ValueError(f"--check {check!r}: give a number of simulations (0: none) or "
                         f"{AUTO!r}")
    return int(check)


def check_prediction(mould, scene: Scene, predicted_normalised: np.ndarray, n_cells: float,
                     n: int, solver: str | None = None, budget=None, say=None,
                     automatic: bool = False) -> Check:
    """Simulate `mould` (a condor.moulds.mould.Mould placed in `scene`) `n` times with `solver`
    (None: the product's) and score `predicted_normalised` (8, H, W, the scene's grid; its N_c
    `n_cells`) against the replicas (class Check, with_verdict's verdict on it). `say(line)`:
    one line a replica, as each finishes. ValueError when n < MIN_CHECK or fewer than
    MIN_CHECK replicas finish ok."""
    if n < MIN_CHECK:
        raise ValueError(f"--check {n}: the noise of the simulations' mean needs at least "
                         f"{MIN_CHECK} of them (3 or more for a steadier figure)")
    if not math.isfinite(scene.depth):
        raise ValueError("the checkpoint records no mould depth: its scene cannot be simulated")
    solver = solver or DEFAULT_SOLVER
    fields, raws, stats, failed, counts = [], [], [], [], []
    start = time.monotonic()
    for k in range(n):
        seed = replica_seed(CHECK_SEED, 0, k)
        result = simulate_mould(mould, scene, solver, budget, seed)
        if result.status != "ok":
            failed.append((seed, result.status))
            if say is not None:
                say(f"simulation {k + 1}/{n}: failed ({result.status})")
            continue
        raw = cell_fields(result.positions, result.orientations, result.tension, scene.box,
                          scene.pixels, scene.sigma)
        f = normalise(raw, len(result.positions))
        fields.append(f)
        raws.append(raw)
        counts.append(len(result.positions))
        stats.append(statistics(f, len(result.positions), scene.pixel_size))
        if say is not None:
            say(f"simulation {k + 1}/{n}: {result.n_cells} cells, E/cell "
                f"{result.energy_per_cell:.5g}, {result.seconds:.1f} s")
    if len(fields) < MIN_CHECK:
        raise ValueError(f"only {len(fields)} of {n} simulations finished ok: too few to check "
                         "against (" + "; ".join(why for _, why in failed) + ")")
    replicas = np.stack(fields)[None].astype(np.float64)  # (1, R, 8, H, W)
    predicted = np.asarray(predicted_normalised, dtype=np.float64)[None]
    error = est.root_mean(est.mse_against_expected(predicted, replicas).corrected)
    ceiling = est.root_mean(est.noise_ceiling(replicas))
    predicted_stats = statistics(predicted[0], float(n_cells), scene.pixel_size)
    rows = []
    for name in predicted_stats:
        values = np.array([s[name] for s in stats], dtype=np.float64)
        value = float(predicted_stats[name])
        if name == "direction":  # an axis: its mean, spread and difference wrap at 180 degrees
            mean, sd = axial_mean_sd(values)
            difference = axial_difference(value, mean)
        else:
            mean, sd = float(np.mean(values)), float(np.std(values, ddof=1))
            difference = value - mean
        rows.append({"statistic": name, "predicted": value, "simulated": mean,
                     "simulated_sd": sd,
                     "difference_in_sd": difference / sd if sd > 0 else math.nan})
    raws = np.stack(raws).astype(np.float64)
    best, weights = best_estimate(predicted[0], replicas[0])
    check = Check(n=len(fields), error=error, ceiling=ceiling, table=pd.DataFrame(rows),
                  failed=failed, seconds=time.monotonic() - start,
                  simulated=raws.mean(axis=0).astype(np.float32),
                  simulated_sd=raws.std(axis=0, ddof=1).astype(np.float32),
                  simulated_normalised=replicas[0].mean(axis=0).astype(np.float32),
                  best_normalised=best.astype(np.float32),
                  weight=float(weights[FIELD_NAMES.index("P")]),
                  tension_weight=float(weights[FIELD_NAMES.index("T")]), automatic=automatic,
                  n_cells=float(np.mean(counts)))
    return with_verdict(check)

