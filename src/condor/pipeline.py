"""The dataset stages as functions of (config, mould ids, paths): shared by the Snakemake
scripts and the `condor` CLI so that neither holds logic of its own.

Stage 1, moulds: generate, validate, write a batch JSON and the store's `inputs`.
Stage 2, simulate: one `SimResult` file per mould (a failed simulation is a result too).
Stage 3, fields: rasterise each ok result into the store; record failures with their reason.
"""

from __future__ import annotations

import json
import logging
import os
from pathlib import Path

import numpy as np

from condor import config as cfg

log = logging.getLogger("condor")


def store_path(config: dict) -> Path:
    return Path(config.get("results", "results")) / "dataset.zarr"


def init_store(config: dict) -> bool:
    """Create the dataset store for `config` (or accept a matching one). True if created."""
    from condor.store import create_store

    return create_store(store_path(config), cfg.store_spec(config))


def warm_kernels() -> None:
    """Compile (or load from numba's cache) every kernel once, before the parallel fan-out:
    numba's on-disk cache can be corrupted when many processes compile at once."""
    from condor.fields import cell_fields
    from condor.simulate import warm_up

    warm_up()
    cell_fields(np.full((1, 3), 1.0), np.array([[0.0, 0.0, 1.0]]), np.zeros(1), box=2.0, pixels=4)


def make_moulds(config: dict, ids, out_json: str | Path, store: str | Path | None = None) -> list:
    """Generate and validate moulds `ids`; write their geometry to `out_json` and, when
    `store` is given, their input channels and metadata into the store."""
    from condor.moulds import generate_mould, input_channels, validate_mould
    from condor.store import write_inputs

    scene = cfg.scene_of(config)
    params = cfg.mould_params_of(config)
    moulds = []
    for mould_id in ids:
        mould = generate_mould(config["seed"], mould_id, box=scene.box, params=params,
                               area_fraction=scene.area_fraction, max_extent=scene.max_extent)
        validate_mould(mould)  # never write invalid geometry
        moulds.append(mould)
    _write_json_atomic(out_json, [m.to_dict() for m in moulds])
    if store is not None:
        for mould in moulds:
            write_inputs(store, mould.mould_id, input_channels(mould, scene.pixels), mould_metadata(mould))
    log.info("moulds %s written to %s", _span(ids), out_json)
    return moulds


def mould_metadata(mould) -> dict:
    return {
        "seed": mould.seed,
        "symmetry": mould.symmetry,
        "order": mould.order,
        "removal": mould.removal,
        "n_tethers": mould.n_tethers,
    }


def load_moulds(path: str | Path) -> list:
    from condor.moulds import Mould

    return [Mould.from_dict(d) for d in json.loads(Path(path).read_text())]


def simulate_moulds(config: dict, moulds_json: str | Path, out_dir: str | Path) -> list[str]:
    """Simulate every mould in `moulds_json`; write `<out_dir>/<mould_id>.npz` each."""
    from condor.simulate import simulate

    scene = cfg.scene_of(config)
    sim = config.get("simulation", {})
    out_dir = Path(out_dir)
    out_dir.mkdir(parents=True, exist_ok=True)
    statuses = []
    moulds = load_moulds(moulds_json)
    for k, mould in enumerate(moulds, 1):
        result = simulate(mould.polygon, mould.tethers, scene.depth, solver=sim.get("solver", "hybrid"),
                          budget=sim.get("budget"), seed=simulation_seed(config["seed"], mould.mould_id))
        result.save(out_dir / f"{mould.mould_id:06d}.npz")
        statuses.append(result.status)
        log.info("[%d/%d] mould %d: %s, %d cells, E/cell %.5g, %.2f s", k, len(moulds),
                 mould.mould_id, result.status, result.n_cells, result.energy_per_cell, result.seconds)
    return statuses


def simulation_seed(seed: int, mould_id: int) -> int:
    """A per-mould simulation seed derived from (global seed, mould id), independent of the
    mould generator's stream."""
    return int(np.random.default_rng([seed, mould_id, 1]).integers(2**62))


def rasterise_result(result, scene) -> np.ndarray:
    from condor.fields import cell_fields

    return cell_fields(result.positions, result.orientations, result.tension, scene.box, scene.pixels, scene.sigma)


def write_fields(config: dict, sims_dir: str | Path, moulds_json: str | Path, store: str | Path,
                 out_summary: str | Path) -> dict:
    """Rasterise each simulation of the batch into the store; failures keep their reason."""
    from condor.simulate import SimResult
    from condor.store import write_sample

    scene = cfg.scene_of(config)
    summary = {}
    for mould in load_moulds(moulds_json):
        result = SimResult.load(Path(sims_dir) / f"{mould.mould_id:06d}.npz")
        meta = {"n_cells": result.n_cells, "energy": result.energy, "solver": result.solver,
                "solver_seconds": result.seconds}
        fields = rasterise_result(result, scene) if result.status == "ok" else None
        status = result.status
        if fields is not None and not np.all(np.isfinite(fields)):
            fields, status = None, "non-finite fields"
        write_sample(store, mould.mould_id, fields, meta, status)
        summary[mould.mould_id] = status
    _write_json_atomic(out_summary, summary)
    return summary


def _write_json_atomic(path: str | Path, payload) -> None:
    path = Path(path)
    path.parent.mkdir(parents=True, exist_ok=True)
    tmp = path.with_name(path.name + f".tmp{os.getpid()}")
    tmp.write_text(json.dumps(payload, indent=1))
    os.replace(tmp, path)


def _span(ids) -> str:
    ids = list(ids)
    return f"{ids[0]}..{ids[-1]}" if ids else "(none)"


def setup_logging(logfile: str | Path | None = None) -> None:
    """Log condor's progress to `logfile` (a job's log) and to stderr."""
    handlers = [logging.StreamHandler()]
    if logfile:
        Path(logfile).parent.mkdir(parents=True, exist_ok=True)
        handlers.append(logging.FileHandler(logfile, mode="w"))
    logging.basicConfig(level=logging.INFO, format="%(asctime)s %(message)s", handlers=handlers, force=True)
