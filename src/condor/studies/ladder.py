"""The anneal ladder: does the dataset's fast solver sample the paper's ensemble?

"CONDOR" means the paper's anneal (1e6 moves per cell). On a few test moulds each rung of
the ladder (an anneal budget, then tight relaxation: `recipes.anneal_then_relax`) is run with
several seeds: an ensemble. Each rung's expected fields are compared with the dataset
solver's (the store's replicas of the same moulds) by the noise-corrected distance between
ensemble means (condor.measures.estimators.ensemble_distance), beside the scatter of one simulation
within each ensemble. A rung whose distance is well below that scatter samples the same
states; energies per cell say which family of minima is lower.
"""

from __future__ import annotations

import numpy as np
import pandas as pd

from condor.measures import estimators as est
from condor.data.fields import cell_fields, normalise
from condor.progress import progress
from condor.data.seeds import study_seed
from condor.studies.recipes import anneal_then_relax


def ladder(ensemble, moulds, scene, budgets, n_seeds: int, dataset_seed: int, log=None
           ) -> pd.DataFrame:
    """One row per (mould, rung) plus the dataset solver's own row per mould: runs, energy per
    cell (median, min, max), `distance_to_dataset` (RMS over normalised fields, noise removed),
    `spread` (one simulation's RMS scatter within the rung), and annealer diagnostics.
    `moulds`: condor.moulds.mould.Mould objects of ensemble.moulds (same order)."""
    truth = ensemble.normalised
    rows = []
    for m, mould in enumerate(moulds):
        if int(mould.mould_id) != int(ensemble.moulds[m]):
            raise ValueError(f"mould {mould.mould_id} is not the ensemble's mould "
                             f"{ensemble.moulds[m]} at position {m}")
        energies = ensemble.energy_per_cell[m][np.isfinite(ensemble.energy_per_cell[m])]
        rows.append({"mould": int(mould.mould_id), "rung": "dataset solver", "budget": np.nan,
                     "runs": len(energies), "energy_per_cell": float(np.median(energies)),
                     "energy_min": float(energies.min()), "energy_max": float(energies.max()),
                     "distance_to_dataset": 0.0,
                     "spread": est.root_mean(est.noise_ceiling(truth[m:m + 1]))})
        for budget in budgets:
            fields, energies, accept, inverted = [], [], [], []
            for k in progress(range(n_seeds), desc=f"mould {mould.mould_id} anneal {budget:g}",
                              unit="run"):
                seed = study_seed(dataset_seed, mould.mould_id, 1000 + k)
                r = anneal_then_relax(mould, scene.depth, budget, seed)
                if r.status != "ok":
                    continue
                f = cell_fields(r.positions, r.orientations, r.tension, scene.box, scene.pixels,
                                scene.sigma)
                fields.append(normalise(f.astype(np.float64), r.n_cells))
                energies.append(r.energy_per_cell)
                accept.append(r.info.get("anneal_accept_pos", np.nan))
                inverted.append(r.info.get("inverted_fraction", np.nan))
            row = {"mould": int(mould.mould_id), "rung": f"anneal {budget:g} + relax",
                   "budget": float(budget), "runs": len(fields)}
            if len(fields) >= 2:
                ens = np.stack(fields)[None]
                row.update(energy_per_cell=float(np.median(energies)),
                           energy_min=float(np.min(energies)), energy_max=float(np.max(energies)),
                           distance_to_dataset=est.root_mean(
                               est.ensemble_distance(ens, truth[m:m + 1]).corrected),
                           spread=est.root_mean(est.noise_ceiling(ens)),
                           accept_pos=float(np.median(accept)),
                           inverted_fraction=float(np.max(inverted)))
            rows.append(row)
            if log is not None:
                log(f"ladder mould {mould.mould_id} anneal {budget:g}: {row}")
    return pd.DataFrame(rows)
