"""The dataset as a product (condor.dataset): open, select, statistics, a PyTorch DataLoader,
and a card whose numbers match the store."""

import os
import platform
import re

import numpy as np
import shapely
import pandas as pd
import pytest
import torch

import condor
from condor.data import dataset
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
        write_inputs(path, mould, (rng.random((2, PIXELS, PIXELS)) > 0.5).astype(np.uint8), meta, lattice=np.zeros((2, PIXELS, PIXELS), np.float32),
                     polygon=shapely.box(0.5, 0.5, 3.5, 3.5), tethers=np.full((2, 3), 1.0))
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
    assert "`outline_x`, `outline_y`" in text and "`tether_r`" in text
    assert "condor.dataset.mould_geometry(ds, 0)" in text


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

    from condor.stages.build import hardware

    record = hardware()
    assert f"({get_host_cpu_name()})" in record
    assert record.endswith(f"{os.cpu_count()} cores, {platform.machine()}")


# --------------------------------------------------------------------------- issue 32, item 4


@pytest.fixture(scope="module")
def replicated_store(tmp_path_factory):
    """3 moulds, the test ones simulated 4 and 5 times, with their expected fields derived:
    (path, raw fields per mould (R, 8, H, W), N_c per mould)."""
    from condor.data.store import write_expected

    path = tmp_path_factory.mktemp("rep") / "dataset.zarr"
    replicas, split = (1, 4, 5), ("train", "test", "test")
    create_store(path, StoreSpec(3, PIXELS, 5, split, {"scene": {"name": "t", "box": 4.0},
                                                        "pixel_size": 0.5}, replicas))
    rng = np.random.default_rng(7)
    meta = {"seed": 5, "symmetry": "x", "order": 1, "removal": "none", "n_tethers": 2}
    fields = {}
    for mould in range(3):
        lattice = rng.random((2, PIXELS, PIXELS)).astype(np.float32)
        write_inputs(path, mould, (rng.random((2, PIXELS, PIXELS)) > 0.5).astype(np.uint8),
                     meta, lattice=lattice, polygon=shapely.box(0.5, 0.5, 3.5, 3.5),
                     tethers=np.full((2, 3), 1.0))
        fields[mould] = (1.0 + rng.random((replicas[mould], 8, PIXELS, PIXELS))).astype("float32")
        for r in range(replicas[mould]):
            write_sample(path, sample_index(replicas, mould, r), fields[mould][r],
                         {"sim_seed": r, "n_cells": 100 + mould, "energy": 1.0,
                          "max_force": 1e-4, "solver": "lbfgs", "solver_seconds": 1.0,
                          "hardware": "CPU"}, "ok")
    write_expected(path)
    return path, fields, {m: 100.0 + m for m in range(3)}


def test_torch_dataset_serves_lattice_n_cells_mould_and_expected_fields(replicated_store):
    path, fields, n_cells = replicated_store
    ds = condor.open_dataset(path)
    items = list(condor.torch_dataset(ds, "test", lattice=True, n_cells=True, mould_id=True,
                                      expected=True))
    assert [int(i["mould"]) for i in items] == [1, 2]
    for item in items:
        mould = int(item["mould"])
        assert float(item["n_cells"]) == n_cells[mould]
        np.testing.assert_array_equal(item["fields"].numpy(), fields[mould][0])
        np.testing.assert_array_equal(item["lattice"].numpy(),
                                      ds["lattice"].isel(sample=mould).values)
        np.testing.assert_allclose(item["fields_mean"].numpy(), fields[mould].mean(axis=0),
                                   rtol=1e-6)
        np.testing.assert_allclose(item["fields_std"].numpy(),
                                   fields[mould].std(axis=0, ddof=1), rtol=1e-5)
        assert int(item["n_replicas"]) == len(fields[mould])
    train = condor.torch_dataset(ds, "train", expected=True)[0]
    assert int(train["n_replicas"]) == 0 and torch.isnan(train["fields_mean"]).all()
    batch = next(iter(torch.utils.data.DataLoader(condor.torch_dataset(ds, "test", n_cells=True),
                                                  batch_size=2)))
    assert batch["n_cells"].tolist() == [101.0, 102.0]
    # without options, the documented (inputs, fields) pairs
    inputs, _ = condor.torch_dataset(ds, "test")[0]
    assert inputs.shape == (2, PIXELS, PIXELS)


