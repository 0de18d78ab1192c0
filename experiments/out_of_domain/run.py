"""How the surrogate's calibration degrades out of its training domain, measured on moulds drawn
outside it, one count of `condor.surrogate.answer.domain_table` at a time.

    python experiments/out_of_domain/run.py --checkpoint results/models/unet.pt \
        --config config/config.yaml

Groups (KINDS; each mould is kept only when domain_table puts it outside on exactly the
group's counts, so that a group measures one count):

  inside          generated moulds of the dataset's seed, ids beyond n_moulds (never trained on)
  area            generated at scene.area_fraction x (1 -+ AREA_DEVIATION), alternately
  extent          generated with max_extent 1 (kept: larger side beyond scene.max_extent)
  tethers         generated with min_tethers 1 (kept: 1 to 3 tethers)
  tether_radius   generated with tether radii RADIUS_CANVAS canvas widths (kept: a radius
                  beyond the training range)
  hidden_tethers  a generated mould whose tethers become pins of radius HIDDEN_PIN pixels on
                  pixel corners (in the radius range, yet no pixel centre of the input grid)
  dogbone         a 2-post dog-bone drawn from scratch and placed as a user drawing
                  (condor.moulds.place.place_drawing, fit "area"); kept: outside on area and tethers

Every mould is simulated `--replicas` times with the product's default solver
(condor.model.simulate.DEFAULT_SOLVER, the config's budget) at the replica seeds of
condor.data.seeds (the dataset's global seed, the mould's id), and predicted as
`condor predict` predicts a mould file (its exact N_c and lattice channels; the spread map;
condor.surrogate.answer.mould_summary, its statistics' spreads calibrated by the shipped
factors, condor.findings' spread_calibration, unless --uncalibrated). Per mould:

  z             how far the prediction of each whole-mould statistic is from the expected one,
                in predicted spreads, the replica mean's noise removed:
                z_s^2 = ((predicted - replica mean)^2 - s^2 / R) / spread^2, averaged over the
                statistics (alignment, direction, alignment_x, mean_tension, tissue_area), then
                the root (floored at 0);
  spread_ratio  how much one simulation's statistic scatters against the predicted spread:
                sqrt of the mean over the statistics of s^2 / spread^2 (s: the replicas'
                standard deviation, ddof 1); 1 when the spread is right, above 1 too small;
  coverage_90   the fraction of the replicas' pixels (every field, the tissue) inside the
                spread map's 90% intervals (condor.surrogate.calibration.interval_coverage);
  field_error   the normalised fields' error against the replica mean, its noise removed
                (condor.measures.estimators.mse_against_expected), beside the noise ceiling
                (one simulation's error).

Per group: medians over moulds of z, spread_ratio and coverage_90 and the RMS over moulds of
the field error, each with a 95% bootstrap interval over moulds. Simulations are cached under
--cache (one file per replica), so an interrupted run resumes. Writes, under --out:
out_of_domain_<scene>.csv (per group), out_of_domain_moulds_<scene>.csv (per mould, every
statistic), out_of_domain_statistics_<scene>.csv (per group and statistic).
"""

from __future__ import annotations

import argparse
import math
import os
import sys
import time
from dataclasses import replace
from pathlib import Path

os.environ.setdefault("OPENBLAS_NUM_THREADS", "1")
os.environ.setdefault("NUMBA_NUM_THREADS", "1")

import numpy as np  # noqa: E402
import pandas as pd  # noqa: E402
from shapely import affinity  # noqa: E402
from shapely.geometry import Point, box as shapely_box  # noqa: E402

from condor.config import Config  # noqa: E402
from condor.moulds.place import place_drawing  # noqa: E402
from condor.data.fields import normalise  # noqa: E402
from condor.moulds.mould import InvalidMouldError, input_channels  # noqa: E402
from condor.moulds.paper import generate_mould  # noqa: E402
from condor.data.seeds import replica_seed  # noqa: E402
from condor.measures import estimators as est  # noqa: E402
from condor.measures.metrics import normalise_predicted  # noqa: E402
from condor.model.scenes import get_scene, same_length  # noqa: E402
from condor.model.simulate import SimResult, warm_up  # noqa: E402
from condor.stages.build import rasterise_result, simulate_mould  # noqa: E402
from condor.surrogate.answer import (SPREAD_STATISTICS, domain_table, mould_summary,  # noqa: E402
                                     statistics)
from condor.surrogate.calibration import interval_coverage, tissue_pixels  # noqa: E402

