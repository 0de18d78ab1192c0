"""What `condor predict` answers in numbers: a mould's whole-mould statistics, each with the
predicted spread of one simulation about it, and where the mould sits against the training
moulds (docs/user_moulds.md, "What predict prints").

The statistics (computed by `statistics`, which is condor.data.statistics.mould_summary_statistics,
their one home; docs/fields.md defines each once) are ratios of sums over the normalised
fields (condor.design.objectives), so they read the same at any normalisation:

  alignment      in-plane nematic order of the whole mould along its principal direction:
                 |(sum(Sx2 - Sy2), 2 sum SxSy)| / sum(Sx2 + Sy2), in [0, 1] (0 isotropic, 1
                 every cell along one direction); `direction` is that direction, degrees
                 from x in (-90, 90].
  alignment_x    the same along x (objective alignment:x), in [-1, 1].
  mean_tension   sum T / sum P, the mean cell tension (the paper's T-bar; objective
                 mean_tension), in the fields' units of tension.
  tissue_area    the area where the density exceeds condor.data.statistics.DENSITY_THRESHOLD
                 cells per paper pixel (the paper's N(P > 0.2)), in l0^2 and, given l0_um,
                 mm^2.
  reproducibility  the reproducibility map's root mean square over the tissue pixels and the 8
                 fields (normalised units): how far one simulation scatters about the expected
                 fields; larger is less reproducible (the measure by which the surrogate ranks
                 the test moulds, README "Will this mould give the same tissue twice?").

Spread: the standard deviation of the statistic over draws of fields + spread * z
(`spread_draws`, as condor.design.search.objective_spread: Gaussian noise smoothed by the
fields' kernel), times the statistic's calibration factor (`factors`; `condor predict` reads
them from condor.findings' "spread_calibration" table, experiments/spread_calibration). The
draws alone are the wrong size for a whole-mould statistic, each its own way: the map is a
predictive spread (one simulation's scatter and the surrogate's own error, calibrated as
per-pixel intervals), well above the replicas' scatter in P and T, so the mean tension's and
tissue area's draws scatter too much; and it gives no correlations beyond the kernel, while
orientation domains are larger, so the alignment's scatter too little
(experiments/spread_calibration/README.md measures both).
"""

from __future__ import annotations

import math

import numpy as np
import pandas as pd

from condor.data.fields import FIELD_NAMES
from condor.data.statistics import MOULD_STATISTICS, STATISTIC_UNITS, axial_mean_sd
# one home: data.statistics
from condor.data.statistics import mould_summary_statistics as statistics

_P = FIELD_NAMES.index("P")

# The mask-only path (a picture: lattice channels estimated from its pixels) against the
# mould's geometry, measured on the default run's 100 test moulds (issue 32): the bias of the
# mean tension (median of predicted / simulated - 1, 95% interval) and its r.
MASK_ONLY_MEASURED = ("mean tension biased by -9% [-16, -4] and its r 0.93 over 100 test "
                      "moulds, against +0.5% and r 0.996 from the mould's geometry")

SUMMARY_DRAWS = 64  # Monte Carlo draws of the spread of each statistic
# The statistics with a drawn spread, each with its own calibration factor (tissue_area_mm2
# takes tissue_area's).
SPREAD_STATISTICS = MOULD_STATISTICS  # ("alignment", "direction", "alignment_x", "mean_tension", "tissue_area")