def test_score_matches_the_noise_corrected_error_computed_by_hand(replicated_store):
    """condor.score against the estimator written out: per mould, the squared error of the
    normalised prediction against the replica mean, less the replica mean's variance s^2/R,
    averaged over fields and pixels; the RMS over moulds."""
    path, fields, n_cells = replicated_store
    rng = np.random.default_rng(3)
    predictions = {m: (1.0 + rng.random((8, PIXELS, PIXELS))) for m in (1, 2)}
    result = condor.score(predictions, path, simulated=True)  # normalised by N_c
    per_mould = []
    for m in (1, 2):
        scale = PIXELS * PIXELS / n_cells[m]
        truth = fields[m].astype(np.float64) * scale
        plain = ((predictions[m] * scale - truth.mean(axis=0)) ** 2).mean()
        noise = (truth.var(axis=0, ddof=1) / len(truth)).mean()
        per_mould.append(plain - noise)
    row = result["accuracy"].set_index("method").loc["predictions"]
    assert row["field_error"] == pytest.approx(np.sqrt(np.mean(per_mould)), rel=1e-9)
    assert row["field_error_lo"] <= row["field_error"] <= row["field_error_hi"]
    assert list(result["moulds"]) == [1, 2]
    # the same predictions as an array in the order of ds["replicated"]
    again = condor.score(np.stack([predictions[1], predictions[2]]), condor.open_dataset(path),
                         simulated=True)
    assert again["accuracy"].set_index("method").loc["predictions", "field_error"] == \
        pytest.approx(row["field_error"], rel=1e-12)
    assert {"r", "r_lo", "r_hi", "bias", "bias_lo", "bias_hi"} <= set(result["statistics"])
    # one vocabulary: condor's statistics under the names condor predict prints them, beside
    # the paper's that condor has no name for
    from condor.data.statistics import MOULD_STATISTICS

    named = list(result["statistics"]["statistic"])
    assert set(named) >= set(MOULD_STATISTICS) - {"direction"}
    assert not {"mean_T_norm", "n_P_gt_0.2"} & set(named) and "mean_P" in named
    with pytest.raises(ValueError, match="2 replicated"):
        condor.score(np.zeros((3, 8, PIXELS, PIXELS)), path)


def test_replicated_moulds_gives_each_test_mould_s_ok_replicas(replicated_store):
    """Moulds 1 and 2 (4 and 5 replicas): their fields as written, N_c, family and geometry;
    the train mould (1 replica) is not a test mould, and min_ok above a mould's count leaves
    it out."""
    path, fields, n_cells = replicated_store
    got = list(dataset.replicated_moulds(path))
    assert [g[0] for g in got] == [1, 2]
    for mould, family, (polygon, tethers), raw, n, statuses in got:
        np.testing.assert_array_equal(raw, fields[mould].astype(np.float64))
        assert n == n_cells[mould] and statuses == ["ok"] * len(fields[mould])
        assert polygon.equals(shapely.box(0.5, 0.5, 3.5, 3.5)) and tethers.shape == (2, 3)
        assert isinstance(family, str)
    assert [g[0] for g in dataset.replicated_moulds(path, min_ok=5)] == [2]
    assert [g[0] for g in dataset.replicated_moulds(path, split="train", min_ok=1)] == [0]


def test_store_has_cf_attributes_and_x_y_coordinates(replicated_store):
    ds = condor.open_dataset(replicated_store[0])
    np.testing.assert_allclose(ds["x"].values, (np.arange(PIXELS) + 0.5) * 0.5)
    np.testing.assert_allclose(ds["y"].values, (np.arange(PIXELS) + 0.5) * 0.5)
    assert ds["x"].attrs["units"] == "l0" and ds["x"].attrs["standard_name"] == \
        "projection_x_coordinate"
    for name in ("inputs", "lattice", "fields", "fields_mean", "fields_std", "n_cells"):
        assert ds[name].attrs["long_name"] and "units" in ds[name].attrs, name
    assert ds.attrs["Conventions"].startswith("CF-")


