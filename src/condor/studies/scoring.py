"""Scoring recipes the surrogate studies share (experiments/surrogate_*), written once.

- `paired_ratio`: the ratio of two methods' field errors on the same moulds, sqrt(mean b /
  mean a), with a bootstrap interval over moulds resampled together (the moulds' own
  difficulty cancels, so much smaller differences resolve than two separate intervals do);
- `paired_rows`: that ratio for each of several methods against the first, overall and per
  field;
- `field_errors`: per-mould squared errors against the replicas' expected fields, each field
  in units of its RMS over the replicas (overall and per field), what the ratios compare;
- `predict_replica_moulds`: a checkpoint's raw prediction of given moulds of a store;
- `statistics_of`: whole-mould statistics of fields of any leading shape;
- `pooled_ensemble`: one Ensemble of the replicated moulds of several ensembles (stores);
- `first_training_moulds`: a dataset whose training split keeps only its first n moulds;
- `study_dataset`: a store relabelled for a study (test = the replica moulds, train = the
  first n usable others);
- `with_training_moulds`: a dataset with another store's training moulds appended.
"""

from __future__ import annotations

from dataclasses import replace

import numpy as np
import pandas as pd

from condor.measures.estimators import bootstrap_interval, mse_against_expected
from condor.data.statistics import STATISTICS, mould_statistics


def _ratio(pairs: np.ndarray) -> float:
    """sqrt(mean of column 1 / mean of column 0); NaN when column 0's mean is not positive.
    A negative mean (noise-corrected errors can be) counts as 0."""
    base = pairs[:, 0].mean()
    if not base > 0:
        return float("nan")
    return float(np.sqrt(max(pairs[:, 1].mean(), 0.0) / base))


def paired_ratio(reference, other, seed: int = 0) -> tuple[float, float, float]:
    """(ratio, lo, hi): sqrt(mean(other) / mean(reference)) of per-mould squared errors
    (M,) on the same moulds, with its 95% bootstrap interval over moulds resampled in pairs.
    Below 1: `other` lies closer to the target than `reference`."""
    reference, other = np.asarray(reference, float), np.asarray(other, float)
    if reference.shape != other.shape or reference.ndim != 1:
        raise ValueError(f"paired errors need the same moulds: shapes {reference.shape}, "
                         f"{other.shape}")
    return bootstrap_interval(np.stack([reference, other], axis=1), _ratio, seed=seed)


def paired_rows(names, errors, field_names=None) -> pd.DataFrame:
    """One row per name after the first: its field error's ratio to the first's with the
    paired interval (`ratio`, `ratio_lo`, `ratio_hi`) and the share of moulds it does better
    on. `errors[i]` is per-mould squared errors (M,), or a pair (overall (M,), per field
    (M, F)) to add `<field>:ratio`, `<field>:lo`, `<field>:hi` for each of `field_names`."""
    names, errors = list(names), list(errors)
    if len(names) != len(errors) or len(names) < 2:
        raise ValueError("paired_rows needs a reference and at least one other, named")
    split = [e if isinstance(e, tuple) else (e, None) for e in errors]
    (ref_all, ref_fields), rows = split[0], []
    for name, (overall, per_field) in zip(names[1:], split[1:]):
        est, lo, hi = paired_ratio(ref_all, overall)
        row = {"reference": names[0], "checkpoint": name, "ratio": est, "ratio_lo": lo,
               "ratio_hi": hi, "moulds_better": float(np.mean(np.asarray(overall) < ref_all))}
        if per_field is not None and field_names is not None:
            for f, field in enumerate(field_names):
                est, lo, hi = paired_ratio(ref_fields[:, f], per_field[:, f])
                row.update({f"{field}:ratio": est, f"{field}:lo": lo, f"{field}:hi": hi})
        rows.append(row)
    return pd.DataFrame(rows)


def pooled_ensemble(ensembles):
    """One Ensemble (condor.studies.recipes) of every ensemble's moulds, renumbered 0..M-1;
    the per-replica arrays NaN-padded to the most replicas any of them holds."""
    parts = list(ensembles)
    if not parts:
        raise ValueError("no ensemble to pool")
    if len({e.pixel_size for e in parts}) != 1:
        raise ValueError(f"the ensembles differ in their pixel size: "
                         f"{sorted({e.pixel_size for e in parts})}")
    most = max(e.n_replicas for e in parts)

    def joined(name):
        arrays = [getattr(e, name) for e in parts]
        if any(a is None for a in arrays):
            return None
        if name in ("raw", "seconds", "energy_per_cell"):  # NaN-padded to the most replicas
            arrays = [np.pad(np.asarray(a, float),
                             [(0, 0), (0, most - a.shape[1])] + [(0, 0)] * (a.ndim - 2),
                             constant_values=np.nan) for a in arrays]
        return np.concatenate(arrays)

    return replace(parts[0], moulds=np.arange(sum(len(e.moulds) for e in parts)),
                   raw=joined("raw"), n_cells=joined("n_cells"), inputs=joined("inputs"),
                   seconds=joined("seconds"), energy_per_cell=joined("energy_per_cell"),
                   lattice=joined("lattice"))


