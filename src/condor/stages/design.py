"""The design stage: search moulds with the surrogate, confirm the best and a random sample by
simulation with replicas, and hand over drawings (condor.design, docs/design.md).

`design(...)` writes into `out_dir`:
- designs.csv: the ranked designs with predicted and (where confirmed) simulated objectives;
- summary.csv: Spearman rho and bias between predicted and simulated objective (intervals),
  the best confirmed design against the best mould of the dataset's test split;
- search_history.csv;
- design_NN.json (the mould, as `condor simulate` reads it), design_NN.svg and design_NN.dxf
  (drawings with dimensions in l0 and, given `l0_um`, in mm), for the best `n_top` designs:
  the confirmed ones, distinct by condor.design.confirm's rule (DISTINCT_FOOTPRINT);
- design_NN_drawn.json, .svg, .dxf: the same at the size of your drawing, when your mould
  was placed scaled (--fit): scaled back by 1 / fit_scale, in mm given `l0_um` (the scale in
  each drawing's title, in summary.csv and in condor_design.json);
- predictions.zarr: their predicted fields (raw, normalised) and reproducibility maps;
- your_moulds.csv: a user's own moulds, predicted and simulated the same way, when given;
- figures/: predicted against simulated objective, the search's progress, the designs;
- condor_design.json: design's mark, naming the command and every file it writes.

`force` replaces only such a folder, and only the files its mark names: a Zarr store, a
results folder of the workflow, the current directory or one above it, and a folder holding
any file design did not write are refused, and nothing in them is touched. Everything is
written into a temporary folder beside `out_dir` first and moved in when all of it is
written: a run that fails (a bad input, a full disk) leaves `out_dir` as it was.
"""

from __future__ import annotations

import json
import logging
import os
from contextlib import contextmanager
from dataclasses import replace
from pathlib import Path

import numpy as np
import pandas as pd
import xarray as xr

from condor import plots
from condor.design import (confirm_designs, constrained_space, dataset_baseline, default_space,
                           design_table,
                           parse_objective, predict_designs, search_designs, simulate_designs)
from condor.design.search import calibrated_statistic
from condor.design.confirm import DISTINCT_FOOTPRINT, DISTINCT_POSTS
from condor.moulds.write import drawn_mould, write_dxf, write_svg
from condor.data.fields import FIELD_NAMES
from condor.files import as_write_error, remove, temporary_path
from condor.folder import LOCK_NAME, store_path
from condor.model.lattice import build_lattice
from condor.moulds.mould import save_json
from condor.model.scenes import Scene, same_length
from condor.data.store import CHANNELS, open_store, quiet_zarr
from condor.surrogate.predict import Predictor

log = logging.getLogger("condor")
YOUR_MOULD_IDS = 10**6  # mould ids (hence replica seeds) of a user's moulds: none of the search's


MARK = "condor_design.json"  # what design writes first into its folder: the files it owns
WRITER = "condor design"
FIGURES = ("confirmation.png", "search_history.png", "designs.png")


class DesignOutputError(ValueError):
    """The design's output folder cannot be written as asked."""


YOURS_MIN_REPLICAS = 6  # your moulds are simulated at least this often: their +- is a measured sd


def own_files(n_top: int, drawn: bool = False) -> list[str]:
    """Every path (relative to the folder) that design writes with `n_top` designs (and, with
    `drawn`, their versions at your drawing's size), besides its mark; predictions.zarr is a
    folder."""
    kinds = ("", "_drawn") if drawn else ("",)
    return ["designs.csv", "summary.csv", "search_history.csv", "your_moulds.csv",
            "predictions.zarr",
            *(f"design_{k:02d}{kind}.{ext}" for k in range(1, n_top + 1) for kind in kinds
              for ext in ("json", "svg", "dxf")),
            *(f"figures/{name}" for name in FIGURES)]


