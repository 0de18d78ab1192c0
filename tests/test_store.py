"""The dataset store: creation, per-sample visibility, parallel writers, clear errors."""

import multiprocessing
import re
import shutil

import numpy as np
import pytest
import shapely
import xarray as xr
import zarr

from condor.data.geometry_arrays import MAX_TETHERS, MAX_VERTICES, outline_polygon
from condor.data.store import (FIELD_NAMES, FORMAT_CHANGES, FORMAT_VERSION, StoreError,
                               StoreSpec, assign_splits, create_store, open_store,
                               sample_index, sample_layout, write_expected, write_inputs,
                               write_sample)
from condor.data.store_check import (check_store, check_metadata, chunk_file, inputs_whole,
                                     restore_layout, scan_store, set_aside)

PIXELS = 8
MOULD_META = {"seed": 1, "symmetry": "cyclic", "order": 3, "removal": "none", "n_tethers": 6}
GEOMETRY = {"polygon": shapely.box(0.5, 0.5, 3.5, 3.5), "tethers": np.full((6, 3), 1.0)}


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


def test_pinned_samples_are_test_samples_and_leave_a_plain_split_alone():
    plain = assign_splits(200, 20, 0.1, seed=3)
    train = [i for i, s in enumerate(plain) if s == "train"][:5]
    pinned = assign_splits(200, 20, 0.1, seed=3, pinned=train + [250])  # 250: not a sample
    assert all(pinned[i] == "test" for i in train)
    assert pinned.count("test") == 20 and pinned.count("val") == 18
    # the other test samples are the plain permutation's first ones: 15 of the 20 kept
    assert sum(a == b == "test" for a, b in zip(plain, pinned)) == 15
    already = [i for i, s in enumerate(plain) if s == "test"][:7]
    assert assign_splits(200, 20, 0.1, seed=3, pinned=already) == plain
    with pytest.raises(ValueError, match="paper reference"):
        assign_splits(200, 4, 0.1, seed=3, pinned=train)


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
    write_inputs(path, 2, np.ones((2, PIXELS, PIXELS), "uint8"), MOULD_META, lattice=np.zeros((2, PIXELS, PIXELS), np.float32), **GEOMETRY)
    states = check_store(path).set_index("sample")["state"]
    assert states[2] == "pending" and states[1] == "missing"
    write_sample(path, 2, fake_fields(2), sim_meta(), "ok")
    write_inputs(path, 3, np.zeros((2, PIXELS, PIXELS), "uint8"), MOULD_META, lattice=np.zeros((2, PIXELS, PIXELS), np.float32), **GEOMETRY)
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
    write_inputs(path, 0, np.ones((2, PIXELS, PIXELS), "uint8"), MOULD_META, lattice=np.zeros((2, PIXELS, PIXELS), np.float32), **GEOMETRY)
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
        write_inputs(path, 6, np.ones((2, PIXELS, PIXELS)), MOULD_META, lattice=np.zeros((2, PIXELS, PIXELS), np.float32), **GEOMETRY)
    with pytest.raises(StoreError, match="outside"):
        write_sample(path, 6, fake_fields(0), sim_meta(), "ok")
    with pytest.raises(ValueError, match="shape"):
        write_inputs(path, 0, np.ones((2, PIXELS + 1, PIXELS)), MOULD_META, lattice=np.zeros((2, PIXELS + 1, PIXELS), np.float32), **GEOMETRY)
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
        write_inputs(path, sample, np.ones((2, PIXELS, PIXELS), "uint8"), MOULD_META, lattice=np.zeros((2, PIXELS, PIXELS), np.float32), **GEOMETRY)
        write_sample(path, sample, fake_fields(sample), sim_meta(), "ok")
    chunk = next((path / "fields" / "c" / "1").rglob("*"))
    while chunk.is_dir():
        chunk = next(chunk.iterdir())
    chunk.write_bytes(chunk.read_bytes()[:10])
    states = check_store(path, deep=True)["state"]
    assert states[0] == "ok" and states[1] == "corrupt"


