"""condor.studies.scoring: the paired ratios, pooled ensembles and training subsets that the
surrogate studies (experiments/surrogate) share."""

from __future__ import annotations

import numpy as np
import pytest
import xarray as xr

from condor.studies import scoring
from condor.data.dataset import usable_samples
from condor.studies.recipes import Ensemble


def test_paired_ratio_is_the_root_of_the_mean_ratio_and_pairing_narrows_it():
    rng = np.random.default_rng(0)
    difficulty = rng.lognormal(0, 1, 60)  # the moulds' own difficulty, shared by both
    a = difficulty * (1 + 0.02 * rng.standard_normal(60))
    b = 0.81 * difficulty * (1 + 0.02 * rng.standard_normal(60))
    ratio, lo, hi = scoring.paired_ratio(a, b)
    assert ratio == pytest.approx(np.sqrt(b.mean() / a.mean()))
    assert lo < ratio < hi and hi < 0.95  # resolved below 1 though the moulds differ 10-fold
    # unpaired, the same errors would not resolve it: shuffling b breaks the pairs
    _, lo_unpaired, hi_unpaired = scoring.paired_ratio(a, rng.permutation(b))
    assert hi_unpaired - lo_unpaired > 3 * (hi - lo)
    assert scoring.paired_ratio(a, a)[0] == pytest.approx(1.0)
    # a noise-corrected error may be negative: its mean counts as 0
    assert scoring.paired_ratio([1.0, 1.0], [-0.5, 0.1])[0] == 0.0
    with pytest.raises(ValueError, match="same moulds"):
        scoring.paired_ratio(a, b[:-1])


def test_paired_rows_one_row_per_method_against_the_first_with_per_field_ratios():
    rng = np.random.default_rng(1)
    ref = rng.uniform(1, 2, (30, 2))
    better = ref * 0.64
    rows = scoring.paired_rows(["ref", "better"], [(ref.sum(1), ref), (better.sum(1), better)],
                               field_names=("P", "T"))
    assert list(rows["checkpoint"]) == ["better"] and rows.loc[0, "reference"] == "ref"
    assert rows.loc[0, "ratio"] == pytest.approx(0.8)
    assert rows.loc[0, "P:ratio"] == pytest.approx(0.8) and rows.loc[0, "T:ratio"] == pytest.approx(0.8)
    assert rows.loc[0, "moulds_better"] == 1.0
    plain = scoring.paired_rows(["a", "b", "c"], [ref[:, 0], ref[:, 0], better[:, 0]])
    assert list(plain["checkpoint"]) == ["b", "c"] and "P:ratio" not in plain
    with pytest.raises(ValueError):
        scoring.paired_rows(["a"], [ref[:, 0]])


def test_field_errors_are_zero_in_expectation_for_a_perfect_predictor():
    rng = np.random.default_rng(2)
    truth = rng.uniform(0, 1, (40, 8, 4, 4))
    replicas = truth[:, None] + 0.1 * rng.standard_normal((40, 6, 8, 4, 4))
    overall, per_field = scoring.field_errors(truth, replicas)
    assert overall.shape == (40,) and per_field.shape == (40, 8)
    assert abs(overall.mean()) < 0.1 * scoring.field_errors(truth + 0.3, replicas)[0].mean()


def _ensemble(n, replicas, pixel=0.5, offset=0.0):
    raw = np.full((n, replicas, 8, 4, 4), 1.0 + offset)
    return Ensemble(moulds=np.arange(n) + 10, raw=raw, n_cells=np.full(n, 100.0),
                    inputs=np.ones((n, 2, 4, 4)), pixel_size=pixel,
                    seconds=np.ones((n, replicas)), energy_per_cell=np.ones((n, replicas)),
                    lattice=np.zeros((n, 2, 4, 4)))


def test_pooled_ensemble_renumbers_and_pads_to_the_most_replicas():
    pooled = scoring.pooled_ensemble([_ensemble(2, 4), _ensemble(3, 20, offset=1.0)])
    assert list(pooled.moulds) == [0, 1, 2, 3, 4]
    assert pooled.raw.shape == (5, 20, 8, 4, 4) and pooled.seconds.shape == (5, 20)
    assert list(pooled.replica_counts) == [4, 4, 20, 20, 20]
    assert pooled.raw[4, 0, 0, 0, 0] == 2.0 and pooled.lattice.shape == (5, 2, 4, 4)
    with pytest.raises(ValueError, match="pixel size"):
        scoring.pooled_ensemble([_ensemble(1, 2), _ensemble(1, 2, pixel=0.25)])


def _dataset(split, status=None, mould=None, replica=None, scene="tiny"):
    n = len(split)
    return xr.Dataset(
        {"split": ("sample", np.array(split)),
         "status": ("sample", np.array(status or ["ok"] * n)),
         "mould": ("sample", np.array(mould if mould is not None else range(n))),
         "replica": ("sample", np.array(replica if replica is not None else [0] * n)),
         "fields": (("sample", "x"), np.arange(n * 2, dtype=float).reshape(n, 2))},
        coords={"sample": np.arange(n)}, attrs={"data_config": {"scene": scene}})


def test_first_training_moulds_keeps_the_first_n_usable_in_store_order():
    ds = _dataset(["train", "val", "train", "train", "test", "train"],
                  status=["ok", "ok", "failed: x", "ok", "ok", "ok"])
    two = scoring.first_training_moulds(ds, 2)
    assert list(usable_samples(two, "train")) == [0, 3]  # the failed sample never trains
    assert list(two["split"].values) == ["train", "val", "train", "train", "test", "unused"]
    with pytest.raises(ValueError, match="3 usable|holds 3"):
        scoring.first_training_moulds(ds, 4)


def test_study_dataset_labels_every_replica_of_a_mould():
    ds = _dataset(["train", "train", "val", "test", "train", "test", "test"],
                  mould=[0, 1, 2, 3, 4, 3, 3], replica=[0, 0, 0, 0, 0, 1, 2])
    out = scoring.study_dataset(ds, replica_ids=[3], n_train=1)
    assert list(out["split"].values) == ["train", "unused", "val", "test", "unused", "test", "test"]
    moved = scoring.study_dataset(ds, replica_ids=[1], val_ids=[0])
    assert list(moved["split"].values)[:3] == ["val", "test", "train"]


def test_with_training_moulds_appends_the_other_stores_training_split():
    ds = _dataset(["train", "test"])
    extra = _dataset(["train", "val", "train"])
    joined = scoring.with_training_moulds(ds, extra)
    assert list(joined["sample"].values) == [0, 1, 2, 4]  # its ids, after ds's
    assert list(joined["split"].values) == ["train", "test", "train", "train"]
    with pytest.raises(ValueError, match="another scene"):
        scoring.with_training_moulds(ds, _dataset(["train"], scene="default"))


def test_statistics_of_keeps_the_leading_shape():
    from condor.data.statistics import STATISTICS

    fields = np.random.default_rng(3).uniform(0, 1, (3, 2, 8, 6, 6))
    stats = scoring.statistics_of(fields, 0.5)
    assert stats.shape == (3, 2, len(STATISTICS))
    assert np.allclose(stats[1, 0], scoring.statistics_of(fields[1, 0], 0.5))
