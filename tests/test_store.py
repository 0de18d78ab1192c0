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
    check_metadata,
    create_store,
    open_store,
    sample_index,
    sample_layout,
    write_expected,
    write_inputs,
    write_sample,
)

PIXELS = 8
MOULD_META = {"seed": 1, "symmetry": "cyclic", "order": 3, "removal": "none", "n_tethers": 6}


def spec(n=6, seed=3, replicas=None, **attrs):
    return StoreSpec(n_moulds=n, pixels=PIXELS, seed=seed, split=assign_splits(n, 1, 0.2, seed),
                     attrs={"scene": {"name": "test"}, **attrs}, replicas=replicas)


def sim_meta(n_cells=100):
    return {"sim_seed": 5, "n_cells": n_cells, "energy": -1.5, "max_force": 1e-4,
            "solver": "hybrid", "solver_seconds": 0.25, "hardware": "test"}


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
    write_inputs(path, 2, np.ones((2, PIXELS, PIXELS), "uint8"), MOULD_META, lattice=np.zeros((2, PIXELS, PIXELS), np.float32))
    states = check_store(path).set_index("sample")["state"]
    assert states[2] == "pending" and states[1] == "missing"
    write_sample(path, 2, fake_fields(2), sim_meta(), "ok")
    write_inputs(path, 3, np.zeros((2, PIXELS, PIXELS), "uint8"), MOULD_META, lattice=np.zeros((2, PIXELS, PIXELS), np.float32))
    write_sample(path, 3, None, sim_meta(), "folded lattice: 12 inverted tetrahedra")
    table = check_store(path, deep=True).set_index("sample")
    assert table.loc[2, "state"] == "ok"
    assert table.loc[3, "state"] == "failed"
    assert table.loc[3, "status"].startswith("folded")
    ds = open_store(path)
    np.testing.assert_array_equal(ds["fields"].isel(sample=2).values, fake_fields(2))
    assert np.isnan(ds["fields"].isel(sample=3).values).all()  # failures write no fields
    assert int(ds["n_cells"].values[2]) == 100


def test_existing_store_is_kept_and_mismatch_is_refused(tmp_path):
    path = tmp_path / "d.zarr"
    create_store(path, spec())
    write_inputs(path, 0, np.ones((2, PIXELS, PIXELS), "uint8"), MOULD_META, lattice=np.zeros((2, PIXELS, PIXELS), np.float32))
    assert not create_store(path, spec())  # same spec: kept, data intact
    assert check_store(path)["state"][0] == "pending"
    with pytest.raises(StoreError, match="seed"):
        create_store(path, spec(seed=4))
    with pytest.raises(StoreError, match="n_moulds"):
        create_store(path, spec(n=7))
    with pytest.raises(StoreError, match="replicas"):
        create_store(path, spec(replicas=(1, 1, 2, 1, 1, 1)))
    assert check_store(path)["state"][0] == "pending"  # refusing lost nothing


def test_bad_writes_are_refused(tmp_path):
    path = tmp_path / "d.zarr"
    create_store(path, spec())
    with pytest.raises(StoreError, match="not in the store"):
        write_inputs(path, 6, np.ones((2, PIXELS, PIXELS)), MOULD_META, lattice=np.zeros((2, PIXELS, PIXELS), np.float32))
    with pytest.raises(StoreError, match="outside"):
        write_sample(path, 6, fake_fields(0), sim_meta(), "ok")
    with pytest.raises(ValueError, match="shape"):
        write_inputs(path, 0, np.ones((2, PIXELS + 1, PIXELS)), MOULD_META, lattice=np.zeros((2, PIXELS + 1, PIXELS), np.float32))
    nan_fields = fake_fields(0)
    nan_fields[3, 2, 2] = np.nan
    with pytest.raises(ValueError, match="NaN"):
        write_sample(path, 0, nan_fields, sim_meta(), "ok")
    assert check_store(path)["status"][0] == ""