def _write_one(args):
    path, sample = args
    write_inputs(path, sample, np.full((2, PIXELS, PIXELS), sample % 2, "uint8"), MOULD_META, lattice=np.zeros((2, PIXELS, PIXELS), np.float32), **GEOMETRY)
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
    write_inputs(path, 1, np.ones((2, PIXELS, PIXELS), "uint8"), MOULD_META, lattice=np.zeros((2, PIXELS, PIXELS), np.float32), **GEOMETRY)
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
        write_inputs(path, sample, np.ones((2, PIXELS, PIXELS), "uint8"), MOULD_META, lattice=np.zeros((2, PIXELS, PIXELS), np.float32), **GEOMETRY)
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
    write_inputs(path, 1, np.ones((2, PIXELS, PIXELS), "uint8"), MOULD_META, lattice=lattice, **GEOMETRY)
    ds = open_store(path)
    assert ds["lattice"].dims == ("sample", "cell", "y", "x")
    assert list(ds["cell"].values) == ["mobile", "fixed"]
    np.testing.assert_array_equal(ds["lattice"].values[1], lattice)
    bad = lattice.copy()
    bad[0, 1, 1] = np.nan
    with pytest.raises(ValueError, match="lattice channels of mould 0 hold NaN"):
        write_inputs(path, 0, np.ones((2, PIXELS, PIXELS), "uint8"), MOULD_META, lattice=bad, **GEOMETRY)
    with pytest.raises(ValueError, match="lattice for mould 0 have shape"):
        write_inputs(path, 0, np.ones((2, PIXELS, PIXELS), "uint8"), MOULD_META,
                     lattice=lattice[:1], **GEOMETRY)
    assert check_store(path).set_index("sample").loc[0, "state"] == "missing"  # nothing written


# --- every chunk of every array: chunk files, not folders; derived and metadata arrays -------

COUNTS = (1, 3, 1, 2)  # moulds 1 and 3 replicated: samples 0-3, then 4, 5 (mould 1), 6 (mould 3)


def _replicated(tmp_path):
    """A finished store with replicated moulds and their expected fields."""
    path = tmp_path / "d.zarr"
    create_store(path, spec(n=len(COUNTS), replicas=COUNTS))
    lattice = np.random.default_rng(1).random((2, PIXELS, PIXELS)).astype(np.float32)
    for mould in range(len(COUNTS)):
        write_inputs(path, mould, np.ones((2, PIXELS, PIXELS), "uint8"), MOULD_META, lattice=lattice, **GEOMETRY)
    for sample in range(sum(COUNTS)):
        write_sample(path, sample, fake_fields(sample), sim_meta(), "ok")
    write_expected(path)
    return path


def _files(path):
    return {p.relative_to(path): p.read_bytes() for p in sorted(path.rglob("*")) if p.is_file()}


def _damaged(path, deep=False):
    return {(d.array, d.index) for d in scan_store(path, deep=deep).damage}


@pytest.mark.parametrize("array, index", [
    ("fields", 3), ("fields", 5), ("inputs", 2), ("lattice", 6), ("energy", 1), ("seed", 0),
    ("outline_x", 4), ("outline_vertices", 2), ("tether_r", 0),
    ("status", 4), ("split", 1), ("mould", 6), ("replica", 5), ("fields_mean", 1),
    ("fields_std", 0), ("field", 0), ("replicated", 0)])