KINDS = ("inside", "area", "extent", "tethers", "tether_radius", "hidden_tethers", "dogbone")
# domain_table's property of each count a group is outside on (exactly these)
OUTSIDE = {"inside": (), "area": ("area / box area",), "extent": ("larger side / box",),
           "tethers": ("tethers",), "tether_radius": ("tether radius / box",),
           "hidden_tethers": ("tethers the input grid misses",),
           "dogbone": ("area / box area", "tethers")}
STATISTICS = SPREAD_STATISTICS  # the statistics whose z and spread ratio are measured
ID_STRIDE = 100_000  # mould ids of group k: n_moulds + k * ID_STRIDE + j
MAX_CANDIDATES = 400  # draws per group before giving up on filling it
AREA_DEVIATION = 0.35  # relative, within condor.moulds.domain.AREA_REFUSE (predict refuses beyond)
RADIUS_CANVAS = (0.09, 0.13)  # canvas widths (the training generator's: 0.02-0.065)
HIDDEN_PIN = 0.6  # pixel sides: below the distance from a pixel corner to a centre (0.707)
CACHE = Path.home() / ".cache" / "condor" / "out_of_domain"


# --------------------------------------------------------------------------- the moulds


def _dogbone(rng: np.random.Generator, scene):
    """Two lobes joined by a neck, a post in each lobe, at a random angle; placed as a drawing
    is (fit "area": the training area, capped by the training extent)."""
    distance, neck = rng.uniform(2.2, 3.0), rng.uniform(0.5, 1.0)  # lobe radii
    outline = (Point(-distance / 2, 0).buffer(1.0, quad_segs=16)
               .union(Point(distance / 2, 0).buffer(1.0, quad_segs=16))
               .union(shapely_box(-distance / 2, -neck / 2, distance / 2, neck / 2)))
    angle = rng.uniform(0.0, 180.0)
    outline = affinity.rotate(outline, angle, origin=(0, 0))
    c, s = math.cos(math.radians(angle)), math.sin(math.radians(angle))
    post = rng.uniform(0.15, 0.28)
    tethers = [[-c * distance / 2, -s * distance / 2, post],
               [c * distance / 2, s * distance / 2, post]]
    return place_drawing(outline, tethers, scene, fit="area", source="dog-bone").mould


def _hidden(mould, scene):
    """`mould` with every tether a pin of HIDDEN_PIN pixels on its nearest pixel corner."""
    size = scene.box / scene.pixels
    tethers = np.array(mould.tethers, dtype=float)
    tethers[:, :2] = np.round(tethers[:, :2] / size) * size
    tethers[:, 2] = HIDDEN_PIN * size
    return place_drawing(mould.polygon, tethers, scene, source="pins").mould


def draw_mould(kind: str, mould_id: int, config: Config, scene, index: int):
    """The candidate mould `mould_id` of group `kind` (index: its place among the group's
    candidates), or None when it cannot be drawn."""
    params = config.mould_params()
    kwargs = dict(scene=scene, params=params)
    try:
        if kind == "dogbone":
            return _dogbone(np.random.default_rng([config.seed, mould_id]), scene)
        if kind == "area":
            sign = -1 if index % 2 == 0 else 1  # smaller, larger, smaller, ...
            kwargs["scene"] = replace(scene, area_fraction=scene.area_fraction
                                      * (1 + sign * AREA_DEVIATION))
        elif kind == "extent":
            kwargs["scene"] = replace(scene, max_extent=1.0)
        elif kind == "tethers":
            kwargs["params"] = replace(params, min_tethers=1)
        elif kind == "tether_radius":
            kwargs["params"] = replace(params, tether_radius_min=RADIUS_CANVAS[0],
                                       tether_radius_max=RADIUS_CANVAS[1], max_attempts=200)
        mould = generate_mould(config.seed, mould_id, **kwargs)
        return _hidden(mould, scene) if kind == "hidden_tethers" else mould
    except (RuntimeError, InvalidMouldError):
        return None


def outside_on(mould, scene) -> tuple[str, ...]:
    table = domain_table(mould, scene)
    return tuple(table.loc[~table["inside"], "property"])


def group_moulds(kind: str, count: int, config: Config, scene) -> list:
    """(mould id, mould) of the first `count` candidates outside on exactly OUTSIDE[kind]."""
    base = config.n_moulds + KINDS.index(kind) * ID_STRIDE
    found = []
    for j in range(MAX_CANDIDATES):
        mould = draw_mould(kind, base + j, config, scene, j)
        if mould is not None and outside_on(mould, scene) == OUTSIDE[kind]:
            found.append((base + j, mould))
            if len(found) == count:
                break
    if len(found) < count:
        print(f"{kind}: only {len(found)} of {count} moulds in {MAX_CANDIDATES} candidates",
              file=sys.stderr)
    return found


