"""Fidelity: how far a solver's ensemble lies from the paper's CONDOR (the reference anneal).

Both ensembles are replicas of the same moulds (M, R, 8, H, W) of normalised fields. The
distance is the noise-corrected RMS distance between their expected fields
(`estimators.ensemble_distance`, RMS over moulds, fields and pixels), with a bootstrap
interval over moulds; the replica noise is one simulation's RMS scatter about the
reference's expected fields (`estimators.noise_ceiling`), the yardstick of every bar. The
whole-mould statistics beside it: the cell-averaged orientation (sum of a field Sa2 over the
sum of P, the mean s_a^2 of the cells) and the energy per cell, as differences of the
ensembles' means (the energy's in % of the reference's, averaged over moulds with a bootstrap
interval: a mould's energy scatters by a few % from seed to seed, so a handful of seeds
resolves a fraction of a percent only over many moulds).

`fidelity_row` is one row of `fidelity.csv` (FIDELITY_COLUMNS first).

The tilt fields SxSz and SySz (s_x s_z, s_y s_z) are odd under the slab's reflection z ->
depth - z. The energy is even under it (bond lengths and squared cosines of bonds with
orientations), and so are the floor and lid; the posts are not quite: their cells stay fixed
at the lattice's layers (z = 0 .. 3.54 in a slab of depth 4), and a tethered mould's cells keep
to the floor. So a tilt field's expectation is near 0, not exactly 0, while one run's tilt is
large and of either sign, and most of one simulation's scatter on many paper-scene moulds.
With `z_symmetric` the distance is that of the ensembles symmetrised under the reflection,
each run averaged with its reflected twin (`z_symmetrised`: the tilt fields 0, the others
unchanged): the distance over the six even fields (still divided by all 8), which equals the
whole where both ensembles' tilt expectations agree, without the tilt fields' noise. It says
nothing of the tilt: report it beside the whole distance, never alone. The replica noise, the
yardstick, stays one simulation's, tilt included.
"""

from __future__ import annotations

import numpy as np
import pandas as pd

from condor.measures import estimators as est
from condor.measures.bars import SAME_STATES
from condor.data.fields import FIELD_NAMES

FIDELITY_COLUMNS = ("method", "scene", "reference", "n_moulds", "n_seeds", "distance",
                    "distance_lo", "distance_hi", "replica_noise", "evaluations_per_mould")
_P, _ORIENT = FIELD_NAMES.index("P"), [FIELD_NAMES.index(f) for f in ("Sx2", "Sy2", "Sz2")]
TILT = tuple(FIELD_NAMES.index(f) for f in ("SxSz", "SySz"))  # odd under z -> depth - z


def z_symmetrised(fields) -> np.ndarray:
    """Fields (..., 8, H, W), each averaged with its twin under the slab's reflection: a copy
    with the tilt fields (TILT) 0, NaN where the run is missing."""
    out = np.array(fields, dtype=np.float64)
    out[..., TILT, :, :] *= 0.0  # keeps NaN
    return out


def mean_orientation(fields) -> np.ndarray:
    """Cell-averaged (sx^2, sy^2, sz^2) of fields (..., 8, H, W): (..., 3)."""
    f = np.asarray(fields, dtype=np.float64)
    total = f.sum(axis=(-2, -1))
    return total[..., _ORIENT] / total[..., _P, None]


