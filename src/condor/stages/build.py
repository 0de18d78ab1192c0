"""The dataset stages: functions of (config, explicit paths) that write files.

The workflow's scripts and the `condor` CLI call these and nothing else:

1. `init_store`: warm numba's kernel cache, create the store (or accept the matching one) and
   write the folder's manifest;
2. `make_moulds`: generate and validate a batch of moulds; geometry JSON + the store's inputs
   and geometry;
3. `simulate_batch`: every replica of every mould of a batch, one result file each (a failed
   simulation is a result too, with its reason);
4. `write_fields`: rasterise each ok result into the store; failures keep their reason (and
   inputs the store lost are written again from the batch's moulds JSON);
5. `finish_dataset`: the store's layout where it was damaged, the expected fields and spread
   of replicated moulds, and the per-sample table; it fails, naming them, when samples are
   missing.
Figures: `write_gallery`, `sample_figure`.

The command line's stages of one mould (`condor mould`, `simulate`, `rasterise`) and of a
store (`condor check-store`) are at the end: `mould_files`, `simulate_placed`,
`rasterise_file`, `store_report`.
"""

from __future__ import annotations

import json
import logging
import os
import platform
from contextlib import ExitStack
from pathlib import Path

import numpy as np
import pandas as pd

from condor.data import inputs as model_inputs
from condor.files import atomic_path, write_text

from condor import plots
from condor.config import Config, recorded_splits
from condor.folder import folder_record
from condor.data.fields import cell_fields
from condor.moulds.mould import PAPER, Mould, input_channels, save_json
from condor.moulds.paper import regime_table
from condor.moulds.sources import make_mould
from condor.progress import progress
from condor.model.scenes import Scene, get_scene, same_length
from condor.data.seeds import replica_seed
from condor.model.simulate import SimResult, default_budget, simulate, warm_up
from condor.data.store_check import (check_metadata, check_store, inputs_whole, restore_layout,
                                     scan_store, set_aside)
from condor.data.store import (create_store, open_group, open_store, sample_index,
                               write_expected, write_inputs, write_sample)

log = logging.getLogger("condor")


def write_json_atomic(path: str | Path, payload) -> Path:
    """Write JSON through a temporary file and a rename: readers see all of it or nothing."""
    path = Path(path)
    path.parent.mkdir(parents=True, exist_ok=True)
    return write_text(path, json.dumps(payload, indent=1))


# --- 1. the store -------------------------------------------------------------------------------

def warm_kernels() -> None:
    """Compile (or load from numba's cache) every kernel once, before the parallel fan-out:
    numba's on-disk cache can be corrupted when many processes compile at once."""
    warm_up()
    cell_fields(np.full((1, 3), 1.0), np.array([[0.0, 0.0, 1.0]]), np.zeros(1), box=2.0, pixels=4)


def init_store(config: Config, store: str | Path, manifest: str | Path) -> bool:
    """Create the store for `config` (or keep the matching one: its samples stay) and write
    `manifest` (what the folder holds and for which data configuration) and the folder's own
    record of it (condor.folder.FOLDER_RECORD, beside the manifest: it outlives a deleted
    store and manifest). True if created."""
    warm_kernels()
    created = create_store(store, config.store_spec())
    record = {"store": str(store), "data_config": config.data_config()}
    write_json_atomic(folder_record(Path(manifest).parent), record)
    write_json_atomic(manifest, {**record, "created": created})
    log.info("store %s %s", store, "created" if created else "exists and matches; kept")
    return created


# --- 2. moulds ----------------------------------------------------------------------------------

def mould_metadata(mould: Mould) -> dict:
    return {"seed": mould.seed, "family": mould.family, "symmetry": mould.symmetry,
            "order": mould.order, "removal": mould.removal, "n_tethers": mould.n_tethers}


def make_moulds(config: Config, ids, out_json: str | Path, store: str | Path | None = None) -> list:
    """Draw moulds `ids`, each from its source (the generator or a lab family:
    `Config.make_mould`); write their geometry to `out_json` and, when `store` is given, their
    input channels (masks and lattice channels, condor.data.inputs) and metadata into the
    store (every replica)."""
    moulds = [config.make_mould(i) for i in ids]
    write_json_atomic(out_json, [m.to_dict() for m in moulds])
    if store is not None:
        for mould in moulds:
            write_mould_inputs(config, store, mould)
    log.info("moulds %s written to %s", _span(ids), out_json)
    return moulds