def mould_summary(normalised, n_cells: float, pixel_size: float, spread=None,
                  tissue=None, sigma_px: float | None = None, l0_um: float | None = None,
                  draws: int = SUMMARY_DRAWS, seed: int = 0,
                  factors: dict | None = None, scale: float = 1.0) -> pd.DataFrame:
    """One row per statistic: `statistic`, `value`, `spread` (the predicted standard deviation
    of one simulation's statistic; NaN without a reproducibility map), `unit`.

    normalised (8, H, W); spread (8, H, W) in normalised units or None; tissue (H, W) bool,
    the pixels over which the reproducibility is averaged (default: the mould's, P > 0);
    sigma_px: the fields' kernel width in pixels (for the spread's draws); factors: each of
    SPREAD_STATISTICS' calibration factor (check_spread_factors; `spread_factors` of the
    findings' table), multiplying its drawn spread; None: the draws' spreads as they are.
    scale: the factor a user's drawing was placed at (--fit): tissue_area_mm2 is the drawn
    mould's, tissue_area / scale^2 (tissue_area in l0^2 stays the simulated mould's)."""

    if factors is not None:
        factors = check_spread_factors(factors)
    normalised = np.asarray(normalised, dtype=np.float64)
    values = statistics(normalised, n_cells, pixel_size)
    spreads = dict.fromkeys(values, math.nan)
    if spread is not None and sigma_px is not None:
        drawn = [statistics(d, n_cells, pixel_size)
                 for d in spread_draws(normalised, spread, sigma_px, draws, seed)]
        for name in values:
            if name == "direction":  # an axis: spread of the angle about the mean, wrapped
                spreads[name] = axial_mean_sd([row[name] for row in drawn])[1]
            else:
                spreads[name] = float(np.std([row[name] for row in drawn], ddof=1))
            if factors is not None:
                spreads[name] *= factors[name]
    rows = [(name, values[name], spreads[name], STATISTIC_UNITS[name]) for name in MOULD_STATISTICS]
    if l0_um is not None:
        mm2 = (float(l0_um) / 1000.0 / float(scale)) ** 2
        rows.append(("tissue_area_mm2", values["tissue_area"] * mm2,
                     spreads["tissue_area"] * mm2,
                     "mm^2" + (f", at the drawn size (placed at {scale:.4g}x)"
                               if scale != 1.0 else "")))
    if spread is not None:
        mask = normalised[_P] > 0 if tissue is None else np.asarray(tissue, bool)
        spread = np.asarray(spread, dtype=np.float64)
        rms = float(np.sqrt((spread[:, mask] ** 2).mean())) if mask.any() else math.nan
        rows.append(("reproducibility", rms, math.nan, "RMS spread, normalised"))
    else:
        rows.append(("reproducibility", math.nan, math.nan,
                     "not predicted: this checkpoint has no reproducibility map"))
    return pd.DataFrame(rows, columns=["statistic", "value", "spread", "unit"])


def check_spread_factors(factors) -> dict:
    """`factors` as {statistic: float} for exactly SPREAD_STATISTICS; ValueError naming a
    missing or unknown statistic, or a factor that is not finite and > 0."""
    given = dict(factors)
    missing = [name for name in SPREAD_STATISTICS if name not in given]
    unknown = [name for name in given if name not in SPREAD_STATISTICS]
    if missing or unknown:
        raise ValueError(f"spread factors must name exactly {list(SPREAD_STATISTICS)}: "
                         f"missing {missing}, unknown {unknown}")
    out = {}
    for name in SPREAD_STATISTICS:
        try:
            value = float(given[name])
        except (TypeError, ValueError):
            raise ValueError(f"spread factor of {name} must be a number, got "
                             f"{given[name]!r}") from None
        if not (math.isfinite(value) and value > 0):
            raise ValueError(f"spread factor of {name} must be finite and > 0, got {value}")
        out[name] = value
    return out


def spread_factors(table: pd.DataFrame) -> dict:
    """The calibration factors of a spread-calibration table (condor.findings'
    "spread_calibration": one row per statistic, columns `statistic` and `factor`) as
    mould_summary takes them; ValueError when a statistic is missing, repeated or unknown."""
    repeated = sorted(set(table["statistic"][table["statistic"].duplicated()]))
    if repeated:
        raise ValueError(f"spread calibration table repeats statistics {repeated}")
    return check_spread_factors(dict(zip(table["statistic"], table["factor"])))


def spread_calibration(table: pd.DataFrame, weights: str, provenance: str = "",
                       recipe: str | None = None) -> tuple:
    """(factors, note, warning) for `condor predict`: the factors of a spread-calibration table
    (spread_factors), a line saying where they were fitted (`provenance`: the finding's
    experiment and commit), and a warning when the checkpoint's network, `weights` (its
    condor.surrogate.checkpoint.weights_sha256), is not the one they were fitted for (the
    table's `weights_sha256`) and its recipe, `recipe` (checkpoint.recipe_sha256), is not that
    one's either (the table's `recipe_sha256`, where it has one), else None. Another training
    of the same recipe (the default run on another machine) gets no warning: the note says
    the factors were fitted for a sibling."""
    factors = spread_factors(table)
    fitted = sorted(set(table["weights_sha256"].astype(str)))
    if len(fitted) != 1:
        raise ValueError(f"spread calibration table names {len(fitted)} checkpoints "
                         f"({[s[:12] for s in fitted]}), not one")
    first = table.iloc[0]
    sibling = (weights != fitted[0] and recipe is not None and "recipe_sha256" in table
               and recipe in set(table["recipe_sha256"].astype(str)))
    note = (f"spreads calibrated per statistic on {int(first['n_moulds'])} moulds x "
            f"{int(first['replicas'])} simulations of checkpoint {fitted[0][:12]}"
            + (", another training of this checkpoint's recipe" if sibling else "") + " ("
            + ", ".join(f"{name} x{factors[name]:.2g}" for name in SPREAD_STATISTICS)
            + (f"; {provenance})" if provenance else ")"))
    warning = None
    if weights != fitted[0] and not sibling:
        warning = (f"the statistics' spread factors were fitted for checkpoint {fitted[0][:12]}, "
                   f"not this one ({weights[:12]}): its spreads may be off by another factor; "
                   "experiments/spread_calibration/run.py fits them for it")
    return factors, note, warning