def _files(folder: Path) -> list[str]:
    """The files under `folder` (relative paths; predictions.zarr and symbolic links as one
    entry each, never followed); empty folders are not listed."""
    found = []
    for entry in sorted(folder.iterdir()):
        if entry.is_dir() and not entry.is_symlink() and entry.name != "predictions.zarr":
            found += [f"{entry.name}/{name}" for name in _files(entry)]
        else:
            found.append(entry.name)
    return found


def _owned(out_dir: Path) -> list[str] | None:
    """The files design's mark in `out_dir` names, None without a readable mark."""
    try:
        mark = json.loads((out_dir / MARK).read_text())
    except (OSError, ValueError):
        return None
    if not isinstance(mark, dict) or mark.get("written_by") != WRITER:
        return None
    return [str(name) for name in mark.get("files", [])]


def _not_replaceable(out_dir: Path, files: list[str]) -> str | None:
    """Why design may not replace the folder `out_dir` holding `files`, or None."""
    here, where = Path.cwd().resolve(), out_dir.resolve()
    if where == here:
        return "is the current directory"
    if where in here.parents:
        return "is a folder above the current directory"
    if any((out_dir / name).exists() for name in ("zarr.json", ".zgroup", ".zarray")):
        return "is a Zarr store"
    if any((out_dir / name).exists() for name in (LOCK_NAME, "dataset.json")) or \
            store_path(out_dir).exists():
        return "is a results folder of the workflow"
    owned = _owned(out_dir)
    if owned is None:
        return f"holds files that {WRITER} did not write (it has no {MARK}): {_some(files)}"
    foreign = [name for name in files if name != MARK and name not in owned]
    if foreign:
        return f"holds files that {WRITER} did not write: {_some(foreign)}"
    return None


def _some(names: list[str], n: int = 3) -> str:
    return ", ".join(names[:n]) + (f" and {len(names) - n} more" if len(names) > n else "")


def _out_dir(out_dir, force: bool) -> Path:
    """The output folder, checked: absent, empty of files, or (with `force`) holding an
    earlier design's files alone (module docstring); anything else refuses."""
    out_dir = Path(out_dir)
    if out_dir.exists() and not out_dir.is_dir():
        raise DesignOutputError(f"--out {str(out_dir)!r} is a file; give a folder")
    files = _files(out_dir) if out_dir.is_dir() else []
    if files:
        reason = _not_replaceable(out_dir, files)
        if reason:
            raise DesignOutputError(f"--out {str(out_dir)!r} {reason}; design replaces only "
                                    "a folder it wrote itself: choose another --out")
        if not force:
            raise DesignOutputError(f"--out {str(out_dir)!r} holds an earlier design; pass "
                                    "--force to replace it")
    return out_dir


@contextmanager
def _design_folder(out_dir, force: bool, n_top: int, scale: dict | None = None):
    """A temporary folder beside `out_dir` to write the design into (marked with the files
    this run writes, and the drawing's `scale`); when the block ends without an error, an earlier design's files are
    removed from `out_dir` (only those its mark names) and the new ones moved in, else the
    temporary folder is removed and `out_dir` is as it was (condor.files)."""
    out_dir = _out_dir(out_dir, force)
    work = temporary_path(out_dir.resolve())
    remove(work)
    try:
        (work / "figures").mkdir(parents=True)
        drawn = scale is not None and scale["fit_scale"] != 1.0
        (work / MARK).write_text(json.dumps({"written_by": WRITER,
                                             "files": own_files(n_top, drawn),
                                             **({"scale": scale} if scale else {})},
                                            indent=1) + "\n")
        yield work
        if not out_dir.exists():
            os.replace(work, out_dir)
            return
        for name in [*(_owned(out_dir) or []), MARK]:
            remove(out_dir / name)
        for entry in sorted(work.iterdir()):
            target = out_dir / entry.name
            if entry.name == "figures" and target.is_dir():  # made by Snakemake, or left empty
                for figure in sorted(entry.iterdir()):
                    os.replace(figure, target / figure.name)
            else:
                os.replace(entry, target)
    except BaseException as err:
        failed = as_write_error(err, work, out_dir)
        if failed is not None:
            raise failed from err
        raise
    finally:
        remove(work)