def write_mould_inputs(config: Config, store: str | Path, mould: Mould) -> None:
    """One mould's input channels, metadata and geometry (outline and tethers) into every
    replica of it in the store."""
    write_inputs(store, mould.mould_id, input_channels(mould, config.scene.pixels),
                 mould_metadata(mould), lattice=model_inputs.of_mould(mould, config.scene),
                 polygon=mould.polygon, tethers=mould.tethers)


def load_moulds(path: str | Path) -> list:
    return [Mould.from_dict(d) for d in json.loads(Path(path).read_text())]


def _span(ids) -> str:
    ids = list(ids)
    return f"{ids[0]}..{ids[-1]}" if ids else "(none)"


# --- 3. simulation ------------------------------------------------------------------------------

def sim_file(out_dir: str | Path, mould: int, replica: int) -> Path:
    """Where a batch keeps the result of one replica of one mould."""
    return Path(out_dir) / f"{mould:06d}_{replica:02d}.npz"


def hardware() -> str:
    """The machine this process runs on, as the dataset records it: CPU model, the CPU target
    numba compiles the kernels for (its instruction set decides their last bits, so two
    machines of one model name can give different equilibria), cores, arch."""
    model = platform.processor() or platform.machine()
    try:
        for line in Path("/proc/cpuinfo").read_text().splitlines():
            if line.startswith("model name"):
                model = line.split(":", 1)[1].strip()
                break
    except OSError:
        pass
    try:
        from llvmlite.binding import get_host_cpu_name  # numba's own compiler

        model = f"{model} ({get_host_cpu_name()})"
    except (ImportError, RuntimeError):
        pass
    return f"{model}, {os.cpu_count()} cores, {platform.machine()}"


def simulate_mould(mould: Mould, scene: Scene, solver: str | None, budget, seed: int) -> SimResult:
    """One simulation of `mould` in `scene`; the result records the scene it belongs to and
    the hardware it ran on."""
    if budget is None:
        budget = default_budget(solver, scene.box)
    result = simulate(mould.polygon, mould.tethers, scene.depth, solver=solver, budget=budget,
                      seed=seed)
    result.info["scene"] = scene.to_dict()
    result.info["hardware"] = hardware()
    return result


def simulate_batch(config: Config, moulds_json: str | Path, out_dir: str | Path) -> list[str]:
    """Simulate every replica of every mould in `moulds_json`; one result file each."""
    solver, budget = config.solver()
    replicas = config.replicas()
    out_dir = Path(out_dir)
    out_dir.mkdir(parents=True, exist_ok=True)
    jobs = [(m, r) for m in load_moulds(moulds_json) for r in range(replicas[m.mould_id])]
    statuses = []
    for k, (mould, replica) in enumerate(progress(jobs, desc="simulate", unit="sim"), 1):
        seed = replica_seed(config.seed, mould.mould_id, replica)
        result = simulate_mould(mould, config.scene, solver, budget, seed)
        result.save(sim_file(out_dir, mould.mould_id, replica))
        statuses.append(result.status)
        log.info("[%d/%d] mould %d replica %d: %s, %d cells, E/cell %.5g, %.2f s", k, len(jobs),
                 mould.mould_id, replica, result.status, result.n_cells,
                 result.energy_per_cell, result.seconds)
    return statuses


# --- 4. fields ----------------------------------------------------------------------------------

class SceneMismatchError(ValueError):
    """A simulation rasterised on the grid of another scene."""


def rasterise_result(result: SimResult, scene: Scene) -> np.ndarray:
    """The 8 fields of a result on `scene`'s grid; SceneMismatchError when the result was
    simulated for another box."""
    recorded = result.info.get("scene")
    if recorded is not None and not same_length(recorded["box"], scene.box):
        raise SceneMismatchError(
            f"the simulation belongs to scene {recorded.get('name')!r} (box {recorded['box']:g} "
            f"l0), not {scene.name!r} (box {scene.box:g} l0): pass --scene {recorded.get('name')}")
    return cell_fields(result.positions, result.orientations, result.tension, scene.box,
                       scene.pixels, scene.sigma)


def max_force(result: SimResult) -> float:
    """The largest residual force of a result (kappa0 l0), NaN when the solver reports none."""
    return float(result.info.get("max_force", result.info.get("min_max_force", np.nan)))