def first_training_moulds(ds, n_train: int):
    """`ds` (an xarray Dataset with `split`) whose training split keeps its first `n_train`
    usable samples in store order; the rest are relabelled "unused". ValueError when it holds
    fewer."""
    from condor.surrogate.samples import usable_samples

    train = usable_samples(ds, "train")
    if n_train > len(train):
        raise ValueError(f"{n_train} training moulds asked, the dataset holds {len(train)}")
    split = np.asarray(ds["split"].values).astype("<U8").copy()
    split[train[n_train:]] = "unused"
    return ds.assign(split=("sample", split))


def with_training_moulds(ds, extra):
    """`ds` with the usable training moulds of `extra`, a store of the same scene, appended
    as training samples (renumbered after ds's; the per-mould replica tables dropped)."""
    import xarray as xr

    from condor.surrogate.samples import usable_samples

    scene = [d.attrs.get("data_config", {}).get("scene") for d in (ds, extra)]
    if scene[0] != scene[1]:
        raise ValueError(f"the extra training store has another scene ({scene[1]!r}, not "
                         f"{scene[0]!r})")
    extra = extra.isel(sample=usable_samples(extra, "train")).load()
    extra = extra.assign_coords(sample=extra["sample"].values + int(ds["sample"].max()) + 1)
    keep = [name for name in ds.data_vars if ds[name].dims[:1] == ("sample",)]
    joined = xr.concat([ds[keep], extra[keep]], dim="sample", data_vars="all",
                       coords="minimal", compat="override", join="override")
    joined.attrs = ds.attrs
    return joined


def field_errors(raw, replicas) -> tuple[np.ndarray, np.ndarray]:
    """Noise-corrected squared errors of predictions `raw` (M, 8, H, W) against the expected
    fields of `replicas` (M, R, 8, H, W): overall (M,) and per field (M, 8), each field in
    units of its RMS over the replicas (so that every field counts)."""
    raw, replicas = np.asarray(raw, np.float64), np.asarray(replicas, np.float64)
    scale = np.sqrt(np.nanmean(replicas ** 2, axis=(0, 1, 3, 4)))[None, :, None, None]
    overall = mse_against_expected(raw / scale, replicas / scale[:, None]).corrected
    per_field = mse_against_expected(raw / scale, replicas / scale[:, None],
                                     per_field=True).corrected
    return overall, per_field


def predict_replica_moulds(checkpoint, ds, mould_ids) -> np.ndarray:
    """A checkpoint's raw prediction (M, 8, H, W) of the moulds `mould_ids` of `ds` (their
    replica-0 samples: sample == mould), with the store's N_c and, for a checkpoint that reads
    them, its lattice channels."""
    from condor.surrogate.samples import model_inputs
    from condor.surrogate.predict import Predictor

    position = {int(m): i for i, m in enumerate(np.asarray(ds["sample"].values))}
    pos = [position[int(m)] for m in mould_ids]
    predictor = Predictor(checkpoint)
    lattice = model_inputs(ds, pos, "lattice") if predictor.needs_lattice else None
    return predictor(model_inputs(ds, pos, "mask"), n_cells=np.asarray(ds["n_cells"].values)[pos],
                     lattice=lattice).raw.astype(np.float64)


def statistics_of(fields, pixel_size: float) -> np.ndarray:
    """Whole-mould statistics (condor.data.statistics.STATISTICS) of fields (..., 8, H, W) ->
    (..., n_statistics); N_c is each field set's own density sum."""
    fields = np.asarray(fields)
    flat = fields.reshape(-1, *fields.shape[-3:])
    rows = [[mould_statistics(f, pixel_size)[k] for k in STATISTICS] for f in flat]
    return np.asarray(rows, dtype=np.float64).reshape(*fields.shape[:-3], len(STATISTICS))


def study_dataset(ds, replica_ids, n_train: int | None = None, val_ids=None):
    """`ds` (a store opened with condor.open_dataset) with its splits relabelled by mould
    (every replica of a mould takes its label): test = `replica_ids`, val = `val_ids` (default:
    the store's own val split), train = the other moulds whose replica 0 is usable, the first
    `n_train` by id when given; everything else "unused"."""
    mould = np.asarray(ds["mould"].values)
    first = np.asarray(ds["replica"].values) == 0  # sample == mould for these
    split = np.asarray(ds["split"].values).astype(str)
    status = np.asarray(ds["status"].values).astype(str)
    val = np.isin(mould, val_ids) if val_ids is not None else split == "val"
    test = np.isin(mould, replica_ids)
    pool = mould[first & (status == "ok") & ~val & ~test]
    if n_train is not None:
        if n_train > len(pool):
            raise ValueError(f"{n_train} training moulds asked, {len(pool)} usable")
        pool = pool[:n_train]
    labels = np.full(len(mould), "unused", dtype="<U8")
    labels[np.isin(mould, pool)], labels[val], labels[test] = "train", "val", "test"
    return ds.assign(split=("sample", labels))
