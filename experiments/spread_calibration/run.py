"""Calibrating the predicted spreads of the whole-mould statistics (condor predict's `+-`),
one factor per statistic, fitted on moulds that are neither trained on nor test moulds and
scored on the run's test moulds.

    python experiments/spread_calibration/run.py --checkpoint results/models/unet.pt \
        --store results/dataset.zarr --config config/config.yaml

Fit moulds: `--fit` moulds generated as the training moulds (the config's seed, ids
n_moulds + FIT_BASE + j, beyond the run's and every out-of-domain group's), kept when
condor.surrogate.answer.domain_table puts them inside the domain on every count, each
simulated `--replicas` times with the product's default solver (the replica seeds of
condor.data.seeds; cached per replica under --cache, so a run resumes). Score moulds: the
store's test moulds with their replicas (at least 2 ok). Both are predicted as
`condor predict` predicts a mould file and measured by the out-of-domain study's
`mould_row` (experiments/out_of_domain/run.py: per statistic the predicted spread, as drawn
with no calibration, and the replicas' standard deviation s, ddof 1, a direction's about the
prediction, wrapped).

Per statistic (condor.surrogate.answer.SPREAD_STATISTICS):

  factor     condor.surrogate.calibration.statistic_spread_ratio on the fit moulds:
             sqrt(mean over moulds of s^2 / spread^2), its 95% bootstrap interval over moulds;
             the calibrated spread is factor x spread;
  ratio      the same measure on the test moulds, before (the drawn spread) and after (the
             calibrated one): 1 when the spread is one simulation's scatter, above 1 too small;
             with the median of s / spread beside it (the out-of-domain study's measure; for
             Gaussian scatter and 4 replicas about 0.89 when the spread is right).

Writes, under --out: spread_calibration_<scene>.csv (the factors, one row per statistic:
`statistic`, `factor`, `factor_lo`, `factor_hi`, `n_moulds`, `replicas`, `weights_sha256`,
`recipe_sha256` (condor.surrogate.checkpoint: another training of the recipe gets no warning);
copied as src/condor/findings/spread_calibration.csv), spread_calibration_score_<scene>.csv
(before and after, fit and test moulds), spread_calibration_moulds_<scene>.csv (every mould).
"""

from __future__ import annotations

import argparse
import importlib.util
import os
import time
from pathlib import Path

os.environ.setdefault("OPENBLAS_NUM_THREADS", "1")
os.environ.setdefault("NUMBA_NUM_THREADS", "1")

import numpy as np  # noqa: E402
import pandas as pd  # noqa: E402

from condor.config import Config  # noqa: E402
from condor.files import write_text  # noqa: E402
from condor.moulds.lab import lab_mould  # noqa: E402
from condor.moulds.mould import Mould  # noqa: E402
from condor.data.dataset import open_dataset, replicated_moulds  # noqa: E402
from condor.model.scenes import get_scene  # noqa: E402
from condor.model.simulate import warm_up  # noqa: E402
from condor.surrogate.answer import SPREAD_STATISTICS  # noqa: E402
from condor.surrogate.calibration import statistic_spread_ratio  # noqa: E402
from condor.surrogate.checkpoint import recipe_sha256, weights_sha256  # noqa: E402


def _out_of_domain():
    """experiments/out_of_domain/run.py as a module (its moulds, replicas and measures)."""
    path = Path(__file__).resolve().parents[1] / "out_of_domain" / "run.py"
    spec = importlib.util.spec_from_file_location("out_of_domain_run", path)
    module = importlib.util.module_from_spec(spec)
    spec.loader.exec_module(module)
    return module


OOD = _out_of_domain()
FIT_BASE = 10 * OOD.ID_STRIDE  # fit mould ids: n_moulds + FIT_BASE + j
CACHE = Path.home() / ".cache" / "condor" / "spread_calibration"


def fit_moulds(count: int, config: Config, scene) -> list:
    """(mould id, mould) of `count` fit moulds beyond n_moulds + FIT_BASE, drawn as the run's
    training moulds are: a share `moulds.lab_fraction` of them from the lab families (the
    config's, in turn: condor.moulds.lab), the rest generated moulds that domain_table puts
    inside the generator's domain; SystemExit when too few are found."""
    base = config.n_moulds + FIT_BASE
    families = config.lab_families() if config.moulds["lab_fraction"] > 0 else []
    n_lab = int(round(config.moulds["lab_fraction"] * count)) if families else 0
    found = [(base + j, lab_mould(config.seed, base + j, families[j % len(families)], scene,
                                  tuple(config.moulds["lab_area"])))
             for j in range(n_lab)]
    for j in range(n_lab, n_lab + OOD.MAX_CANDIDATES):
        if len(found) == count:
            return found
        mould = OOD.draw_mould("inside", base + j, config, scene, j)
        if mould is not None and OOD.outside_on(mould, scene) == ():
            found.append((base + j, mould))
    if len(found) == count:
        return found
    raise SystemExit(f"only {len(found)} of {count} fit moulds inside the domain in "
                     f"{OOD.MAX_CANDIDATES} candidates")