def write_fields(config: Config, sims_dir: str | Path, moulds_json: str | Path,
                 store: str | Path, out_summary: str | Path) -> dict:
    """Rasterise each simulation of the batch into the store; failures keep their reason.
    A mould whose inputs the store lost gets them again first, from the geometry its
    simulations used (`moulds_json`): the same bytes the mould stage wrote."""
    replicas = config.replicas()
    summary = {}
    for mould in load_moulds(moulds_json):
        if not inputs_whole(store, mould.mould_id):
            log.info("mould %d: the store lost its inputs; written again", mould.mould_id)
            write_mould_inputs(config, store, mould)
        for replica in range(replicas[mould.mould_id]):
            path = sim_file(sims_dir, mould.mould_id, replica)
            if not path.is_file():
                raise FileNotFoundError(f"simulation result {path} is missing: the simulate job "
                                        "of this batch must run again (the workflow does this)")
            result = SimResult.load(path)
            meta = {"sim_seed": result.seed, "n_cells": result.n_cells, "energy": result.energy,
                    "max_force": max_force(result), "solver": result.solver,
                    "solver_seconds": result.seconds,
                    "hardware": str(result.info.get("hardware", ""))}
            fields = rasterise_result(result, config.scene) if result.status == "ok" else None
            status = result.status
            if fields is not None and not np.all(np.isfinite(fields)):
                fields, status = None, "non-finite fields"
            sample = sample_index(replicas, mould.mould_id, replica)
            write_sample(store, sample, fields, meta, status)
            summary[f"{mould.mould_id}/{replica}"] = status
    write_json_atomic(out_summary, summary)
    return summary


# --- 5. the finished dataset ------------------------------------------------------------------

class IncompleteStoreError(RuntimeError):
    """Samples the store should hold are missing or corrupt; the message names them."""


def finish_dataset(store: str | Path, out_csv: str | Path, split=None) -> pd.DataFrame:
    """Write again whatever of the store's layout is lost or damaged (the coordinates, each
    sample's mould, replica and, given the per-mould `split`, split: condor.data.store.
    restore_layout), derive the expected fields of replicated moulds, then write the
    per-sample table. IncompleteStoreError, one line naming the samples, their damaged arrays
    and the way out, when a sample is missing, pending or corrupt."""
    restored = restore_layout(store, split)
    if restored:
        log.info("%s: rewrote the layout chunks %s", store, ", ".join(restored))
    table = check_store(store)
    bad = table[~table["state"].isin(["ok", "failed"])]
    if len(bad):
        shown = ", ".join(f"{r.sample} ({r.state}{': ' + r.lost if r.lost else ''})"
                          for r in bad.head(12).itertuples())
        raise IncompleteStoreError(
            f"{len(bad)} sample(s) of {store} are not finished: {shown}; run snakemake again "
            f"(it rebuilds what the store lacks; `condor check-store {store}` lists it)")
    n = write_expected(store)
    table.to_csv(out_csv, index=False)
    log.info("%s: %s; %d replicated moulds", store,
             table["state"].value_counts().to_dict(), n)
    return table


def write_gallery(moulds_jsons, n: int, out_png: str | Path, out_csv: str | Path) -> None:
    """The first `n` moulds drawn, and the regime/removal frequencies of all of them."""
    moulds = [m for path in moulds_jsons for m in load_moulds(path)]
    plots.mould_gallery(moulds[:n], out_png)
    regime_table([m for m in moulds if m.family == PAPER]).to_csv(out_csv)


def sample_figure(store: str | Path, out_png: str | Path, n: int = 4) -> list[int]:
    """The mould and 8 fields of the first `n` ok samples."""
    ds = open_store(store)
    ok = np.flatnonzero(ds["status"].values.astype(str) == "ok")[:n]
    if len(ok) == 0:
        raise IncompleteStoreError(f"{store} has no finished sample to show")
    rows = [(f"mould {int(ds['mould'].values[s])}", ds["inputs"].values[s], ds["fields"].values[s])
            for s in ok]
    plots.field_panels(rows, out_png)
    return [int(s) for s in ok]


# --- the command line's stages: one mould, one store --------------------------------------------

def mould_files(scene: Scene, seed: int, mould_id: int, params=None, out=None,
                png=None, source: str = PAPER) -> Mould:
    """Mould `mould_id` of dataset `seed` in `scene` from `source` (make_mould: the generator
    or a lab family), written as JSON to `out` and drawn to `png` (each when given): both or
    neither (condor.files.atomic_path)."""
    mould = make_mould(scene, seed, mould_id, source, params)
    with ExitStack() as both:
        if out:
            save_json(mould, both.enter_context(atomic_path(out)))
        if png:
            plots.mould_picture(mould, both.enter_context(atomic_path(png)))
    return mould


