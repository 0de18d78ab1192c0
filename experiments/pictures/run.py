"""A picture of a mould against the mould itself: does reading a picture (condor.moulds.
read_picture, then the exact lattice of what was read) predict the mean tension as the
geometry does?

    python experiments/pictures/run.py --checkpoint /tmp/i42_tiny/models/unet.pt \
        --scene tiny --out experiments/pictures

Moulds: the generator's moulds of the dataset's seed (0) with ids from --first (beyond any
training run's n_moulds: never trained on), --moulds of them. Each is simulated --replicas
times with the product's solver (condor.model.simulate.DEFAULT_SOLVER, its budget) at the
replica seeds of condor.data.seeds: the truth is the replicas' mean of each statistic
(condor.surrogate.answer.statistics of each replica's normalised fields).

With --store (a run's dataset.zarr, whose checkpoint --checkpoint is): the run's own test
moulds instead (condor.data.dataset.replicated_moulds; paper and lab, `family` says which),
the truth the mean over their replicas in the store; nothing is simulated, so the
`*_simulated` paths are left out:

    python experiments/pictures/run.py --checkpoint results/models/unet.pt \
        --store results/dataset.zarr --out experiments/pictures

Paths, each predicted as `condor predict` predicts (eval mode, no spread):

  geometry      the mould itself: exact N_c and lattice channels (a JSON, SVG or DXF)
  picture       its own picture, `condor mould --png` (condor.plots.mould_picture, which
                states its box in the PNG), read back with condor.moulds.read_picture
  photo         a photo-like picture of it: 400 px spanning the box, dark mould on a light
                background, grey posts, lighting falling by half across it, Gaussian noise of
                0.08, saved as JPEG (quality 80); read back likewise (the picture spans the box)
  masks         the masks on the checkpoint's grid with N_c and the lattice channels
                estimated from their pixels (the old picture path: condor.data.inputs.
                estimate_lattice_channels)

And, free of any surrogate, the read moulds simulated with the same replica seeds
(`picture_simulated`, `photo_simulated`): what the picture's geometry itself does to the
simulated mean tension.

Per path: the bias of the mean tension (median over moulds of predicted / simulated - 1,
with a 95% percentile bootstrap interval over moulds: condor.measures.estimators), its
Pearson r over moulds, and, for the pictures, the bias against the geometry path (paired)
(`paired`: picture / geometry - 1 through the surrogate, read / true mould - 1 simulated)
and how far the read geometry is from the true one (area, post radii). Writes
pictures_<scene>.csv (per path) and pictures_moulds_<scene>.csv (per mould and path).
"""

from __future__ import annotations

import argparse
import sys
import tempfile
import time
from pathlib import Path

import numpy as np
import pandas as pd
from PIL import Image

from condor import plots
from condor.data.dataset import open_dataset, replicated_moulds
from condor.data.fields import cell_fields, normalise
from condor.data.seeds import replica_seed
from condor.measures import estimators as est
from condor.model.scenes import get_scene
from condor.model.simulate import DEFAULT_SOLVER
from condor.moulds.mould import Mould, input_channels
from condor.moulds.read import load_placement
from condor.moulds.sources import make_mould
from condor.stages.build import simulate_mould
from condor.surrogate.answer import statistics
from condor.surrogate.predict import Predictor

SEED = 0
PATHS = ("geometry", "picture", "photo", "masks", "picture_simulated", "photo_simulated")


def photo_like(mould, path: Path, pixels: int = 400, seed: int = 0) -> None:
    """A photo-like picture of `mould` spanning its box: dark mould (0.15), light background
    (0.9), grey posts (0.5), lighting falling to half across it, noise 0.08, JPEG."""
    cover = input_channels(mould, pixels, supersample=4)  # [channel, y, x], y up
    image = 0.9 * (1 - cover[0] - cover[1]) + 0.15 * cover[0] + 0.5 * cover[1]
    image = image[::-1]
    yy, xx = np.mgrid[0:pixels, 0:pixels] / pixels
    image = image * (1.0 - 0.35 * xx - 0.15 * yy)
    image = image + 0.08 * np.random.default_rng([seed, 7]).standard_normal(image.shape)
    Image.fromarray((np.clip(image, 0, 1) * 255).astype(np.uint8)).save(path, quality=80)