def design(scene: Scene, checkpoint, out_dir, objective: str, *, budget: int, seed: int,
           n_top: int, n_random: int, replicas: int, store=None, l0_um: float | None = None,
           solver: str | None = None, your_moulds=(), force: bool = False,
           progress: bool | None = None, keep=(), say=None,
           fit_scale: float = 1.0) -> pd.DataFrame:
    """Search, confirm and hand over (module docstring); returns the summary row. The
    numbers have one home, the workflow config's `design:` defaults (the packaged schema),
    which the workflow and the CLI pass. Every
    error a user can cause (objective, scene, budget, a bad mould file) is raised before the
    search runs. `your_moulds`: condor.moulds.mould.Mould objects (a user's own designs) scored
    the same way, predicted and simulated, into your_moulds.csv: the designs to beat, and drawn
    first in figures/designs.png. `keep`: "footprint" and/or "posts" of the first of them
    constrain the search (condor.design.constrained_space). `say`: called with one line as
    each phase starts (progress where no bar shows, e.g. not on a terminal). `fit_scale`: the
    factor your (first) mould's drawing was placed at (condor.moulds.place.Placement.scale):
    the designs are also written at your drawing's size (design_NN_drawn.*), and the scale is
    recorded in summary.csv and condor_design.json. Your moulds are simulated with at least
    YOURS_MIN_REPLICAS replicas."""
    say = say or (lambda line: log.info("%s", line))
    predictor = Predictor(checkpoint, device="cpu")
    if predictor.native != scene.pixels or predictor.box is None or \
            not same_length(predictor.box, scene.box):
        raise DesignOutputError(f"checkpoint {str(checkpoint)!r} was trained on {predictor.native} "
                                f"px of box {predictor.box} l0, not the {scene.name!r} scene")
    parsed = parse_objective(objective, pixels=scene.pixels, max_extent=scene.max_extent)
    if keep and not your_moulds:
        raise DesignOutputError(f"--keep {','.join(keep)} needs your mould (--mould)")
    space = constrained_space(scene, your_moulds[0], keep, parsed) if keep else \
        default_space(scene, parsed)
    scale = {"fit_scale": float(fit_scale), "drawn_scale": 1.0 / float(fit_scale),
             "l0_um": None if l0_um is None else float(l0_um),
             "means": "the designs were searched and simulated at the placed size; "
                      "design_NN_drawn.* are at your drawing's size, 1 / fit_scale times it"}
    with _design_folder(out_dir, force, n_top, scale) as out:
        return _search_confirm_draw(out, scene, predictor, parsed, objective, space,
                                    budget=budget, seed=seed, n_top=n_top, n_random=n_random,
                                    replicas=replicas, store=store, l0_um=l0_um, solver=solver,
                                    your_moulds=your_moulds, progress=progress, keep=keep,
                                    say=say, fit_scale=fit_scale)