def simulate_placed(placement, scene: Scene, solver: str | None, budget, seed: int,
                    out) -> SimResult:
    """One simulation of a placed mould (condor.moulds.place.Placement), saved to `out` with
    how it was placed (its scale factor, the units read) and its whole-mould statistics
    (`simulated_statistics`, as `condor predict` names them)."""
    result = simulate_mould(placement.mould, scene, solver, budget, seed)
    result.info["placement"] = placement.record()
    if result.status == "ok":
        table = simulated_statistics(result, scene, placement.l0_um, placement.scale)
        result.info["statistics"] = {row.statistic: {"value": float(row.value), "unit": row.unit}
                                     for row in table.itertuples()}
    result.save(out)
    return result


def simulated_statistics(result: SimResult, scene: Scene, l0_um: float | None = None,
                         scale: float = 1.0) -> pd.DataFrame:
    """The whole-mould statistics of one simulation, under the names and units `condor
    predict` prints them (condor.data.statistics.mould_summary_statistics, on the scene's grid):
    `statistic`, `value`, `spread` (NaN: one simulation has none), `unit`; tissue_area_mm2
    (given l0_um) at the drawn size, as predict's."""
    from condor.data.fields import normalise
    from condor.data.statistics import (MOULD_STATISTICS, STATISTIC_UNITS,
                                        mould_summary_statistics)

    raw = cell_fields(result.positions, result.orientations, result.tension, scene.box,
                      scene.pixels, scene.sigma)
    n_cells = len(result.positions)
    values = mould_summary_statistics(normalise(raw, n_cells), n_cells, scene.pixel_size)
    rows = [(name, values[name], np.nan, STATISTIC_UNITS[name]) for name in MOULD_STATISTICS]
    if l0_um is not None:
        mm2 = (float(l0_um) / 1000.0 / float(scale)) ** 2
        rows.append(("tissue_area_mm2", values["tissue_area"] * mm2, np.nan,
                     "mm^2" + (f", at the drawn size (placed at {scale:.4g}x)"
                               if scale != 1.0 else "")))
    return pd.DataFrame(rows, columns=["statistic", "value", "spread", "unit"])


def rasterise_file(simulation, scene_name: str | None, out: Path) -> tuple[SimResult, Scene]:
    """The 8 fields of a saved simulation, on the grid of `scene_name` (default: the scene it
    records, else "default"), written to `out` (.npy, or a .png picture)."""
    result = SimResult.load(simulation)
    if result.status != "ok":
        raise ValueError(f"{simulation} is a failed simulation ({result.status}); no fields")
    recorded = result.info.get("scene", {}).get("name")
    scene = get_scene(scene_name or recorded or "default")
    fields = rasterise_result(result, scene)
    if out.suffix == ".npy":
        with atomic_path(out) as tmp:
            np.save(tmp, fields)
    else:
        plots.field_panels([(f"{result.n_cells} cells", None, fields)], out)
    return result, scene


def store_report(store, deep: bool = False, shown: int = 20) -> tuple[list[str], bool]:
    """What `condor check-store` says of a store (check_metadata, scan_store), and whether it
    is whole; with `deep`, damaged chunk files are moved aside (set_aside)."""
    problems = check_metadata(store)
    split = recorded_splits(open_group(store).attrs.get("data_config") or {})
    check = scan_store(store, deep=deep, split=split)
    table = check.samples
    counts = table["state"].value_counts()
    lines = [f"{store}: {len(table)} samples: " + ", ".join(f"{k} {v}" for k, v in counts.items())]
    lines += [f"  metadata: {problem}" for problem in problems]
    for state in ("missing", "pending", "failed", "corrupt"):
        rows = table[table["state"] == state]
        if len(rows):
            more = f" (+{len(rows) - shown} more)" if len(rows) > shown else ""
            lines.append(f"  {state}: {', '.join(str(s) for s in rows['sample'].head(shown))}{more}")
            if state == "failed":
                lines += [f"    {len(group)} x {reason}" for reason, group in rows.groupby("status")]
    lines += [f"  damaged: {damage}" for damage in check.damage[:shown]]
    if len(check.damage) > shown:
        lines.append(f"  damaged: +{len(check.damage) - shown} more chunks")
    if not check.derived:
        lines.append("  expected fields (fields_mean, fields_std, n_replicas_ok): not written (the "
                     "workflow's dataset step derives them)")
    moved = set_aside(store, check.damage) if deep else None
    if moved:
        lines.append(f"  moved the damaged chunk files to {moved}")
    if check.damage:
        lines.append("  the next `snakemake` run rebuilds the samples and arrays named above")
    whole = not (problems or (table["state"] != "ok").any() or check.damage or not check.derived)
    return lines, whole