def simulated(mould, scene, replicas: int, mould_id: int | None = None) -> tuple[float, float, int]:
    """(mean over replicas of the mean tension, its standard deviation, replicas ok); the
    replica seeds of `mould_id` (default: the mould's)."""
    values = []
    mould_id = mould.mould_id if mould_id is None else mould_id
    for r in range(replicas):
        result = simulate_mould(mould, scene, DEFAULT_SOLVER, None,
                                replica_seed(SEED, mould_id, r))
        if result.status != "ok":
            continue
        raw = cell_fields(result.positions, result.orientations, result.tension, scene.box,
                          scene.pixels, scene.sigma)
        f = normalise(raw, len(result.positions))
        values.append(statistics(f, len(result.positions), scene.pixel_size)["mean_tension"])
    return float(np.mean(values)), float(np.std(values, ddof=1)), len(values)


def store_moulds(store, scene):
    """(mould, mean tension of its replicas, their sd, replicas ok) of each test mould of the
    run's store (at least 2 ok replicas), its family kept on the mould."""
    ds = open_dataset(store)
    for m, family, (polygon, tethers), fields, n_cells, _ in replicated_moulds(ds):
        values = [statistics(normalise(f, n_cells), n_cells, scene.pixel_size)["mean_tension"]
                  for f in fields]
        mould = Mould(box=scene.box, polygon=polygon, tethers=tethers, mould_id=m,
                      family=family)
        yield mould, float(np.mean(values)), float(np.std(values, ddof=1)), len(values)


def generated_moulds(args, scene):
    """(mould, mean tension of its replicas, their sd, replicas ok) of --moulds new generated
    moulds, each simulated --replicas times."""
    for k in range(args.moulds):
        mould = make_mould(scene, SEED, args.first + k)
        yield (mould, *simulated(mould, scene, args.replicas))


def predicted(predictor, mould, scene, pixel_size) -> float:
    inputs = input_channels(mould, predictor.native)
    extra = predictor.mould_arguments([mould])
    prediction = predictor(inputs[None], n_cells=extra["n_cells"], lattice=extra.get("lattice"))
    return statistics(prediction.normalised[0], float(prediction.n_cells[0]),
                      pixel_size)["mean_tension"]


def predicted_from_masks(predictor, mould, pixel_size) -> float:
    inputs = input_channels(mould, predictor.native)[None]
    lattice = predictor.estimate_lattice(inputs) if predictor.needs_lattice else None
    prediction = predictor(inputs, lattice=lattice)
    return statistics(prediction.normalised[0], float(prediction.n_cells[0]),
                      pixel_size)["mean_tension"]


def geometry_error(true, read) -> dict:
    radii_true = np.sort(np.asarray(true.tethers)[:, 2])
    radii_read = np.sort(np.asarray(read.tethers)[:, 2])
    same = len(radii_true) == len(radii_read)
    return {"area_error": read.polygon.area / true.polygon.area - 1,
            "posts_true": len(radii_true), "posts_read": len(radii_read),
            "radius_error": float(np.max(np.abs(radii_read / radii_true - 1)))
            if same and len(radii_true) else (np.nan if same else np.inf)}