# --------------------------------------------------------------------------- simulation


def replicas(mould_id: int, mould, config: Config, scene, n: int, cache: Path, log=print):
    """The `n` replicas of a mould: (fields (n_ok, 8, H, W), N_c, statuses), each replica
    read from the cache or simulated and cached."""
    solver, budget = config.solver()
    folder = cache / f"{scene.name}_s{config.seed}_{solver}_{budget:g}"
    folder.mkdir(parents=True, exist_ok=True)
    fields, statuses, n_cells = [], [], None
    for r in range(n):
        path = folder / f"m{mould_id}_r{r}.npz"
        if path.exists():
            result = SimResult.load(path)
        else:
            seed = replica_seed(config.seed, mould_id, r)
            result = simulate_mould(mould, scene, solver, budget, seed)
            tmp = path.with_suffix(".tmp.npz")
            result.save(tmp)
            tmp.replace(path)
            log(f"  mould {mould_id} replica {r}: {result.status}, {result.n_cells} cells, "
                f"{result.seconds:.1f} s")
        statuses.append(result.status)
        if result.status == "ok":
            fields.append(rasterise_result(result, scene))
            n_cells = result.n_cells
    return np.array(fields, dtype=np.float64), n_cells, statuses


# --------------------------------------------------------------------------- measures


def _deviation(name: str, values, predicted):
    """Replica values minus the prediction; a direction's wrapped to (-90, 90] degrees."""
    d = np.asarray(values, dtype=np.float64) - predicted
    return (d + 90.0) % 180.0 - 90.0 if name == "direction" else d


def mould_row(kind, mould_id, mould, scene, predictor, fields, n_cells, statuses,
              factors=None) -> dict:
    """Every measure of one mould (module docstring); factors: the statistics' spread factors
    (mould_summary's; None: the drawn spreads uncalibrated)."""
    from condor.design.search import prediction_spread

    pixel_size = predictor.pixel_size
    inputs = input_channels(mould, predictor.native)
    exact = predictor.mould_arguments([mould])
    prediction = predictor(inputs, n_cells=exact.get("n_cells"), lattice=exact.get("lattice"))
    spread = prediction_spread(prediction)
    if spread is None:
        raise SystemExit(f"{predictor.path} predicts no spread map: nothing to calibrate")
    tissue = tissue_pixels(inputs[None])[0]
    summary = mould_summary(prediction.normalised, float(prediction.n_cells), pixel_size, spread,
                            tissue=tissue, sigma_px=predictor.sigma / pixel_size,
                            factors=factors)
    summary = summary.set_index("statistic")
    table = domain_table(mould, scene).set_index("property")
    tethers = np.asarray(mould.tethers).reshape(-1, 3)
    row = {"kind": kind, "mould": mould_id, "outside_on": "; ".join(OUTSIDE[kind]),
           "area_fraction": mould.polygon.area / scene.box ** 2,
           "extent": float(table.loc["larger side / box", "value"]),
           "n_tethers": len(tethers),
           "max_tether_radius": float(tethers[:, 2].max() / scene.box) if len(tethers) else np.nan,
           "n_cells": n_cells, "replicas": len(fields), "failed": len(statuses) - len(fields)}
    R = len(fields)
    simulated = normalise(fields, np.full(R, float(n_cells)))
    z2, ratio2 = [], []
    for name in STATISTICS:
        predicted, sd = float(summary.loc[name, "value"]), float(summary.loc[name, "spread"])
        values = [statistics(f, n_cells, pixel_size)[name] for f in simulated]
        d = _deviation(name, values, predicted)
        mean, s = float(d.mean()), float(d.std(ddof=1))
        simulated_mean = float(_deviation(name, predicted + mean, 0.0))  # a direction wrapped
        row.update({f"{name}_predicted": predicted, f"{name}_spread": sd,
                    f"{name}_simulated": simulated_mean, f"{name}_simulated_sd": s})
        if np.isfinite(sd) and sd > 0 and np.isfinite(mean) and np.isfinite(s):
            row[f"{name}_z2"] = (mean ** 2 - s ** 2 / R) / sd ** 2
            row[f"{name}_ratio"] = s / sd
            z2.append(row[f"{name}_z2"])
            ratio2.append(row[f"{name}_ratio"] ** 2)
    row["z"] = math.sqrt(max(float(np.mean(z2)), 0.0)) if z2 else np.nan
    row["spread_ratio"] = math.sqrt(float(np.mean(ratio2))) if ratio2 else np.nan
    coverage = interval_coverage(prediction.raw[None], prediction.spread[None], fields[None],
                                 tissue[None])
    row["coverage_50"], row["coverage_90"] = float(coverage[0.5][0]), float(coverage[0.9][0])
    error = est.mse_against_expected(normalise_predicted(prediction.raw)[None], simulated[None])
    row["field_sq_error"] = float(error.corrected[0])
    row["field_sq_error_plain"] = float(error.plain[0])
    row["ceiling_sq"] = float(est.noise_ceiling(simulated[None])[0])
    predicted_rms = math.sqrt(float((spread[:, tissue] ** 2).mean()))
    replica_rms = math.sqrt(float((simulated.var(axis=0, ddof=1)[:, tissue]).mean()))
    row["pixel_spread_ratio"] = replica_rms / predicted_rms
    return row