def checkpoint_spread_calibration(finding, state: dict) -> tuple:
    """spread_calibration of the finding "spread_calibration" (condor.findings) for a loaded
    checkpoint `state`: its weights and recipe, the finding's experiment and commit."""
    from condor.surrogate.checkpoint import recipe_sha256, weights_sha256

    return spread_calibration(finding.frame(), weights_sha256(state),
                              f"{finding.experiment} at {finding.commit}", recipe_sha256(state))


NO_DIRECTION = "no clear direction: the alignment lies within its spread of 0"


def direction_is_clear(table: pd.DataFrame) -> bool:
    """False where the mould's alignment is no larger than its spread (a mould whose cells
    point every way, such as a 4-fold symmetric one): its direction is then noise, whatever
    the number says. True without an alignment spread to judge by."""
    rows = table.set_index("statistic")
    if "alignment" not in rows.index:
        return True
    value, spread = rows.loc["alignment", ["value", "spread"]]
    return not (np.isfinite(value) and np.isfinite(spread) and value <= spread)


def format_mould_summary(table: pd.DataFrame) -> str:
    """The summary as lines "  alignment      0.62 +- 0.04  (0..1)"; the direction says when
    it is noise (direction_is_clear)."""
    lines = []
    clear = direction_is_clear(table)
    for row in table.itertuples():
        spread = "" if not np.isfinite(row.spread) else f" +- {row.spread:.3g}"
        value = f"{row.value:.4g}" if np.isfinite(row.value) else "n/a"
        note = f"; {NO_DIRECTION}" if row.statistic == "direction" and not clear else ""
        lines.append(f"  {row.statistic:<16} {value}{spread}  ({row.unit}{note})")
    return "\n".join(lines)


def domain_table(mould, scene) -> pd.DataFrame:
    """Where `mould` sits against the training moulds of `scene`, property by property:
    `property`, `value`, `training` (the generated moulds' range), `inside` (bool). The
    ranges are condor.moulds.domain's (docs/user_moulds.md, "Predicting a mould unlike the training
    moulds")."""
    from condor.moulds.domain import (AREA_WARN, TRAINING_MIN_TETHERS, TRAINING_TETHER_RADIUS,
                                      tethers_without_pixels)

    box = float(scene.box)
    fraction = mould.polygon.area / box ** 2
    xmin, ymin, xmax, ymax = mould.polygon.bounds
    extent = max(xmax - xmin, ymax - ymin) / box
    tethers = np.asarray(mould.tethers, dtype=float).reshape(-1, 3)
    n = len(tethers)
    radii = tethers[:, 2] / box
    low, high = TRAINING_TETHER_RADIUS
    hidden = len(tethers_without_pixels(tethers, box, scene.pixels))
    rows = [
        ("area / box area", f"{fraction:.3g}", f"{scene.area_fraction:g} exactly (within "
         f"+-{AREA_WARN:.0%} tolerated)", abs(fraction / scene.area_fraction - 1) <= AREA_WARN),
        ("larger side / box", f"{extent:.3g}", f"at most {scene.max_extent:g}",
         extent <= scene.max_extent * (1 + 1e-9)),
        ("tethers", f"{n}", f"0 or at least {TRAINING_MIN_TETHERS}",
         n == 0 or n >= TRAINING_MIN_TETHERS),
        ("tether radius / box", f"{radii.min():.3g}-{radii.max():.3g}" if n else "-",
         f"{low:g}-{high:g}", bool(n == 0 or ((radii >= low) & (radii <= high)).all())),
        ("tethers the input grid misses", f"{hidden}", "0", hidden == 0),
    ]
    return pd.DataFrame(rows, columns=["property", "value", "training", "inside"])


