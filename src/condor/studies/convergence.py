"""What the scene's reductions change: fields against depth (layers) and box size.

Each configuration (a depth, or a box scale) of a mould is simulated with several seeds: an
ensemble. Its systematic change is the noise-corrected distance between its mean fields and
the mean fields of the reference configuration (the deepest / largest; condor.measures.estimators.
ensemble_distance), per channel, relative to the RMS of the reference's expected fields. It is
compared with the scatter of one simulation about its own expected fields (the noise). A
reduction whose systematic change stays below half the scatter of one simulation, on every
channel of P, T, Sx2, Sy2, Sz2, is invisible in a sample and is `justified`.

Box study: the mould generated in a box `scale` x the scene's (the generator scales the whole
geometry, tether radii included), rasterised in box-relative coordinates (same pixels, sigma
scaled with the box).
"""

from __future__ import annotations

from dataclasses import replace

import math

import numpy as np
import pandas as pd

from condor.measures import estimators as est
from condor.measures.bars import SAME_STATES
from condor.data.fields import FIELD_NAMES, cell_fields, normalise
from condor.model.lattice import HALF
from condor.moulds.paper import generate_mould
from condor.progress import progress
from condor.data.seeds import study_seed
from condor.model.simulate import simulate

SCORED_FIELDS = ("P", "T", "Sx2", "Sy2", "Sz2")


def n_layers(depth: float) -> int:
    """FCC (001) layers that fit in 0 <= z <= depth (l0)."""
    return int(math.floor(depth / HALF + 1e-9)) + 1


def _ensemble(polygon, tethers, depth, box, scene, sigma, seeds, solver):
    fields, cells, seconds = [], 0, []
    for seed in progress(seeds, desc=f"depth {depth:g}, box {box:g}", unit="run"):
        r = simulate(polygon, tethers, depth, solver, None, seed)
        if r.status != "ok":
            raise RuntimeError(f"convergence run failed ({r.status}) at depth {depth}, box {box}")
        f = cell_fields(r.positions, r.orientations, r.tension, box, scene.pixels, sigma)
        fields.append(normalise(f.astype(np.float64), r.n_cells))
        cells, seconds = r.n_cells, seconds + [r.seconds]
    return np.stack(fields), cells, float(np.median(seconds))


def _rows(study, mould_id, runs: dict, ref_value) -> list[dict]:
    ref = runs[ref_value][0]
    scale = np.sqrt((ref.mean(axis=0) ** 2).mean(axis=(1, 2)))  # RMS per channel
    noise = np.sqrt(est.noise_ceiling(ref[None], per_field=True)[0]) / scale
    rows = []
    for value, (ens, cells, seconds) in runs.items():
        dist = est.ensemble_distance(ens[None], ref[None], per_field=True).corrected[0]
        rel = np.sqrt(np.maximum(dist, 0.0)) / scale
        row = {"study": study, "mould": int(mould_id), "value": float(value),
               "layers": n_layers(value) if study == "depth" else None, "n_cells": cells,
               "cpu_s": seconds, "reference": bool(value == ref_value)}
        row.update({f"change_{f}": float(v) for f, v in zip(FIELD_NAMES, rel)})
        row.update({f"noise_{f}": float(v) for f, v in zip(FIELD_NAMES, noise)})
        row["justified"] = bool(all(row[f"change_{c}"] <= SAME_STATES * row[f"noise_{c}"]
                                    for c in SCORED_FIELDS))
        rows.append(row)
    return rows


def convergence(scene, moulds, n_seeds: int = 3, depths=(2.0, 3.0, 4.0), box_scales=(1.0, 2.0),
                solver: str | None = None, dataset_seed: int = 0, log=None) -> pd.DataFrame:
    """One row per (study, mould, value): cells, CPU seconds of one run, change_<field>
    (systematic, relative), noise_<field> (one simulation's scatter, relative), justified."""
    if n_seeds < 2:
        raise ValueError(f"convergence needs at least 2 seeds per configuration, got {n_seeds}")
    rows = []
    for mould in moulds:
        seeds = [study_seed(dataset_seed, mould.mould_id, 100 + k) for k in range(n_seeds)]
        runs = {d: _ensemble(mould.polygon, mould.tethers, d, scene.box, scene, scene.sigma,
                             seeds, solver) for d in depths}
        rows += _rows("depth", mould.mould_id, runs, max(depths))
        runs = {}
        for scale in box_scales or ():
            box = scene.box * scale
            scaled = generate_mould(mould.seed, mould.mould_id, replace(scene, box=box))
            runs[box] = _ensemble(scaled.polygon, scaled.tethers, scene.depth, box, scene,
                                  scene.sigma * scale, seeds, solver)
        if runs:
            rows += _rows("box", mould.mould_id, runs, scene.box * max(box_scales))
        if log is not None:
            log(f"convergence mould {mould.mould_id}: {len(rows)} rows")
    return pd.DataFrame(rows)