def fidelity_row(method: str, scene: str, reference: str, fields, ref_fields,
                 evaluations=None, energy=None, ref_energy=None, paired: bool = False,
                 z_symmetric: bool = False) -> dict:
    """One row: `fields` (M, R, 8, H, W) of the method against `ref_fields` (M, R', 8, H, W)
    of the reference, both normalised, the same moulds in the same order; `evaluations`
    (M, R) the method's cost in evaluation-equivalents; `energy`, `ref_energy` (M, R) and
    (M, R') energies per cell. NaN-padded replicas are allowed (estimators). `paired`: replica
    k of both shares its seed (two rungs of the paper reference), so the distance is
    `estimators.paired_distance`'s, else `ensemble_distance`'s (independent ensembles).
    `z_symmetric`: the distance of the ensembles symmetrised under z -> depth - z, over the six
    even fields (module docs), recorded in the row's `z_symmetric` (a column only such rows
    hold)."""
    fields = np.asarray(fields, dtype=np.float64)
    ref_fields = np.asarray(ref_fields, dtype=np.float64)
    scored = ((z_symmetrised(fields), z_symmetrised(ref_fields)) if z_symmetric
              else (fields, ref_fields))
    d = (est.paired_distance if paired else est.ensemble_distance)(*scored)
    distance, lo, hi = est.bootstrap_interval(d.corrected)
    row = {"method": method, "scene": scene, "reference": reference,
           "n_moulds": int(fields.shape[0]),
           "n_seeds": int(est.replica_counts(fields).min()),
           "distance": distance, "distance_lo": lo, "distance_hi": hi,
           "replica_noise": est.root_mean(est.noise_ceiling(ref_fields)),
           "evaluations_per_mould": float(np.nanmean(evaluations)) if evaluations is not None
           else float("nan")}
    diff = (np.nanmean(mean_orientation(fields), axis=1)
            - np.nanmean(mean_orientation(ref_fields), axis=1))  # (M, 3)
    for name, values in zip(("sx2", "sy2", "sz2"), diff.T):
        row[f"{name}_difference"] = float(np.mean(values))
        row[f"{name}_difference_max"] = float(values[np.argmax(np.abs(values))])
    if energy is not None and ref_energy is not None:
        ratio = 100 * (np.nanmean(energy, axis=1) / np.nanmean(ref_energy, axis=1) - 1)
        e_mean, e_lo, e_hi = est.bootstrap_interval(ratio, statistic=np.mean)
        row.update(energy_difference_pct=e_mean, energy_difference_pct_lo=e_lo,
                   energy_difference_pct_hi=e_hi,
                   energy_difference_pct_max=float(ratio[np.argmax(np.abs(ratio))]))
    row["converged"] = bool(row["distance_hi"] <= SAME_STATES * row["replica_noise"])
    if z_symmetric:
        row["z_symmetric"] = True
    return row


def solver_ensemble(scene, dataset_seed: int, mould_ids, solver: str, budget, replicas: int,
                    log=None):
    """`replicas` simulations of each mould with `solver` (the dataset's replica seeds, so the
    dataset's own solver reproduces its store): normalised fields (M, R, 8, H, W), energies
    per cell and evaluation-equivalents (M, R); a failed run is NaN."""
    from condor.data.seeds import replica_seed
    from condor.model.simulate import simulate
    from condor.studies.paper_reference import mould_of, scene_fields

    fields = np.full((len(mould_ids), replicas, 8, scene.pixels, scene.pixels), np.nan)
    energy = np.full((len(mould_ids), replicas), np.nan)
    evaluations = np.full((len(mould_ids), replicas), np.nan)
    for i, m in enumerate(mould_ids):
        mould = mould_of(scene, dataset_seed, m)
        for k in range(replicas):
            r = simulate(mould.polygon, mould.tethers, scene.depth, solver, budget,
                         seed=replica_seed(dataset_seed, m, k))
            if r.status != "ok":
                continue
            fields[i, k] = scene_fields(r, scene)
            energy[i, k] = r.energy_per_cell
            evaluations[i, k] = r.info["evaluations"]
        if log is not None:
            log(f"fidelity: {solver} on mould {m}: E/cell {np.nanmean(energy[i]):.6f}, "
                f"{np.nanmean(evaluations[i]):.0f} evaluations")
    return fields, energy, evaluations