def test_foreign_and_truncated_stores_give_clear_errors(tmp_path):
    with pytest.raises(StoreError, match="no dataset store"):
        open_store(tmp_path / "absent.zarr")
    foreign = tmp_path / "foreign.zarr"
    zarr.open_group(foreign, mode="w").create_array("x", shape=(3,), dtype="int8")
    with pytest.raises(StoreError, match="not a condor dataset"):
        open_store(foreign)
    not_zarr = tmp_path / "text.zarr"
    not_zarr.mkdir()
    (not_zarr / "zarr.json").write_text("{ this is not json")
    with pytest.raises(StoreError, match="not a readable Zarr store"):
        open_store(not_zarr)
    truncated = tmp_path / "trunc.zarr"
    create_store(truncated, spec())
    shutil.rmtree(truncated / "fields")
    with pytest.raises(StoreError, match="truncated.*fields"):
        check_store(truncated)


def test_corrupt_chunk_is_reported_not_raised(tmp_path):
    path = tmp_path / "d.zarr"
    create_store(path, spec())
    for sample in (0, 1):
        write_inputs(path, sample, np.ones((2, PIXELS, PIXELS), "uint8"), MOULD_META, lattice=np.zeros((2, PIXELS, PIXELS), np.float32))
        write_sample(path, sample, fake_fields(sample), sim_meta(), "ok")
    chunk = next((path / "fields" / "c" / "1").rglob("*"))
    while chunk.is_dir():
        chunk = next(chunk.iterdir())
    chunk.write_bytes(chunk.read_bytes()[:10])
    states = check_store(path, deep=True)["state"]
    assert states[0] == "ok" and states[1] == "corrupt"


def _write_one(args):
    path, sample = args
    write_inputs(path, sample, np.full((2, PIXELS, PIXELS), sample % 2, "uint8"), MOULD_META, lattice=np.zeros((2, PIXELS, PIXELS), np.float32))
    write_sample(path, sample, fake_fields(sample), sim_meta(n_cells=sample), "ok")


def test_parallel_writers_lose_nothing(tmp_path):
    path = tmp_path / "d.zarr"
    n = 24
    create_store(path, spec(n=n))
    with multiprocessing.get_context("spawn").Pool(4) as pool:
        pool.map(_write_one, [(str(path), s) for s in range(n)], chunksize=1)
    assert (check_store(path, deep=True)["state"] == "ok").all()
    ds = open_store(path)
    np.testing.assert_array_equal(ds["n_cells"].values, np.arange(n))
    for sample in range(n):
        np.testing.assert_array_equal(ds["fields"].isel(sample=sample).values, fake_fields(sample))


# --- replicas, expected fields, checks without decompression, checksums --------------------


def test_replica_layout_round_trips_and_keeps_sample_equal_to_mould():
    counts = (1, 3, 1, 2, 1)
    moulds, replicas = sample_layout(counts)
    assert list(moulds[:5]) == [0, 1, 2, 3, 4] and list(replicas[:5]) == [0] * 5
    pairs = {(int(m), int(r)) for m, r in zip(moulds, replicas)}
    assert pairs == {(m, r) for m, c in enumerate(counts) for r in range(c)}
    for s, (m, r) in enumerate(zip(moulds, replicas)):
        assert sample_index(counts, int(m), int(r)) == s


def test_inputs_reach_every_replica_and_expected_fields_are_their_mean(tmp_path):
    path = tmp_path / "d.zarr"
    counts = (1, 3, 1, 1, 1, 2)
    create_store(path, spec(replicas=counts))
    rng = np.random.default_rng(0)
    write_inputs(path, 1, np.ones((2, PIXELS, PIXELS), "uint8"), MOULD_META, lattice=np.zeros((2, PIXELS, PIXELS), np.float32))
    replicas = [rng.random((8, PIXELS, PIXELS)).astype("float32") for _ in range(3)]
    for r, fields in enumerate(replicas):
        write_sample(path, sample_index(counts, 1, r), fields, sim_meta(), "ok")
    assert write_expected(path) == 2
    ds = open_store(path)
    assert list(ds["replicated"].values) == [1, 5]
    assert (ds["inputs"].values[[1, 6, 7]] == 1).all() and (ds["inputs_ready"].values[[1, 6, 7]] == 1).all()
    stack = np.stack(replicas).astype(np.float64)
    np.testing.assert_allclose(ds["fields_mean"].values[0], stack.mean(axis=0), rtol=1e-6)
    np.testing.assert_allclose(ds["fields_std"].values[0], stack.std(axis=0, ddof=1), rtol=1e-5)
    assert list(ds["n_replicas_ok"].values) == [3, 0]
    assert np.isnan(ds["fields_mean"].values[1]).all()  # mould 5 has no ok replica yet
    assert set(ds["split"].values[[1, 6, 7]]) == {ds["split"].values[1]}