def main(argv=None) -> None:
    parser = argparse.ArgumentParser(description=__doc__.split("\n")[0])
    parser.add_argument("--checkpoint", required=True)
    parser.add_argument("--scene", default="tiny")
    parser.add_argument("--moulds", type=int, default=40)
    parser.add_argument("--first", type=int, default=10_000)
    parser.add_argument("--replicas", type=int, default=4)
    parser.add_argument("--store", default=None,
                        help="a run's dataset.zarr: its test moulds and replicas instead")
    parser.add_argument("--out", default=str(Path(__file__).parent))
    args = parser.parse_args(argv)
    scene = get_scene(open_dataset(args.store).attrs["scene"]["name"] if args.store
                      else args.scene)
    predictor = Predictor(args.checkpoint, device="cpu")
    pixel_size = predictor.pixel_size
    rows = []
    start = time.time()
    source = store_moulds(args.store, scene) if args.store else generated_moulds(args, scene)
    with tempfile.TemporaryDirectory() as folder:
        for k, (mould, truth, spread, n_ok) in enumerate(source):
            picture, photo = Path(folder) / f"m{k}.png", Path(folder) / f"m{k}.jpg"
            plots.mould_picture(mould, picture)
            photo_like(mould, photo, seed=k)
            row = {"mould": mould.mould_id, "family": mould.family or "paper",
                   "n_tethers": mould.n_tethers, "replicas_ok": n_ok,
                   "simulated": truth, "simulated_sd": spread,
                   "geometry": predicted(predictor, mould, scene, pixel_size),
                   "masks": predicted_from_masks(predictor, mould, pixel_size)}
            for name, path in (("picture", picture), ("photo", photo)):
                try:
                    read = load_placement(path, scene).mould
                except ValueError as error:  # a picture that cannot be read: counted, not hidden
                    row[name] = np.nan
                    row[f"{name}_error"] = str(error)
                    continue
                row[name] = predicted(predictor, read, scene, pixel_size)
                if not args.store:
                    row[f"{name}_simulated"] = simulated(read, scene, args.replicas,
                                                         mould.mould_id)[0]
                row.update({f"{name}_{key}": value
                            for key, value in geometry_error(mould, read).items()})
            rows.append(row)
            print(f"mould {k + 1} ({time.time() - start:.0f} s): simulated "
                  f"{truth:.4g}, geometry {row['geometry']:.4g}, picture {row['picture']:.4g}, "
                  f"photo {row['photo']:.4g}, masks {row['masks']:.4g}", file=sys.stderr)
    moulds = pd.DataFrame(rows)
    summary = []
    groups = [("all", moulds)]
    if args.store:
        paper = moulds["family"] == "paper"
        groups += [("paper", moulds[paper]), ("lab", moulds[~paper])]
    for group, part in groups:
        summary += path_rows(part, group)
    summary = pd.DataFrame(summary)
    out = Path(args.out)
    out.mkdir(parents=True, exist_ok=True)
    tag = f"{scene.name}_store" if args.store else scene.name
    summary.to_csv(out / f"pictures_{tag}.csv", index=False)
    moulds.to_csv(out / f"pictures_moulds_{tag}.csv", index=False)
    with pd.option_context("display.width", 200, "display.max_columns", 30):
        print(summary.to_string(index=False))


def path_rows(moulds: pd.DataFrame, group: str) -> list[dict]:
    """One row a path (of PATHS that `moulds` holds) for the moulds of `group`."""
    summary = []
    for name in PATHS:
        if name not in moulds:
            continue
        ok = moulds[name].notna().to_numpy()
        ratio = (moulds[name] / moulds["simulated"] - 1).to_numpy()[ok]
        bias, lo, hi = est.bootstrap_interval(ratio, np.median)
        r = float(np.corrcoef(moulds[name][ok], moulds["simulated"][ok])[0, 1])
        row = {"moulds_of": group, "path": name, "moulds": int(ok.sum()),
               "unread": int((~ok).sum()),
               "bias": bias, "bias_lo": lo, "bias_hi": hi, "r": r}
        if name in ("picture", "photo", "masks", "picture_simulated", "photo_simulated"):
            against = "simulated" if name.endswith("_simulated") else "geometry"
            paired = (moulds[name] / moulds[against] - 1).to_numpy()[ok]
            row.update(zip(("paired", "paired_lo", "paired_hi"),
                           est.bootstrap_interval(paired, np.median)))
            row["paired_against"] = against
        if name in ("picture", "photo"):
            row["area_error_max"] = float(np.nanmax(np.abs(moulds[f"{name}_area_error"])))
            row["radius_error_max"] = float(np.nanmax(moulds[f"{name}_radius_error"]))
            row["posts_missed"] = int((moulds[f"{name}_posts_true"]
                                       != moulds[f"{name}_posts_read"]).sum())
        summary.append(row)
    return summary


if __name__ == "__main__":
    main()