def test_a_deleted_chunk_file_of_any_array_is_found_without_decoding(tmp_path, array, index):
    """The file, not its folder c/<i>, which survives: the fast check lists chunk files."""
    path = _replicated(tmp_path)
    assert scan_store(path).damage == []
    ndim = zarr.open_array(path / array).ndim
    chunk_file(path, array, index, ndim).unlink()
    assert (path / array / "c" / str(index)).exists() or ndim == 1
    found = _damaged(path)
    if array == "status":  # a sample without its status reads as not yet simulated
        assert check_store(path).set_index("sample").loc[index, "state"] == "pending"
    else:
        assert found == {(array, index)}
    if array in ("fields", "inputs", "lattice", "energy", "seed", "split", "mould", "replica",
                 "outline_x", "outline_vertices", "tether_r"):
        table = check_store(path).set_index("sample")
        assert table.loc[index, "state"] == "corrupt" and table.loc[index, "lost"] == array


def test_the_expected_fields_not_written_are_said_so(tmp_path):
    path = _replicated(tmp_path)
    (path / "n_replicas_ok" / "c" / "0").unlink()
    check = scan_store(path)
    assert not check.derived and check.damage == []  # what the dataset step writes again


@pytest.mark.parametrize("cut", [1, 9, -5])
def test_a_truncated_or_extended_chunk_is_found_without_decoding(tmp_path, cut):
    path = _replicated(tmp_path)
    for array, index in (("fields", 4), ("inputs", 0), ("energy", 2), ("fields_mean", 1),
                         ("split", 3), ("n_replicas_ok", 0)):
        chunk = chunk_file(path, array, index, zarr.open_array(path / array).ndim)
        data = chunk.read_bytes()
        chunk.write_bytes(data[:-cut] if cut > 0 else data + bytes(-cut))
    assert _damaged(path) == {("fields", 4), ("inputs", 0), ("energy", 2), ("fields_mean", 1),
                              ("split", 3), ("n_replicas_ok", 0)}


def test_a_chunk_of_another_array_is_found_without_decoding(tmp_path):
    path = _replicated(tmp_path)
    shutil.copy(chunk_file(path, "lattice", 2, 4), chunk_file(path, "fields", 2, 4))
    (problem,) = [d.problem for d in scan_store(path).damage]
    assert "decodes to" in problem


def test_deep_decodes_every_chunk_of_every_array(tmp_path):
    """A flipped checksum byte leaves the frame whole: only decoding finds it, in any array."""
    path = _replicated(tmp_path)
    flipped = {("fields", 1), ("inputs", 3), ("lattice", 0), ("energy", 6), ("solver", 2),
               ("seed", 5), ("split", 4), ("fields_mean", 0), ("fields_std", 1)}
    for array, index in flipped:
        chunk = chunk_file(path, array, index, zarr.open_array(path / array).ndim)
        data = bytearray(chunk.read_bytes())
        data[-1] ^= 0x01
        chunk.write_bytes(bytes(data))
    fast = _damaged(path)
    assert fast == {("split", 4)}  # the layout is decoded by the fast check too
    deep = scan_store(path, deep=True)
    assert {(d.array, d.index) for d in deep.damage} == flipped
    assert all("checksum" in d.problem for d in deep.damage)
    assert set(deep.samples.query("state == 'corrupt'")["sample"]) == {1, 3, 0, 6, 2, 5, 4}


def test_deep_finds_a_blank_mould_and_nan_fields(tmp_path):
    path = _replicated(tmp_path)
    group = zarr.open_group(path, mode="r+")
    group["inputs"][2] = np.full((2, PIXELS, PIXELS), 7, "uint8")
    mean = group["fields_mean"][1]
    mean[3, 2, 1] = np.nan
    group["fields_mean"][1] = mean
    assert _damaged(path) == set()
    assert _damaged(path, deep=True) == {("inputs", 2), ("fields_mean", 1)}