def test_card_counts_moulds_and_simulations_apart_and_gives_licence_and_citation(
        replicated_store, tmp_path):
    text = dataset.write_card(replicated_store[0], tmp_path / "README.md").read_text()
    assert "3 moulds, 10 simulations (10 ok)" in text
    table = [r for r in text.splitlines() if r.startswith("| test | 2 | 9 |")]
    assert table, "the split table gives the test split 2 moulds and 9 simulations"
    assert "Licence:" in text and "Andrews, Dickinson and Hague" in text
    assert "condor.score" in text and "expected=True" in text


def test_dir_condor_lists_what_it_offers():
    assert {"open_dataset", "torch_dataset", "score", "__version__"} <= set(dir(condor))


# --------------------------------------------------------------------------- the mould geometry


@pytest.fixture(scope="module")
def mould_store(tmp_path_factory):
    """A tiny store whose moulds the mould stage wrote (no simulation): (config, path)."""
    from condor.config import Config
    from condor.stages.build import make_moulds

    config = Config.from_dict({"scene": "tiny", "seed": 11, "n_moulds": 6, "split": {"test": 2}})
    folder = tmp_path_factory.mktemp("geometry")
    path = folder / "dataset.zarr"
    create_store(path, config.store_spec())
    make_moulds(config, range(config.n_moulds), folder / "moulds.json", path)
    return config, path


def test_mould_geometry_is_its_sources_to_the_last_bit_in_every_replica(mould_store):
    config, path = mould_store
    ds = condor.open_dataset(path)
    families = set()
    for sample in range(ds.sizes["sample"]):
        mould = int(ds["mould"].values[sample])
        made = config.make_mould(mould)  # the generator's or a lab family's (Config.sources)
        families.add(made.family)
        polygon, tethers = dataset.mould_geometry(ds, sample)
        assert polygon.equals_exact(made.polygon, 0.0)
        np.testing.assert_array_equal(shapely.get_coordinates(polygon),
                                      shapely.get_coordinates(made.polygon))
        assert [len(r.coords) for r in polygon.interiors] == \
            [len(r.coords) for r in made.polygon.interiors]
        assert tethers.dtype == np.float64 and tethers.shape == (made.n_tethers, 3)
        np.testing.assert_array_equal(tethers, made.tethers)
    assert "paper" in families and len(families) > 1, families  # both sources were checked
    again, _ = dataset.mould_geometry(path, 2)  # a path works too
    assert again.equals_exact(dataset.mould_geometry(ds, 2)[0], 0.0)


def test_the_stored_inputs_are_the_recovered_geometry_rasterised_on_the_x_y_coordinates(
        mould_store):
    """An independent check of the geometry and its frame: each pixel centre (the store's own
    x and y coordinates) inside the outline and no post is a mould pixel, inside a post's
    circle a tether pixel (the rule of condor.moulds.mould.input_channels, written out)."""
    _, path = mould_store
    ds = condor.open_dataset(path)
    x, y = np.meshgrid(ds["x"].values, ds["y"].values)  # [y, x], like the inputs
    for sample in range(ds.sizes["sample"]):
        polygon, tethers = dataset.mould_geometry(ds, sample)
        post = np.zeros(x.shape, bool)
        for cx, cy, r in tethers:
            post |= (x - cx) ** 2 + (y - cy) ** 2 < r * r
        inside = shapely.contains_xy(polygon, x, y)
        stored = ds["inputs"].values[sample]
        np.testing.assert_array_equal(stored[0], inside & ~post)
        np.testing.assert_array_equal(stored[1], post)
        assert stored[1].any() == (len(tethers) > 0)


def test_mould_geometry_names_what_it_cannot_give(mould_store, store):
    _, path = mould_store
    ds = condor.open_dataset(path)
    with pytest.raises(IndexError, match="sample 99 is not in the dataset"):
        dataset.mould_geometry(ds, 99)
    unwritten = ds.copy()
    unwritten["inputs_ready"] = unwritten["inputs_ready"] * 0
    with pytest.raises(ValueError, match="sample 1: its mould is not written yet"):
        dataset.mould_geometry(unwritten, 1)
    with pytest.raises(condor.dataset.StoreError, match="no mould geometry.*format"):
        dataset.mould_geometry(ds.drop_vars(["outline_x", "outline_y"]), 0)
    polygon, tethers = dataset.mould_geometry(store, 0)  # the synthetic store's square
    assert polygon.equals(shapely.box(0.5, 0.5, 3.5, 3.5)) and tethers.shape == (2, 3)