def paper_ensemble(scene, dataset_seed: int, folder=None):
    """The paper reference the product ships for this scene and seed, each mould at its
    highest rung with at least 2 runs (a rung whose first run alone is done leaves the mould
    at the rung below): (mould ids, normalised fields (M, R, 8, H, W), energies per cell
    (M, R), label such as 'anneal 1e5' or 'anneal 1e5/1e6'), NaN-padded; None when there is
    none (or the scene is not the preset the references were run in) or no mould has 2 runs."""
    from condor.model.scenes import PRESETS
    from condor.studies.paper_reference import budget_tag, load_reference, reference_moulds

    if scene.name not in PRESETS or scene != PRESETS[scene.name]:
        return None
    moulds = reference_moulds(scene.name, dataset_seed, folder)
    refs = [load_reference(scene.name, dataset_seed, m, folder=folder, min_runs=2)
            for m in moulds]
    keep = [i for i, runs in enumerate(refs) if len(runs) >= 2]
    if not keep:
        return None
    moulds = [moulds[i] for i in keep]
    refs = [refs[i] for i in keep]
    width = max(len(runs) for runs in refs)
    fields = np.full((len(moulds), width, 8, scene.pixels, scene.pixels), np.nan)
    energy = np.full((len(moulds), width), np.nan)
    for i, runs in enumerate(refs):
        for k, run in enumerate(runs):
            fields[i, k] = run.fields(scene)
            energy[i, k] = run.energy_per_cell
    rungs = {run.budget for runs in refs for run in runs}
    return moulds, fields, energy, "anneal " + "/".join(budget_tag(b) for b in sorted(rungs))


def fidelity_table(scene, dataset_seed: int, solvers, replicas: int, folder=None,
                   log=None) -> pd.DataFrame:
    """Each (solver, budget) of `solvers` against the paper reference the product ships for
    this scene and seed (`paper_ensemble`): FIDELITY_COLUMNS and the differences of
    `fidelity_row`. Empty (the columns only) when no reference exists."""
    reference = paper_ensemble(scene, dataset_seed, folder)
    if reference is None:
        return pd.DataFrame(columns=list(FIDELITY_COLUMNS))
    moulds, ref_fields, ref_energy, label = reference
    rows = []
    for solver, budget in solvers:
        fields, energy, evaluations = solver_ensemble(scene, dataset_seed, moulds, solver,
                                                      budget, replicas, log)
        row = fidelity_row(solver, scene.name, label, fields, ref_fields, evaluations,
                           energy, ref_energy)
        row["moulds"] = " ".join(map(str, moulds))
        rows.append(row)
    return pd.DataFrame(rows)


def prediction_row(method: str, scene: str, reference: str, predicted, ref_fields,
                   moulds) -> dict:
    """A predictor's answers (M, 8, H, W), normalised, against the reference's expected fields:
    the noise-corrected RMS error (`estimators.mse_against_expected`) in the distance columns,
    one answer a mould (n_seeds 1), no simulation cost."""
    err = est.mse_against_expected(np.asarray(predicted, dtype=np.float64), ref_fields)
    distance, lo, hi = est.bootstrap_interval(err.corrected)
    diff = mean_orientation(predicted) - np.nanmean(mean_orientation(ref_fields), axis=1)
    row = {"method": method, "scene": scene, "reference": reference,
           "n_moulds": int(len(moulds)), "n_seeds": 1, "distance": distance,
           "distance_lo": lo, "distance_hi": hi,
           "replica_noise": est.root_mean(est.noise_ceiling(ref_fields)),
           "evaluations_per_mould": float("nan")}
    for name, values in zip(("sx2", "sy2", "sz2"), diff.T):
        row[f"{name}_difference"] = float(np.mean(values))
        row[f"{name}_difference_max"] = float(values[np.argmax(np.abs(values))])
    row["converged"] = bool(row["distance_hi"] <= SAME_STATES * row["replica_noise"])
    row["moulds"] = " ".join(map(str, moulds))
    return row