@pytest.mark.parametrize("array, index, change", [
    ("fields_mean", 1, lambda v: v * 1.5),        # issue 44: through zarr, a valid checksum
    ("fields_std", 0, lambda v: v + 1e-3),
    ("inputs", 5, lambda v: np.where(np.indices(v.shape).sum(0) == 0, 0, v).astype(v.dtype)),
    # ^ a replica's copy of its mould's inputs (a pixel off)
    ("seed", 6, lambda v: v + 1),                 # ... and of its metadata
    ("status", 2, lambda v: "failed: diverged"),  # a flag that its fields contradict
])
def test_deep_recomputes_what_the_store_derives(tmp_path, array, index, change):
    """A derived array rewritten with a valid checksum: the expected fields differ from the
    mean and spread of their ok replicas, recomputed; a replica's copy of its mould's inputs
    or metadata differs from replica 0's. The fast check reads no grid and does not see it."""
    path = _replicated(tmp_path)
    group = zarr.open_group(path, mode="r+")
    group[array][index] = change(group[array][index])
    assert _damaged(path) == set()
    check = scan_store(path, deep=True)
    assert {(d.array, d.index) for d in check.damage} == {(array, index)}
    assert "differs from" in check.damage[0].problem or array == "status"
    assert ("recomputed" if array.startswith("fields") else "replica 0" if array != "status"
            else "fields are written") in check.damage[0].problem


def test_a_split_other_than_the_configs_is_found_by_the_fast_check(tmp_path):
    path = _replicated(tmp_path)
    split = spec(n=len(COUNTS), replicas=COUNTS).split
    assert _damaged(path) == set() and scan_store(path, split=split).damage == []
    group = zarr.open_group(path, mode="r+")
    group["split"][2] = "test" if split[2] != "test" else "train"
    assert _damaged(path) == set()  # a valid split name: only the config's split tells
    damage = scan_store(path, split=split).damage
    assert [(d.array, d.index) for d in damage] == [("split", 2)]
    assert "the data configuration's split says" in damage[0].problem
    restore_layout(path, split)
    assert scan_store(path, deep=True, split=split).damage == []


def test_set_aside_moves_damaged_chunks_out_for_the_fast_check_to_find(tmp_path):
    path = _replicated(tmp_path)
    chunk = chunk_file(path, "energy", 2, 1)
    data = bytearray(chunk.read_bytes())
    data[-1] ^= 0x01
    chunk.write_bytes(bytes(data))
    aside = set_aside(path, scan_store(path, deep=True).damage)
    assert aside == tmp_path / "d.zarr.damaged"
    assert (aside / "energy" / "c" / "2").read_bytes() == bytes(data)
    assert {(d.array, d.index, d.problem) for d in scan_store(path).damage} == {
        ("energy", 2, "is missing")}


def test_restore_layout_writes_the_layout_again_bit_for_bit(tmp_path):
    path = _replicated(tmp_path)
    before = _files(path)
    for array, index in (("split", 1), ("mould", 6), ("replica", 5), ("field", 0),
                         ("sample", 0), ("replicated", 0)):
        chunk_file(path, array, index, 1).unlink()
    chunk = chunk_file(path, "cell", 0, 1)
    chunk.write_bytes(chunk.read_bytes()[:-3])
    assert len(_damaged(path)) == 7
    split = spec(n=len(COUNTS), replicas=COUNTS).split
    assert len(restore_layout(path, split)) == 7
    assert _files(path) == before and scan_store(path, deep=True).damage == []
    assert restore_layout(path, split) == []


def test_inputs_whole_names_a_mould_whose_inputs_were_lost(tmp_path):
    path = _replicated(tmp_path)
    assert all(inputs_whole(path, m) for m in range(len(COUNTS)))
    chunk_file(path, "lattice", 5, 4).unlink()  # replica 2 of mould 1
    chunk = chunk_file(path, "inputs_ready", 3, 1)
    data = bytearray(chunk.read_bytes())
    data[-1] ^= 0x01
    chunk.write_bytes(bytes(data))
    assert [inputs_whole(path, m) for m in range(len(COUNTS))] == [True, False, True, False]


# --- the mould's geometry (issue 32, item 4) ---------------------------------------------------