def _search_confirm_draw(out: Path, scene: Scene, predictor, parsed, objective: str, space, *,
                         budget: int, seed: int, n_top: int, n_random: int, replicas: int, store,
                         l0_um, solver, your_moulds, progress, keep, say,
                         fit_scale: float) -> pd.DataFrame:
    """design's work once its inputs are checked, written into the folder `out`."""
    spread_factor, spread_note = objective_spread_factor(parsed, predictor)
    say(spread_note)
    yours = None
    if your_moulds:
        yours_replicas = max(replicas, YOURS_MIN_REPLICAS)
        say(f"phase 1/4: your {len(your_moulds)} mould(s): predicting and simulating "
            f"{yours_replicas} replicas each (at least {YOURS_MIN_REPLICAS}: their +- is "
            "measured)")
        table, yours = _score_your_moulds(parsed, list(your_moulds), scene, predictor,
                                          yours_replicas, seed, solver, progress)
        table["predicted_spread"] *= spread_factor
        table["fit_scale"] = float(fit_scale)
        table.to_csv(out / "your_moulds.csv", index=False)
    constraint = f", keeping your mould's {' and '.join(keep)}" if keep else ""
    say(f"phase 2/4: searching {budget} designs with the surrogate{constraint}")
    result = search_designs(parsed, space, predictor, budget=budget, seed=seed, progress=progress)
    if "predicted_spread" in result.designs:
        result.designs["predicted_spread"] *= spread_factor
    log.info("search: %d designs, %.0f per CPU-minute; best predicted %s = %.4g",
             result.evaluations, result.designs_per_cpu_minute, objective,
             result.ranked().iloc[0]["objective"])
    baseline = dataset_baseline(parsed, open_store(store), split="test") if store else None
    say(f"phase 3/4: confirming the best {n_top} and {n_random} random designs by "
        f"simulation, {replicas} replica(s) each")
    confirmation = confirm_designs(result, scene, n_top=n_top, n_random=n_random, replicas=replicas,
                           baseline=baseline, solver=solver, progress=progress)
    top = confirmation.table[confirmation.table["role"] == "top"]
    if len(top) < n_top:
        say(f"only {len(top)} of the {n_top} best designs are distinct by the rule (footprints "
            f"differing in {DISTINCT_FOOTPRINT:.0%} of their pixels, or posts in "
            f"{DISTINCT_POSTS:.0%}): {len(top)} confirmed and drawn")
    table = design_table(result, confirmation, n=max(n_top, 10))
    table.to_csv(out / "designs.csv", index=False)
    confirmation.summary["spread_factor"] = spread_factor
    confirmation.summary["n_top_distinct"] = len(top)
    confirmation.summary["fit_scale"] = float(fit_scale)
    confirmation.summary["l0_um"] = np.nan if l0_um is None else float(l0_um)
    confirmation.summary.to_csv(out / "summary.csv", index=False)
    result.history.to_csv(out / "search_history.csv", index=False)
    say("phase 4/4: drawings, predictions and figures")
    best = [int(d) for d in top.sort_values("rank")["design"]]  # the confirmed best, distinct
    moulds = result.moulds(best)
    for k, mould in enumerate(moulds, 1):
        save_json(mould, out / f"design_{k:02d}.json")
        write_svg(mould, out / f"design_{k:02d}.svg", l0_um=l0_um)
        write_dxf(mould, out / f"design_{k:02d}.dxf", l0_um=l0_um)
        if fit_scale != 1.0:
            _write_drawn(mould, out, k, fit_scale, l0_um)
    cells = [build_lattice(m.polygon, m.tethers, scene.depth).n_cells for m in moulds]
    predicted = predict_designs(parsed, moulds, predictor, n_cells=cells)
    _write_predictions(out / "predictions.zarr", predicted, scene, best)
    simulated = dict(zip(confirmation.table["design"], confirmation.table["simulated_objective"]))
    _figures(out / "figures", table, confirmation, result, predicted, objective, yours,
             [simulated.get(d, np.nan) for d in best])
    log.info("\n%s", confirmation.summary.to_string(index=False))
    return confirmation.summary


def _write_drawn(mould, out: Path, k: int, fit_scale: float, l0_um) -> None:
    """Design k at the size of your drawing (scaled back by 1 / fit_scale): JSON (a minimal
    outline file, in mm given l0_um, else l0), SVG and DXF, each stating the scale."""
    drawn = drawn_mould(mould, fit_scale)
    note = (f"At your drawing's size: design_{k:02d} (as searched and simulated) scaled by "
            f"1/{fit_scale:.4g} = {1 / fit_scale:.4g}" + (f", l0 = {l0_um:g} um" if l0_um else ""))
    write_svg(drawn, out / f"design_{k:02d}_drawn.svg", l0_um=l0_um, note=note)
    write_dxf(drawn, out / f"design_{k:02d}_drawn.dxf", l0_um=l0_um, note=note)
    factor = 1.0 if l0_um is None else float(l0_um) / 1000.0  # l0 -> mm
    ring = np.asarray(drawn.polygon.exterior.coords)[:-1] * factor
    outline = {"outline": ring.tolist(),
               "holes": [(np.asarray(h.coords)[:-1] * factor).tolist()
                         for h in drawn.polygon.interiors],
               "tethers": (np.asarray(drawn.tethers).reshape(-1, 3) * factor).tolist(),
               "units": "l0" if l0_um is None else "mm",
               "comment": note + f"; read it back with --fit to place it as design_{k:02d}"}
    (out / f"design_{k:02d}_drawn.json").write_text(json.dumps(outline))