def _finished(tmp_path, n=4):
    path = tmp_path / "d.zarr"
    create_store(path, spec(n=n))
    for sample in range(n):
        write_inputs(path, sample, np.ones((2, PIXELS, PIXELS), "uint8"), MOULD_META, lattice=np.zeros((2, PIXELS, PIXELS), np.float32))
        write_sample(path, sample, fake_fields(sample), sim_meta(), "ok")
    return path


def test_a_lost_chunk_is_found_without_decoding(tmp_path):
    path = _finished(tmp_path)
    shutil.rmtree(path / "fields" / "c" / "2")
    table = check_store(path).set_index("sample")
    assert table.loc[2, "state"] == "corrupt" and table.loc[2, "lost"] == "fields"
    assert (table.drop(index=2)["state"] == "ok").all()
    shutil.rmtree(path / "inputs" / "c" / "0")
    assert check_store(path).set_index("sample").loc[0, "lost"] == "inputs"
    shutil.rmtree(path / "lattice" / "c" / "3")
    table = check_store(path).set_index("sample")
    assert table.loc[3, "state"] == "corrupt" and table.loc[3, "lost"] == "lattice"
    assert table.loc[1, "state"] == "ok"


def test_a_flipped_byte_fails_its_checksum(tmp_path):
    path = _finished(tmp_path)
    chunk = next(p for p in (path / "fields" / "c" / "1").rglob("*") if p.is_file())
    data = bytearray(chunk.read_bytes())
    data[len(data) // 2] ^= 0x01
    chunk.write_bytes(bytes(data))
    assert check_store(path).set_index("sample").loc[1, "state"] == "ok"  # listing only
    deep = check_store(path, deep=True).set_index("sample")["state"]
    assert deep[1] == "corrupt" and (deep.drop(index=1) == "ok").all()


def test_edited_metadata_is_found(tmp_path):
    import json

    path = _finished(tmp_path)
    assert check_metadata(path) == []
    meta_path = path / "fields" / "zarr.json"
    meta = json.loads(meta_path.read_text())
    meta["data_type"] = "float64"
    meta_path.write_text(json.dumps(meta))
    assert any("fields" in p and "consolidated" in p for p in check_metadata(path))
    root = json.loads((path / "zarr.json").read_text())
    root["attributes"]["n_samples"] = 99
    (path / "zarr.json").write_text(json.dumps(root))
    with pytest.raises(StoreError, match="disagree"):
        check_store(path)


def test_lattice_channels_round_trip_and_bad_ones_are_refused(tmp_path):
    path = tmp_path / "d.zarr"
    create_store(path, spec(n=2))
    lattice = np.random.default_rng(0).random((2, PIXELS, PIXELS)).astype(np.float32)
    write_inputs(path, 1, np.ones((2, PIXELS, PIXELS), "uint8"), MOULD_META, lattice=lattice)
    ds = open_store(path)
    assert ds["lattice"].dims == ("sample", "cell", "y", "x")
    assert list(ds["cell"].values) == ["mobile", "fixed"]
    np.testing.assert_array_equal(ds["lattice"].values[1], lattice)
    bad = lattice.copy()
    bad[0, 1, 1] = np.nan
    with pytest.raises(ValueError, match="lattice channels of mould 0 hold NaN"):
        write_inputs(path, 0, np.ones((2, PIXELS, PIXELS), "uint8"), MOULD_META, lattice=bad)
    with pytest.raises(ValueError, match="lattice for mould 0 have shape"):
        write_inputs(path, 0, np.ones((2, PIXELS, PIXELS), "uint8"), MOULD_META,
                     lattice=lattice[:1])
    assert check_store(path).set_index("sample").loc[0, "state"] == "missing"  # nothing written