def _median(values) -> float:
    return float(np.median(values))


def summarise(moulds: pd.DataFrame, seed: int = 0) -> pd.DataFrame:
    """One row per group (KINDS order): n_moulds, replicas, the medians over moulds of z,
    spread_ratio and coverage_90, the field error (RMS over moulds) and the noise ceiling, and
    the median of pixel_spread_ratio (the replicas' RMS standard deviation over the tissue
    against the map's), each with its 95% bootstrap interval over moulds: the columns of
    condor.findings.OUT_OF_DOMAIN_COLUMNS, in order, then pixel_spread_ratio; then, per
    statistic, the medians over moulds of its z and spread ratio (z_<statistic>,
    spread_ratio_<statistic>): its spread can err the other way from the pooled figure."""
    rows = []
    for kind in [k for k in KINDS if k in set(moulds["kind"])]:
        group = moulds[moulds["kind"] == kind]
        row = {"kind": kind, "outside_on": group["outside_on"].iloc[0],
               "description": describe(kind, group), "n_moulds": len(group),
               "replicas": int(group["replicas"].min())}
        for column in ("z", "spread_ratio", "coverage_90"):
            row[column], row[f"{column}_lo"], row[f"{column}_hi"] = \
                est.bootstrap_interval(group[column].dropna().to_numpy(), _median, seed=seed)
        row["field_error"], row["field_error_lo"], row["field_error_hi"] = \
            est.bootstrap_interval(group["field_sq_error"].to_numpy(), seed=seed)
        row["noise_ceiling"] = est.root_mean(group["ceiling_sq"].to_numpy())
        column = "pixel_spread_ratio"
        row[column], row[f"{column}_lo"], row[f"{column}_hi"] = \
            est.bootstrap_interval(group[column].dropna().to_numpy(), _median, seed=seed)
        for name in STATISTICS:  # each statistic's own: the pooled figures mix them
            z2 = group[f"{name}_z2"].dropna().to_numpy()
            row[f"z_{name}"] = float(np.median(np.sqrt(np.maximum(z2, 0)))) if len(z2) else np.nan
            row[f"spread_ratio_{name}"] = float(group[f"{name}_ratio"].median())
        rows.append(row)
    return pd.DataFrame(rows)


def statistic_table(moulds: pd.DataFrame) -> pd.DataFrame:
    """Per group and statistic: the medians over moulds of z and of the spread ratio."""
    rows = []
    for kind in [k for k in KINDS if k in set(moulds["kind"])]:
        group = moulds[moulds["kind"] == kind]
        for name in STATISTICS:
            z2 = group[f"{name}_z2"].dropna()
            rows.append({"kind": kind, "statistic": name, "n_moulds": len(z2),
                         "z": float(np.median(np.sqrt(np.maximum(z2, 0)))) if len(z2) else np.nan,
                         "spread_ratio": float(group[f"{name}_ratio"].median())})
    return pd.DataFrame(rows)


def describe(kind: str, group: pd.DataFrame) -> str:
    """What the group's moulds are, in numbers of the moulds themselves."""
    def span(column, fmt=".2g"):
        return f"{group[column].min():{fmt}}-{group[column].max():{fmt}}"

    if kind == "inside":
        return "generated moulds (ids beyond the training run's)"
    if kind == "area":
        return f"generated moulds of area {span('area_fraction')} of the box"
    if kind == "extent":
        return f"generated moulds whose larger side is {span('extent', '.3g')} of the box"
    if kind == "tethers":
        return f"generated moulds with {span('n_tethers', 'd')} tethers"
    if kind == "tether_radius":
        return (f"generated moulds with tether radii up to {span('max_tether_radius', '.2g')} "
                "of the box")
    if kind == "hidden_tethers":
        return (f"generated moulds whose tethers are pins of {HIDDEN_PIN:g} pixel on pixel "
                "corners")
    return (f"2-post dog-bones drawn and fitted to the window (area {span('area_fraction')} of "
            "the box)")