def checkpoint_design_scene(checkpoint) -> Scene:
    """The scene a checkpoint was trained on (condor.stages.predict.checkpoint_scene), in
    which its designs are simulated; DesignOutputError when it records no mould depth."""
    from condor.stages.predict import checkpoint_scene

    scene = checkpoint_scene(Predictor(checkpoint, device="cpu"))
    if np.isnan(scene.depth):
        raise DesignOutputError(f"checkpoint {checkpoint!r} records no mould depth: its designs "
                                "cannot be simulated")
    return scene


def summary_lines(summary, out_dir, n_top: int, objective: str, store=None,
                  mould_paths=()) -> list[str]:
    """What `condor design` prints of its run: the files, the best confirmed design and the
    rank correlation, the dataset's best test mould, and each of your moulds against the best."""
    shown = int(summary.get("n_top_distinct", n_top))
    scale = float(summary.get("fit_scale", 1.0))
    drawn = (f"; design_01..{shown:02d}_drawn .json/.svg/.dxf at your drawing's size (the "
             f"designs scaled by 1/{scale:.4g} = {1 / scale:.4g})" if scale != 1.0 else "")
    lines = [f"{out_dir}: designs.csv, summary.csv, design_01..{shown:02d} .json/.svg/.dxf "
             f"(the {shown} best distinct designs, each simulated){drawn}, predictions.zarr, "
             "figures/",
             f"best confirmed design: simulated {summary['best_simulated']:.4g}; Spearman rho "
             f"{summary['spearman']:.2f} [{summary['spearman_low']:.2f}, "
             f"{summary['spearman_high']:.2f}] over {int(summary['n'])} confirmed designs"]
    if "best_baseline" in summary:
        lines.append(f"best test mould of {store}: {summary['best_baseline']:.4g} "
                     f"(improvement {summary['improvement']:+.4g})")
    if mould_paths:
        table = pd.read_csv(Path(out_dir) / "your_moulds.csv")
        lines += [f"yours {row.simulated_objective:.3g} +- "
                  f"{row.simulated_objective_std / np.sqrt(row.n_ok):.2g} (the mean of "
                  f"{row.n_ok} simulations +- its standard error; one simulation scatters +- "
                  f"{row.simulated_objective_std:.2g}; predicted {row.predicted_objective:.3g} "
                  f"+- {row.predicted_spread:.2g}, one simulation's predicted spread) -> "
                  f"best {summary['best_simulated']:.3g} simulated: {objective} "
                  f"{summary['best_simulated'] - row.simulated_objective:+.3g} "
                  f"(mould {row.mould}, {mould_paths[row.mould - 1]})"
                  for row in table.itertuples()]
        lines.append(f"your moulds, predicted and simulated: {Path(out_dir) / 'your_moulds.csv'}; "
                     f"drawn beside the best designs in {Path(out_dir) / 'figures' / 'designs.png'}")
    return lines


def objective_spread_factor(objective, predictor) -> tuple[float, str]:
    """(factor, line): the calibration factor of the objective's predicted spread, the
    factor condor predict applies to the whole-mould statistic the objective equals
    (condor.design.search.calibrated_statistic; condor.findings' "spread_calibration"), and a
    line saying so; (1.0, a line saying it is uncalibrated) for any other objective."""
    from condor.findings import load_findings
    from condor.surrogate.answer import checkpoint_spread_calibration

    statistic = calibrated_statistic(objective)
    if statistic is None:
        return 1.0, ("the objective's predicted spread is uncalibrated (the one-simulation "
                     "spread drawn from the spread map): only alignment along x or y and "
                     "mean_tension over the whole box have calibrated spreads "
                     "(experiments/spread_calibration)")
    calibration = load_findings()["spread_calibration"]
    factors, _, warning = checkpoint_spread_calibration(calibration, predictor.state)
    line = (f"the objective's predicted spread is {statistic}'s, calibrated: x"
            f"{factors[statistic]:.3g} ({calibration.experiment} at {calibration.commit})")
    return factors[statistic], line + (f"; warning: {warning}" if warning else "")