def test_geometry_reaches_every_replica_exactly_with_holes_and_cf_attributes(tmp_path):
    path = tmp_path / "d.zarr"
    create_store(path, spec(n=len(COUNTS), replicas=COUNTS, pixel_size=0.5))
    ring = shapely.Point(2.0, 2.0).buffer(1.7, quad_segs=5)  # irrational vertices: exactness
    holed = ring.difference(shapely.box(1.6, 1.6, 2.1, 2.1)).difference(
        shapely.Point(2.9, 2.0).buffer(0.2, quad_segs=2))
    assert len(holed.interiors) == 2
    tethers = np.random.default_rng(2).random((6, 3)) + [1.0, 1.0, 0.05]
    write_inputs(path, 1, np.ones((2, PIXELS, PIXELS), "uint8"), MOULD_META,
                 lattice=np.zeros((2, PIXELS, PIXELS), np.float32), polygon=holed, tethers=tethers)
    ds = open_store(path)
    assert ds["outline_x"].dims == ("sample", "vertex") and ds.sizes["vertex"] == MAX_VERTICES
    assert ds["tether_r"].dims == ("sample", "tether") and ds.sizes["tether"] == MAX_TETHERS
    for name in ("outline_x", "outline_y", "tether_x", "tether_y", "tether_r"):
        assert ds[name].dtype == np.float64 and ds[name].attrs["units"] == "l0", name
        assert ds[name].attrs["long_name"], name
    assert "frame of the x coordinate" in ds["outline_x"].attrs["frame"]
    assert "lower edge" in ds["tether_y"].attrs["frame"]
    count = len(holed.exterior.coords) + sum(len(r.coords) + 1 for r in holed.interiors)
    for sample in (1, 4, 5):  # every replica of mould 1
        x, y = ds["outline_x"].values[sample], ds["outline_y"].values[sample]
        assert int(ds["outline_vertices"].values[sample]) == count
        assert np.isnan(x[count:]).all() and np.isfinite(x[:len(holed.exterior.coords)]).all()
        back = outline_polygon(x, y, count)
        assert back.equals_exact(holed, 0.0) and len(back.interiors) == 2
        np.testing.assert_array_equal(shapely.get_coordinates(back),
                                      shapely.get_coordinates(holed))
        stored = np.column_stack([ds[f"tether_{a}"].values[sample] for a in "xyr"])
        np.testing.assert_array_equal(stored[:6], tethers)
        assert np.isnan(stored[6:]).all()
    # a mould not yet written holds the fill values
    assert int(ds["outline_vertices"].values[0]) == -1 and np.isnan(ds["outline_x"].values[0]).all()
    assert check_metadata(path) == [] and scan_store(path, deep=True).damage == []


