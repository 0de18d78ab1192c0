"""The dataset as a product (condor.dataset): open, select, statistics, a PyTorch DataLoader,
and a card whose numbers match the store."""

import os
import platform
import re

import numpy as np
import pandas as pd
import pytest
import torch

import condor
from condor.data import reader as dataset
from condor.data.store import StoreSpec, create_store, sample_index, write_inputs, write_sample

PIXELS = 8
REPLICAS = (1, 3, 1, 1, 2, 1)
SPLIT = ("train", "test", "train", "val", "test", "train")
SECONDS = {}


@pytest.fixture(scope="module")
def store(tmp_path_factory):
    path = tmp_path_factory.mktemp("ds") / "dataset.zarr"
    create_store(path, StoreSpec(6, PIXELS, 3, SPLIT, {"scene": {"name": "t", "box": 4.0},
                                                         "pixel_size": 0.5}, REPLICAS))
    rng = np.random.default_rng(1)
    meta = {"seed": 3, "symmetry": "x", "order": 1, "removal": "none", "n_tethers": 2}
    for mould in range(6):
        write_inputs(path, mould, (rng.random((2, PIXELS, PIXELS)) > 0.5).astype(np.uint8), meta, lattice=np.zeros((2, PIXELS, PIXELS), np.float32))
        for r in range(REPLICAS[mould]):
            s = sample_index(REPLICAS, mould, r)
            failed = (mould, r) == (5, 0)
            SECONDS[s] = 10.0 + s
            write_sample(path, s, None if failed else rng.random((8, PIXELS, PIXELS)).astype("float32"),
                         {"sim_seed": s, "n_cells": 50 + mould, "energy": 1.0, "max_force": 1e-4,
                          "solver": "hybrid", "solver_seconds": SECONDS[s],
                          "hardware": "CPU A" if s % 2 else "CPU B"},
                         "folded: 2%" if failed else "ok")
    return path


def test_open_and_select_one_sample_per_mould(store):
    ds = condor.open_dataset(store)
    assert ds.sizes["sample"] == sum(REPLICAS)
    train = dataset.select(ds, "train")
    assert list(train["mould"].values) == [0, 2]  # mould 5 failed
    test_all = dataset.select(ds, "test", all_replicas=True)
    assert sorted(test_all["mould"].values) == [1, 1, 1, 4, 4]
    with pytest.raises(ValueError, match="split"):
        dataset.select(ds, "training")


def test_field_statistics_match_brute_force(store):
    ds = condor.open_dataset(store)
    stats = dataset.field_statistics(ds, "train", chunk=1).set_index("field")
    values = ds["fields"].values[[0, 2]].astype(np.float64)
    for k, name in enumerate(stats.index):
        assert stats.loc[name, "mean"] == pytest.approx(values[:, k].mean())
        assert stats.loc[name, "std"] == pytest.approx(values[:, k].std())
        assert stats.loc[name, "max"] == pytest.approx(values[:, k].max())


def test_dataloader_yields_batches_of_the_documented_shapes(store):
    ds = condor.open_dataset(store)
    stats = dataset.field_statistics(ds)
    loader = torch.utils.data.DataLoader(dataset.torch_dataset(ds, "train", standardise=stats),
                                         batch_size=2, shuffle=False)
    inputs, fields = next(iter(loader))
    assert inputs.shape == (2, 2, PIXELS, PIXELS) and fields.shape == (2, 8, PIXELS, PIXELS)
    assert inputs.dtype == fields.dtype == torch.float32
    assert set(np.unique(inputs.numpy())) <= {0.0, 1.0}
    raw = ds["fields"].values[[0, 2]]
    expected = (raw - stats["mean"].to_numpy()[:, None, None]) / stats["std"].to_numpy()[:, None, None]
    np.testing.assert_allclose(fields.numpy(), expected, rtol=1e-4, atol=1e-5)
    assert "inputs (2, H, W)" in dataset.ITEM_SHAPES


def test_card_counts_and_core_hours_match_the_store(store, tmp_path):
    path = dataset.write_card(store, tmp_path / "README.md")
    text = path.read_text()
    assert "scene 't', 6 moulds" in text
    hours = sum(SECONDS.values()) / 3600
    assert f"{hours:.3f} core-hours" in text
    assert f"over {sum(REPLICAS)} simulations" in text
    # the per-split table: test has 5 ok simulations, train 2 ok and 1 failed
    rows = {r.split("|")[1].strip(): r for r in text.splitlines() if re.match(r"\| (train|test|val) ", r)}
    test_row = [c.strip() for c in rows["test"].split("|")[1:-1]]
    assert test_row[0] == "test" and "5" in test_row
    assert "CPU A" in text and "CPU B" in text
    assert "condor.open_dataset" in text and "check-store --deep" in text


def test_training_data_names_a_corrupt_or_lost_sample(store, tmp_path):
    import shutil

    from condor.surrogate.samples import DataError, SampleSource

    copy = tmp_path / "copy.zarr"
    shutil.copytree(store, copy)
    chunk = next(p for p in (copy / "fields" / "c" / "2").rglob("*") if p.is_file())
    chunk.write_bytes(chunk.read_bytes()[:-7] + b"garbage")
    ds = condor.open_dataset(copy)
    with pytest.raises(DataError, match=r"\[2\]"):
        SampleSource(ds, dataset.usable_samples(ds, "train"), None)
    shutil.rmtree(copy / "fields" / "c" / "2")  # a lost chunk reads as NaN: named too
    with pytest.raises(DataError, match=r"sample\(s\) \[2\].*NaN"):
        SampleSource(condor.open_dataset(copy), dataset.usable_samples(ds, "train"), None)


def test_hardware_names_the_cpu_target_numba_compiles_for():
    # the instruction set decides the kernels' last bits, so the record must tell two
    # machines of one model name apart
    from llvmlite.binding import get_host_cpu_name

    from condor.stages.dataset import hardware

    record = hardware()
    assert f"({get_host_cpu_name()})" in record
    assert record.endswith(f"{os.cpu_count()} cores, {platform.machine()}")
