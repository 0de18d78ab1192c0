"""The dataset store: creation, per-sample visibility, parallel writers, clear errors."""

import multiprocessing
import shutil

import numpy as np
import pytest
import xarray as xr
import zarr

from condor.store import (
    FIELD_NAMES,
    StoreError,
    StoreSpec,
    assign_splits,
    check_store,
    create_store,
    open_dataset,
    write_inputs,
    write_sample,
)

PIXELS = 8
MOULD_META = {"seed": 1, "symmetry": "cyclic", "order": 3, "removal": "none", "n_tethers": 6}


def spec(n=6, seed=3, **attrs):
    return StoreSpec(n_samples=n, pixels=PIXELS, seed=seed, split=assign_splits(n, 1, 0.2, seed),
                     attrs={"scene": {"name": "test"}, **attrs})


def sim_meta(n_cells=100):
    return {"n_cells": n_cells, "energy": -1.5, "solver": "hybrid", "solver_seconds": 0.25}


def fake_fields(sample):
    rng = np.random.default_rng(sample)
    return rng.random((len(FIELD_NAMES), PIXELS, PIXELS)).astype("float32")


def test_split_is_deterministic_and_sized():
    a = assign_splits(100, 10, 0.1, seed=5)
    assert a == assign_splits(100, 10, 0.1, seed=5)
    assert a != assign_splits(100, 10, 0.1, seed=6)
    assert a.count("test") == 10 and a.count("val") == 9 and a.count("train") == 81


@pytest.mark.parametrize("args", [(10, 10, 0.1), (10, -1, 0.1), (10, 2, 1.0)])
def test_split_rejects_bad_sizes(args):
    with pytest.raises(ValueError):
        assign_splits(*args, seed=0)


def test_new_store_opens_with_xarray_and_is_empty(tmp_path):
    path = tmp_path / "d.zarr"
    assert create_store(path, spec())
    ds = xr.open_zarr(path)
    assert ds["inputs"].dims == ("sample", "channel", "y", "x")
    assert ds["fields"].shape == (6, 8, PIXELS, PIXELS)
    assert list(ds["field"].values.astype(str)) == list(FIELD_NAMES)
    assert ds.attrs["scene"] == {"name": "test"}
    assert set(check_store(path)["state"]) == {"missing"}


def test_sample_visible_only_when_status_written(tmp_path):
    path = tmp_path / "d.zarr"
    create_store(path, spec())
    write_inputs(path, 2, np.ones((2, PIXELS, PIXELS), "uint8"), MOULD_META)
    states = check_store(path).set_index("sample")["state"]
    assert states[2] == "pending" and states[1] == "missing"
    write_sample(path, 2, fake_fields(2), sim_meta(), "ok")
    write_inputs(path, 3, np.zeros((2, PIXELS, PIXELS), "uint8"), MOULD_META)
    write_sample(path, 3, None, sim_meta(), "folded lattice: 12 inverted tetrahedra")
    table = check_store(path, deep=True).set_index("sample")
    assert table.loc[2, "state"] == "ok"
    assert table.loc[3, "state"] == "failed"
    assert table.loc[3, "status"].startswith("folded")
    ds = open_dataset(path)
    np.testing.assert_array_equal(ds["fields"].isel(sample=2).values, fake_fields(2))
    assert np.isnan(ds["fields"].isel(sample=3).values).all()  # failures write no fields
    assert int(ds["n_cells"].values[2]) == 100


def test_existing_store_is_kept_and_mismatch_is_refused(tmp_path):
    path = tmp_path / "d.zarr"
    create_store(path, spec())
    write_inputs(path, 0, np.ones((2, PIXELS, PIXELS), "uint8"), MOULD_META)
    assert not create_store(path, spec())  # same spec: kept, data intact
    assert check_store(path)["state"][0] == "pending"
    with pytest.raises(StoreError, match="seed"):
        create_store(path, spec(seed=4))
    with pytest.raises(StoreError, match="n_samples"):
        create_store(path, spec(n=7))
    assert check_store(path)["state"][0] == "pending"  # refusing lost nothing


def test_bad_writes_are_refused(tmp_path):
    path = tmp_path / "d.zarr"
    create_store(path, spec())
    with pytest.raises(StoreError, match="outside"):
        write_inputs(path, 6, np.ones((2, PIXELS, PIXELS)), MOULD_META)
    with pytest.raises(ValueError, match="shape"):
        write_inputs(path, 0, np.ones((2, PIXELS + 1, PIXELS)), MOULD_META)
    nan_fields = fake_fields(0)
    nan_fields[3, 2, 2] = np.nan
    with pytest.raises(ValueError, match="NaN"):
        write_sample(path, 0, nan_fields, sim_meta(), "ok")
    assert check_store(path)["status"][0] == ""


def test_foreign_and_truncated_stores_give_clear_errors(tmp_path):
    with pytest.raises(StoreError, match="no dataset store"):
        open_dataset(tmp_path / "absent.zarr")
    foreign = tmp_path / "foreign.zarr"
    zarr.open_group(foreign, mode="w").create_array("x", shape=(3,), dtype="int8")
    with pytest.raises(StoreError, match="not a condor dataset"):
        open_dataset(foreign)
    not_zarr = tmp_path / "text.zarr"
    not_zarr.mkdir()
    (not_zarr / "zarr.json").write_text("{ this is not json")
    with pytest.raises(StoreError, match="not a readable Zarr store"):
        open_dataset(not_zarr)
    truncated = tmp_path / "trunc.zarr"
    create_store(truncated, spec())
    shutil.rmtree(truncated / "fields")
    with pytest.raises(StoreError, match="truncated.*fields"):
        check_store(truncated)


def test_corrupt_chunk_is_reported_not_raised(tmp_path):
    path = tmp_path / "d.zarr"
    create_store(path, spec())
    for sample in (0, 1):
        write_inputs(path, sample, np.ones((2, PIXELS, PIXELS), "uint8"), MOULD_META)
        write_sample(path, sample, fake_fields(sample), sim_meta(), "ok")
    chunk = next((path / "fields" / "c" / "1").rglob("*"))
    while chunk.is_dir():
        chunk = next(chunk.iterdir())
    chunk.write_bytes(chunk.read_bytes()[:10])
    states = check_store(path, deep=True)["state"]
    assert states[0] == "ok" and states[1] == "corrupt"


def _write_one(args):
    path, sample = args
    write_inputs(path, sample, np.full((2, PIXELS, PIXELS), sample % 2, "uint8"), MOULD_META)
    write_sample(path, sample, fake_fields(sample), sim_meta(n_cells=sample), "ok")


def test_parallel_writers_lose_nothing(tmp_path):
    path = tmp_path / "d.zarr"
    n = 24
    create_store(path, spec(n=n))
    with multiprocessing.get_context("spawn").Pool(4) as pool:
        pool.map(_write_one, [(str(path), s) for s in range(n)], chunksize=1)
    assert (check_store(path, deep=True)["state"] == "ok").all()
    ds = open_dataset(path)
    np.testing.assert_array_equal(ds["n_cells"].values, np.arange(n))
    for sample in range(n):
        np.testing.assert_array_equal(ds["fields"].isel(sample=sample).values, fake_fields(sample))