def test_geometry_that_does_not_fit_is_refused_by_value_and_nothing_is_written(tmp_path):
    path = tmp_path / "d.zarr"
    create_store(path, spec(n=2))
    masks, lattice = np.ones((2, PIXELS, PIXELS), "uint8"), np.zeros((2, PIXELS, PIXELS), np.float32)
    fine = shapely.box(0.5, 0.5, 3.5, 3.5)
    dense = shapely.Point(2.0, 2.0).buffer(1.5, quad_segs=600)
    n = len(dense.exterior.coords)
    assert n > MAX_VERTICES
    with pytest.raises(ValueError, match=f"mould 0: the outline needs {n} entries.*at most "
                       f"{MAX_VERTICES}"):
        write_inputs(path, 0, masks, MOULD_META, lattice=lattice, polygon=dense,
                     tethers=GEOMETRY["tethers"])
    many = np.full((MAX_TETHERS + 1, 3), 1.0)
    with pytest.raises(ValueError, match=f"{MAX_TETHERS + 1} tethers.*at most {MAX_TETHERS}"):
        write_inputs(path, 0, masks, {**MOULD_META, "n_tethers": MAX_TETHERS + 1},
                     lattice=lattice, polygon=fine, tethers=many)
    with pytest.raises(ValueError, match="MultiPolygon"):
        write_inputs(path, 0, masks, MOULD_META, lattice=lattice, tethers=GEOMETRY["tethers"],
                     polygon=fine.union(shapely.box(5, 5, 6, 6)))
    with pytest.raises(ValueError, match="3 tethers given.*n_tethers = 6"):
        write_inputs(path, 0, masks, MOULD_META, lattice=lattice, polygon=fine,
                     tethers=np.full((3, 3), 1.0))
    with pytest.raises(ValueError, match="shape"):
        write_inputs(path, 0, masks, MOULD_META, lattice=lattice, polygon=fine,
                     tethers=np.full((6, 2), 1.0))
    assert check_store(path).set_index("sample").loc[0, "state"] == "missing"
    # the largest outline that fits is kept whole
    angle = np.linspace(0.0, 2 * np.pi, MAX_VERTICES - 1, endpoint=False)
    edge = shapely.Polygon(np.column_stack([2 + 1.5 * np.cos(angle), 2 + 1.5 * np.sin(angle)]))
    assert len(edge.exterior.coords) == MAX_VERTICES
    write_inputs(path, 1, masks, {**MOULD_META, "n_tethers": 0}, lattice=lattice, polygon=edge,
                 tethers=np.zeros((0, 3)))
    ds = open_store(path)
    assert int(ds["outline_vertices"].values[1]) == MAX_VERTICES
    assert outline_polygon(ds["outline_x"].values[1], ds["outline_y"].values[1],
                           MAX_VERTICES).equals_exact(edge, 0.0)
    assert np.isnan(ds["tether_x"].values[1]).all()


def test_a_store_of_an_older_format_is_refused_naming_what_it_lacks(tmp_path):
    import json

    path = _finished(tmp_path)
    root = json.loads((path / "zarr.json").read_text())
    root["attributes"]["format_version"] = FORMAT_VERSION - 1
    (path / "zarr.json").write_text(json.dumps(root))
    added = re.escape(FORMAT_CHANGES[FORMAT_VERSION])  # what the newest format adds
    with pytest.raises(StoreError, match=f"format version {FORMAT_VERSION - 1}, this code reads "
                       f"version {FORMAT_VERSION}.*{added}.*rebuild"):
        open_store(path)


def test_a_generated_mould_with_holes_and_the_most_tethers_round_trips(tmp_path):
    """Generated moulds have holes (the union of copies encloses them) and may keep every
    tether the generator's limit allows: seed 1's mould 2890 has 6 holes, its mould 1603 the
    36 tethers of MouldParams.max_tethers."""
    from condor.model.scenes import get_scene
    from condor.moulds.paper import generate_mould

    path = tmp_path / "d.zarr"
    create_store(path, spec(n=2))
    masks, lattice = np.ones((2, PIXELS, PIXELS), "uint8"), np.zeros((2, PIXELS, PIXELS), np.float32)
    paper = get_scene("paper")
    moulds = [generate_mould(1, 2890, paper), generate_mould(1, 1603, paper)]
    assert len(moulds[0].polygon.interiors) == 6 and moulds[1].n_tethers == MAX_TETHERS
    for k, made in enumerate(moulds):
        write_inputs(path, k, masks, {**MOULD_META, "n_tethers": made.n_tethers}, lattice=lattice,
                     polygon=made.polygon, tethers=made.tethers)
    ds = open_store(path)
    for k, made in enumerate(moulds):
        back = outline_polygon(ds["outline_x"].values[k], ds["outline_y"].values[k],
                               ds["outline_vertices"].values[k])
        assert back.equals_exact(made.polygon, 0.0)
        assert [r.coords[:] for r in back.interiors] == [r.coords[:] for r in made.polygon.interiors]
        stored = np.column_stack([ds[f"tether_{a}"].values[k] for a in "xyr"])[:made.n_tethers]
        np.testing.assert_array_equal(stored, made.tethers)