def _score_your_moulds(parsed, moulds, scene, predictor, replicas, seed, solver, progress):
    """A user's moulds under the objective: predicted and simulated (replica mean)."""
    moulds = [replace(m, mould_id=YOUR_MOULD_IDS + k) for k, m in enumerate(moulds)]
    cells = [build_lattice(m.polygon, m.tethers, scene.depth).n_cells for m in moulds]
    prediction = predict_designs(parsed, moulds, predictor, n_cells=cells)
    predicted = prediction.table
    simulated = simulate_designs(parsed, moulds, scene, replicas, seed, solver=solver,
                                 progress=progress).table
    return pd.DataFrame({"mould": [k + 1 for k in range(len(moulds))],
                         "predicted_objective": predicted["objective"].to_numpy(),
                         "predicted_spread": predicted["predicted_spread"].to_numpy(),
                         "simulated_objective": simulated["objective"].to_numpy(),
                         "simulated_objective_std": simulated["objective_std"].to_numpy(),
                         "n_ok": simulated["n_ok"].to_numpy()}), prediction


def _write_predictions(path: Path, predicted, scene: Scene, designs) -> None:
    centres = (np.arange(scene.pixels) + 0.5) * scene.pixel_size
    variables = {"inputs": (("design", "channel", "y", "x"), predicted.inputs.astype(np.uint8)),
                 "raw": (("design", "field", "y", "x"), predicted.raw.astype(np.float32)),
                 "normalised": (("design", "field", "y", "x"), predicted.normalised.astype(np.float32))}
    if predicted.spread is not None:
        variables["spread"] = (("design", "field", "y", "x"), predicted.spread.astype(np.float32))
    ds = xr.Dataset(variables, coords={"design": list(designs), "field": list(FIELD_NAMES),
                                       "channel": list(CHANNELS), "y": centres, "x": centres},
                    attrs={"length_unit": "l0", "scene": scene.name,
                           "spread": "standard deviation of one simulation about the predicted "
                                     "(expected) raw field"})
    with quiet_zarr():
        ds.to_zarr(path, mode="w-")


def _figures(folder: Path, table, confirmation, result, predicted, objective: str,
             yours=None, simulated=()) -> None:
    plots.design_confirmation(confirmation.table, confirmation.summary,
                              folder / "confirmation.png", title=objective)
    plots.design_search_history(result.history, folder / "search_history.png")
    rows = []
    shown = [("yours", yours)] if yours is not None else []
    for label, prediction in shown + [("design", predicted)]:
        for k in range(len(prediction.inputs)):
            images = [("mould", prediction.inputs[k][0] + 2 * prediction.inputs[k][1]),
                      ("P", prediction.raw[k][0]), ("T", prediction.raw[k][1]),
                      ("Sx2", prediction.raw[k][2]), ("Sy2", prediction.raw[k][3])]
            if prediction.spread is not None:
                images += [("Sx2 spread", prediction.spread[k][2])]
            value = prediction.table["objective"].iloc[k]
            sim = f", sim. {simulated[k]:.3g}" if label == "design" and k < len(simulated) \
                and np.isfinite(simulated[k]) else ""
            rows.append((f"{label} {k + 1}\n(pred. {value:.3g}{sim})", images))
    plots.image_grid(rows, folder / "designs.png", f"{'your moulds and ' if shown else ''}the "
                     f"best distinct designs for {objective} (predicted and simulated "
                     "objective in brackets): predicted fields and reproducibility",
                     cmaps={"mould": "Greys"})