def domain_verdict(table: pd.DataFrame, measured: pd.DataFrame | None = None,
                   provenance: str = "") -> str:
    """One line from domain_table: inside, or outside on which counts (with the numbers) and
    what that did to the surrogate where it was measured (`measured_sentence` of `measured`,
    the out-of-domain study's table: condor.findings' "out_of_domain" frame, with
    `provenance`, its experiment and commit; `condor predict` passes them)."""
    outside = table[~table["inside"]]
    if outside.empty:
        return (f"inside the training domain on all {len(table)} counts "
                f"({'; '.join(f'{r.property} {r.value}' for r in table.itertuples())})")
    counts = "; ".join(f"{r.property} {r.value} (training: {r.training})"
                       for r in outside.itertuples())
    words = ("Not measured out of the domain" if measured is None else
             measured_sentence(measured, list(outside["property"]), provenance))
    return (f"OUTSIDE the training domain on {len(outside)} of {len(table)} counts: {counts}. "
            f"{words}. Simulate it (condor simulate) to be sure")


def outside_counts(outside_on) -> tuple[str, ...]:
    """The domain_table properties a row of the out-of-domain table is outside on (its
    `outside_on`: property names joined by ";", empty inside)."""
    text = "" if not isinstance(outside_on, str) else outside_on
    return tuple(p.strip() for p in text.split(";") if p.strip())


def _per_statistic(row, prefix: str) -> dict:
    """A row's per-statistic columns `<prefix><statistic>` (NaN left out), by statistic."""
    values = {f[len(prefix):]: getattr(row, f) for f in row._fields if f.startswith(prefix)
              and f not in (f"{prefix}lo", f"{prefix}hi")}
    return {k: float(v) for k, v in values.items() if isinstance(v, (int, float)) and v == v}


def _measured(row) -> str:
    """One row of the out-of-domain table in words: medians over its moulds, 95% intervals,
    and, when the table holds them, the statistics whose z and spread ratio are extreme."""
    z, ratio = _per_statistic(row, "z_"), _per_statistic(row, "spread_ratio_")
    worst = ""
    if z:
        name = max(z, key=z.get)
        worst = f" (the most, {name}, by {z[name]:.2g})"
    span = ""
    if ratio:
        low, high = min(ratio, key=ratio.get), max(ratio, key=ratio.get)
        span = f" (from {ratio[low]:.2g}x for {low} to {ratio[high]:.2g}x for {high})"
    return (f"{int(row.n_moulds)} {row.description}: the statistics are off by {row.z:.2g} "
            f"[{row.z_lo:.2g}, {row.z_hi:.2g}] of their predicted spreads{worst}, one "
            f"simulation scatters {row.spread_ratio:.2g}x [{row.spread_ratio_lo:.2g}, "
            f"{row.spread_ratio_hi:.2g}] the predicted spread{span}, the 90% intervals hold "
            f"{row.coverage_90:.0%} [{row.coverage_90_lo:.0%}, {row.coverage_90_hi:.0%}] of the "
            "simulated pixels")


def measured_sentence(measured: pd.DataFrame, outside, provenance: str = "") -> str:
    """What the out-of-domain study measured (its table, condor.findings
    OUT_OF_DOMAIN_COLUMNS) for a mould outside the training domain on the domain_table
    properties `outside`: each count's own group of moulds (or "not measured"), a group
    outside on exactly these counts together when there is one, and the moulds inside the
    domain for comparison."""
    rows = list(measured.itertuples())
    wanted = tuple(outside)
    parts = []
    for count in wanted:
        alone = [r for r in rows if outside_counts(r.outside_on) == (count,)]
        parts += [f"{count}: {_measured(r)}" for r in alone] or [f"{count}: not measured"]
    if len(wanted) > 1:
        parts += [f"{' and '.join(wanted)} together: {_measured(r)}" for r in rows
                  if set(outside_counts(r.outside_on)) == set(wanted)]
    inside = [f". Inside it, on {_measured(r)}" for r in rows if r.kind == "inside"]
    where = f"{provenance}; " if provenance else ""
    return (f"Measured on moulds drawn outside it ({where}medians over moulds, 95% "
            f"intervals): {'; '.join(parts)}{''.join(inside)}")


def spread_draws(fields: np.ndarray, spread: np.ndarray, sigma_px: float, draws: int = 64,
                 seed: int = 0):
    """`draws` fields like one simulation's, as condor.design.search.objective_spread draws them: fields + spread
    * z, z a unit-variance Gaussian noise smoothed by the fields' kernel (sigma_px)."""
    from condor.surrogate.baselines import gaussian_blur, gaussian_matrix

    fields = np.asarray(fields, dtype=np.float64)
    spread = np.asarray(spread, dtype=np.float64)
    rng = np.random.default_rng([int(seed), 3])
    n = fields.shape[-1]
    kernel = gaussian_matrix(n, sigma_px)
    unit = float(np.sqrt(np.sum(np.outer(kernel[n // 2], kernel[n // 2]) ** 2)))
    for _ in range(draws):
        yield fields + spread * (gaussian_blur(rng.standard_normal(fields.shape), sigma_px) / unit)