# --------------------------------------------------------------------------- main


def scene_predictor(checkpoint, scene):
    """condor.surrogate.predict.Predictor of `checkpoint` on one torch thread; SystemExit
    unless it was trained on `scene`'s grid and box."""
    import torch

    from condor.surrogate.predict import Predictor

    torch.set_num_threads(1)
    predictor = Predictor(checkpoint)
    if predictor.native != scene.pixels or predictor.box is None or \
            not same_length(predictor.box, scene.box):
        raise SystemExit(f"{checkpoint} was trained on a {predictor.native} px grid of "
                         f"box {predictor.box}, not the {scene.name!r} scene's")
    return predictor


def main(argv=None) -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--checkpoint", required=True)
    parser.add_argument("--config", nargs="+", default=["config/config.yaml"],
                        help="the run's config files, layered (seed, n_moulds, solver)")
    parser.add_argument("--scene", default=None, help="the scene (default: the config's)")
    parser.add_argument("--inside", type=int, default=8, help="moulds inside the domain")
    parser.add_argument("--per-kind", type=int, default=6, help="moulds per outside group")
    parser.add_argument("--replicas", type=int, default=4)
    parser.add_argument("--kinds", nargs="+", default=list(KINDS), choices=KINDS)
    parser.add_argument("--uncalibrated", action="store_true",
                        help="the statistics' drawn spreads without the shipped calibration "
                             "factors (condor.findings' spread_calibration, which predict uses)")
    parser.add_argument("--cache", default=str(CACHE))
    parser.add_argument("--out", default=str(Path(__file__).resolve().parent))
    args = parser.parse_args(argv)

    config = Config.load(*args.config)
    scene = get_scene(args.scene) if args.scene else config.scene
    predictor = scene_predictor(args.checkpoint, scene)
    factors = None
    if not args.uncalibrated:  # as condor predict calibrates the statistics' spreads
        from condor.findings import load_findings
        from condor.surrogate.answer import spread_calibration
        from condor.surrogate.checkpoint import weights_sha256

        finding = load_findings()["spread_calibration"]
        factors, note, warning = spread_calibration(finding.frame(),
                                                    weights_sha256(predictor.state),
                                                    f"{finding.experiment} at {finding.commit}")
        print(note if warning is None else f"warning: {warning}")
    solver, budget = config.solver()
    print(f"scene {scene.name}, seed {config.seed}, ids beyond {config.n_moulds}, {solver} "
          f"({budget:g}), {args.replicas} replicas, checkpoint {args.checkpoint}")
    warm_up()
    rows, start = [], time.perf_counter()
    for kind in args.kinds:
        count = args.inside if kind == "inside" else args.per_kind
        for mould_id, mould in group_moulds(kind, count, config, scene):
            fields, n_cells, statuses = replicas(mould_id, mould, config, scene, args.replicas,
                                                 Path(args.cache))
            if len(fields) < 2:
                print(f"{kind} mould {mould_id}: {len(fields)} ok replicas, left out")
                continue
            rows.append(mould_row(kind, mould_id, mould, scene, predictor, fields, n_cells,
                                  statuses, factors))
            print(f"{kind} mould {mould_id}: z {rows[-1]['z']:.2f}, spread ratio "
                  f"{rows[-1]['spread_ratio']:.2f}, coverage_90 {rows[-1]['coverage_90']:.2f} "
                  f"({time.perf_counter() - start:.0f} s)", flush=True)
    moulds = pd.DataFrame(rows)
    out = Path(args.out)
    out.mkdir(parents=True, exist_ok=True)
    summary = summarise(moulds)
    moulds.to_csv(out / f"out_of_domain_moulds_{scene.name}.csv", index=False, float_format="%.6g")
    summary.to_csv(out / f"out_of_domain_{scene.name}.csv", index=False, float_format="%.6g")
    statistic_table(moulds).to_csv(out / f"out_of_domain_statistics_{scene.name}.csv",
                                   index=False, float_format="%.4g")
    with pd.option_context("display.width", 200, "display.max_columns", 30):
        print(summary.drop(columns=["description"]).to_string(index=False, float_format="%.3g"))
    print(f"{len(moulds)} moulds in {time.perf_counter() - start:.0f} s; tables in {out}")


if __name__ == "__main__":
    main()