def test_moulds(store):
    """(mould id, mould, raw fields (R, 8, H, W), N_c, statuses) of each test mould of the
    store with at least 2 ok replicas (condor.data.dataset.replicated_moulds)."""
    ds = open_dataset(store)
    box = float(ds.attrs["scene"]["box"])
    kept = set()
    for m, _, (polygon, tethers), fields, n_cells, statuses in replicated_moulds(ds):
        kept.add(m)
        yield m, Mould(box=box, polygon=polygon, tethers=tethers), fields, n_cells, statuses
    left = sorted(set(ds["mould"].values[ds["split"].values.astype(str) == "test"].tolist()) - kept)
    if left:
        print(f"test moulds {left}: fewer than 2 ok replicas, left out")


def score(moulds: pd.DataFrame, factors: dict) -> pd.DataFrame:
    """Per statistic and set (fit, test): n_moulds, the ratio before and after calibration
    with 95% intervals (statistic_spread_ratio), and the medians of s / spread."""
    rows = []
    for part in ("fit", "test"):
        group = moulds[moulds["set"] == part]
        for name in SPREAD_STATISTICS:
            s, spread = group[f"{name}_simulated_sd"], group[f"{name}_spread"]
            row = {"set": part, "statistic": name, "n_moulds": len(group)}
            for when, k in (("before", 1.0), ("after", factors[name])):
                row[f"ratio_{when}"], row[f"ratio_{when}_lo"], row[f"ratio_{when}_hi"] = \
                    statistic_spread_ratio(s, k * spread)
                row[f"median_{when}"] = float(np.median(s / (k * spread)))
            rows.append(row)
    return pd.DataFrame(rows)


def main(argv=None) -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--checkpoint", required=True)
    parser.add_argument("--store", required=True, help="the run's dataset (its test moulds)")
    parser.add_argument("--config", nargs="+", default=["config/config.yaml"],
                        help="the run's config files, layered (seed, n_moulds, solver)")
    parser.add_argument("--scene", default=None, help="the scene (default: the config's)")
    parser.add_argument("--fit", type=int, default=40, help="fit moulds")
    parser.add_argument("--replicas", type=int, default=4, help="replicas of a fit mould")
    parser.add_argument("--cache", default=str(CACHE))
    parser.add_argument("--out", default=str(Path(__file__).resolve().parent))
    args = parser.parse_args(argv)
    if args.fit < 2 or args.replicas < 2:
        raise SystemExit(f"--fit {args.fit} and --replicas {args.replicas} must be at least 2")

    config = Config.load(*args.config)
    scene = get_scene(args.scene) if args.scene else config.scene
    predictor = OOD.scene_predictor(args.checkpoint, scene)
    sha, recipe = weights_sha256(predictor.state), recipe_sha256(predictor.state)
    print(f"scene {scene.name}, seed {config.seed}, {args.fit} fit moulds x {args.replicas} "
          f"replicas, test moulds of {args.store}, checkpoint {args.checkpoint} ({sha[:12]})")
    warm_up()
    rows, start = [], time.perf_counter()
    for mould_id, mould in fit_moulds(args.fit, config, scene):
        fields, n_cells, statuses = OOD.replicas(mould_id, mould, config, scene, args.replicas,
                                                 Path(args.cache))
        if len(fields) < 2:
            print(f"fit mould {mould_id}: {len(fields)} ok replicas, left out")
            continue
        rows.append({"set": "fit", **OOD.mould_row("inside", mould_id, mould, scene, predictor,
                                                   fields, n_cells, statuses)})
        print(f"fit mould {mould_id} ({time.perf_counter() - start:.0f} s)", flush=True)
    for mould_id, mould, fields, n_cells, statuses in test_moulds(args.store):
        rows.append({"set": "test", **OOD.mould_row("inside", mould_id, mould, scene, predictor,
                                                    fields, n_cells, statuses)})
    moulds = pd.DataFrame(rows).drop(columns=["kind", "outside_on"])
    fit = moulds[moulds["set"] == "fit"]
    table = []
    for name in SPREAD_STATISTICS:
        factor, lo, hi = statistic_spread_ratio(fit[f"{name}_simulated_sd"], fit[f"{name}_spread"])
        table.append({"statistic": name, "factor": factor, "factor_lo": lo, "factor_hi": hi,
                      "n_moulds": len(fit), "replicas": int(fit["replicas"].min()),
                      "weights_sha256": sha, "recipe_sha256": recipe})
    table = pd.DataFrame(table)
    scores = score(moulds, dict(zip(table["statistic"], table["factor"])))
    out = Path(args.out)
    out.mkdir(parents=True, exist_ok=True)
    for name, frame, digits in (("", table, "%.6g"), ("_score", scores, "%.4g"),
                                ("_moulds", moulds, "%.6g")):  # each whole or not at all
        write_text(out / f"spread_calibration{name}_{scene.name}.csv",
                   frame.to_csv(index=False, float_format=digits))
    with pd.option_context("display.width", 200, "display.max_columns", 30):
        print(table.drop(columns=["weights_sha256", "recipe_sha256"]).to_string(index=False,
                                                                  float_format="%.3g"))
        print(scores.to_string(index=False, float_format="%.3g"))
    print(f"{len(moulds)} moulds in {time.perf_counter() - start:.0f} s; tables in {out}")


if __name__ == "__main__":
    main()
