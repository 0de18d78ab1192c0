"""The studies (condor.studies): the recipes every study shares, the sweep, the accuracy tables on
synthetic ensembles with known answers, the convergence study and the ladder on tiny moulds."""

import numpy as np
import shapely
import pandas as pd
import pytest
from shapely.geometry import box

from condor.model.energy import random_orientations
from condor.data.fields import FIELD_NAMES, normalise
from condor.model.lattice import build_lattice
from condor.moulds.mould import Mould
from condor.model.scenes import get_scene
from condor.model.simulate import simulate_lattice
from condor.data.store import (StoreSpec, create_store, open_store, sample_index, write_inputs,
                               write_sample)
from condor.studies import accuracy, recipes, sweep
from condor.studies.convergence import convergence
from condor.studies.ladder import ladder

SCENE = get_scene("tiny", depth=1.5)
TETHERS = np.array([[4.5, 7.8, 0.9], [11.1, 7.8, 0.9]])


def small_mould(mould_id=0):
    return Mould(mould_id=mould_id, seed=0, symmetry="dihedral", order=2, removal="none",
                 box=SCENE.box, polygon=box(3, 5, 12.6, 10.6), tethers=TETHERS,
                 origin=(7.8, 7.8), unpruned_tethers=TETHERS)


def test_anneal_then_relax_is_the_anneal_followed_by_a_tight_relaxation(monkeypatch):
    mould = small_mould()
    seconds = []  # what each of the recipe's two runs reports, as it returns

    def timed(*args, **kwargs):
        result = simulate_lattice(*args, **kwargs)
        seconds.append(result.seconds)
        return result

    monkeypatch.setattr(recipes, "simulate_lattice", timed)
    result = recipes.anneal_then_relax(mould, SCENE.depth, 50, seed=3)
    monkeypatch.undo()
    lattice = build_lattice(mould.polygon, mould.tethers, SCENE.depth)
    start = random_orientations(lattice.n_cells, np.random.default_rng([3, 1]))
    annealed = simulate_lattice(lattice, lattice.positions, start, "anneal", 50, 3)
    again = simulate_lattice(lattice, annealed.positions, annealed.orientations, "lbfgs",
                             recipes.TIGHT_MAX_ITER, 3, recipes.TIGHT_FTOL)
    assert result.energy == pytest.approx(again.energy, rel=1e-12)
    assert result.info["max_force"] <= recipes.TIGHT_FTOL
    assert result.info["evaluations"] == annealed.info["evaluations"] + again.info["evaluations"]
    assert result.energy < annealed.energy and result.status == "ok"
    # its CPU seconds are its two runs' (the anneal's recorded apart), whatever they took
    assert len(seconds) == 2 and result.seconds == seconds[0] + seconds[1]
    assert result.info["anneal_seconds"] == seconds[0]


def test_sweep_runs_every_method_once_with_independent_seeds():
    methods = sweep.study_methods(100, (10,))
    assert [m.family for m in methods] == ["long anneal", "anneal", "minimise", "hybrid", "hybrid"]
    rows, fields = sweep.run_methods(small_mould(), SCENE, methods, dataset_seed=7)
    table = pd.DataFrame(rows).set_index("method")
    assert fields.shape == (5, 8, SCENE.pixels, SCENE.pixels) and np.isfinite(fields).all()
    assert (table["status"] == "ok").all() and table["seed"].nunique() == 5
    converged = table.loc["minimise", "energy_per_cell"]
    assert table.loc["anneal 10", "energy_per_cell"] > 2 * converged  # unconverged
    assert table.loc["long anneal 100", "energy_per_cell"] < 1.05 * converged
    # the density of every answer integrates to the cell count (the mould is inside the grid)
    assert np.allclose(fields[:, 0].sum(axis=(1, 2)), table["n_cells"], rtol=1e-3)


def synthetic_ensemble(rng, moulds=40, replicas=8, sigma=0.3, size=6):
    """Replicas mu + sigma * noise of raw fields whose density sums to the cell count."""
    n_cells = rng.integers(200, 400, size=moulds).astype(float)
    n_pixels = size * size
    mu = 1.0 + rng.random((moulds, 8, size, size))  # normalised expected fields, positive
    noise = sigma * rng.normal(size=(moulds, replicas, 8, size, size))
    noise[:, :, 0] = 0.0  # density: exactly the cell count in every replica
    mu[:, 0] = n_pixels / mu[:, 0].size * mu[:, 0].size / n_pixels  # P normalised to 1 per pixel
    normalised = mu[:, None] + noise
    raw = normalised * (n_cells / n_pixels)[:, None, None, None, None]
    ens = recipes.Ensemble(moulds=np.arange(moulds), raw=raw.astype(np.float32),
                             n_cells=n_cells, inputs=np.ones((moulds, 2, size, size), np.uint8),
                             pixel_size=0.5, seconds=np.full((moulds, replicas), 2.0),
                             energy_per_cell=np.full((moulds, replicas), 0.01))
    return ens, mu, n_cells, n_pixels


def test_accuracy_tables_recover_known_errors_ceiling_and_bias():
    rng = np.random.default_rng(11)
    sigma = 0.3
    ens, mu, n_cells, n_pixels = synthetic_ensemble(rng, sigma=sigma)
    raw_of = lambda normalised: normalised * (n_cells / n_pixels)[:, None, None, None]  # noqa: E731
    offset = np.zeros(mu.shape[1:])
    offset[1:] = 0.2  # every field but P off by 0.2: RMS error sqrt(7/8) * 0.2
    answers = [accuracy.Answer("perfect", "test", raw_of(mu), np.full(len(mu), 1.0)),
               accuracy.Answer("offset", "test", raw_of(mu + offset), np.full(len(mu), 3.0))]
    table, stats = accuracy.accuracy_tables(ens, answers)
    rows = table.set_index("method")
    assert list(table["method"][:3]) == ["single simulation", "mean of 2 simulations",
                                         "mean of 4 simulations"]
    ceiling = sigma * np.sqrt(7 / 8)  # P carries no noise
    for method, expected in (("single simulation", ceiling), ("mean of 4 simulations",
                                                              ceiling / 2),
                             ("perfect", 0.0), ("offset", 0.2 * np.sqrt(7 / 8))):
        row = rows.loc[method]
        assert row.field_error_lo - 0.01 <= expected <= row.field_error_hi + 0.01, (method, row)
    assert rows.loc["perfect", "field_error_plain"] > 0.05  # the uncorrected error keeps the noise
    assert rows.loc["offset", "cpu_s_per_mould"] == 3.0
    assert rows.loc["single simulation", "cpu_s_per_mould"] == 2.0
    s = stats.set_index(["method", "statistic"])
    assert abs(s.loc[("perfect", "mean_T"), "bias"]) < 0.01
    assert s.loc[("offset", "mean_Sx2_norm"), "bias"] == pytest.approx(
        np.median(0.2 / (mu[:, 2].mean(axis=(1, 2)))), rel=0.05)
    assert set(stats.columns) >= {"method", "statistic", "r", "r_ceiling", "bias"}
    # condor's statistics by predict's names: a perfect answer has no bias on them; the
    # signed alignment_x has no ratio bias; the paper's r only on the paper's statistics
    assert abs(s.loc[("perfect", "mean_tension"), "bias"]) < 0.01
    assert abs(s.loc[("perfect", "tissue_area"), "bias"]) < 0.01
    assert np.isnan(s.loc[("perfect", "alignment_x"), "bias"])
    assert np.isnan(s.loc[("perfect", "alignment"), "paper_r"])
    assert s.loc[("perfect", "mean_tension"), "paper_r"] == 0.98


def test_accuracy_of_a_prediction_uses_its_own_density_and_skips_failures():
    rng = np.random.default_rng(12)
    ens, mu, n_cells, n_pixels = synthetic_ensemble(rng, moulds=12)
    raw = mu * (n_cells / n_pixels)[:, None, None, None] * 1.3  # every field x 1.3
    raw[3] = np.nan  # a failed run
    table, _ = accuracy.accuracy_tables(ens, [accuracy.Answer("scaled", "surrogate", raw,
                                                              np.ones(12), predicted=True)])
    row = table.set_index("method").loc["scaled"]
    assert row.n_moulds == 11
    assert row.field_error_lo <= 0.0 + 0.02  # normalised by its own density: the scale cancels


def test_reference_ensemble_reads_ok_replicas_from_the_store(tmp_path):
    path = tmp_path / "d.zarr"
    counts = (1, 4, 5, 1, 4)
    create_store(path, StoreSpec(5, 8, 0, ("train", "test", "test", "val", "test"),
                                 {"pixel_size": 0.5}, counts))
    rng = np.random.default_rng(0)
    meta = {"seed": 0, "symmetry": "x", "order": 1, "removal": "none", "n_tethers": 2}
    for mould in range(5):
        write_inputs(path, mould, np.ones((2, 8, 8), np.uint8), meta, lattice=np.zeros((2, 8, 8), np.float32),
                     polygon=shapely.box(1, 1, 7, 7), tethers=np.full((2, 3), 2.0))
        for r in range(counts[mould]):
            status = "folded" if (mould, r) == (4, 2) else "ok"
            write_sample(path, sample_index(counts, mould, r),
                         rng.random((8, 8, 8)).astype("float32") if status == "ok" else None,
                         {"sim_seed": r, "n_cells": 100 + mould, "energy": 1.0, "max_force": 0.0,
                          "solver": "hybrid", "solver_seconds": 1.0 + r, "hardware": "test"}, status)
    ens = recipes.reference_ensemble(path)
    assert list(ens.moulds) == [1, 2]  # mould 4 has only 3 ok replicas
    # every replica of each mould: mould 1's fifth is NaN padding, mould 2's is its own
    assert ens.raw.shape == (2, 5, 8, 8, 8) and list(ens.n_cells) == [101, 102]
    assert list(ens.replica_counts) == [4, 5] and ens.describe_replicas() == "4-5 replicas"
    assert np.isnan(ens.raw[0, 4]).all() and np.isnan(ens.seconds[0, 4])
    np.testing.assert_array_equal(
        ens.raw[1, 4], open_store(path)["fields"].isel(sample=sample_index(counts, 2, 4)).values)
    assert ens.seconds[1, 4] == 5.0
    assert ens.energy_per_cell[0, 0] == pytest.approx(1 / 101)
    np.testing.assert_allclose(ens.normalised[0, 0], normalise(ens.raw[0, 0].astype(float), 101))
    with pytest.raises(ValueError, match="replicas"):
        recipes.reference_ensemble(path, moulds=[4])


def test_convergence_reference_rows_are_zero_and_a_thin_slab_is_not_justified():
    table = convergence(SCENE, [small_mould()], n_seeds=2, depths=(0.8, 1.5), box_scales=())
    rows = table.set_index("value")
    assert bool(rows.loc[1.5, "reference"]) and rows.loc[1.5, "change_P"] == 0.0
    assert rows.loc[0.8, "layers"] == 2 and rows.loc[1.5, "layers"] == 3
    changes = [rows.loc[0.8, f"change_{f}"] for f in ("P", "T", "Sx2", "Sy2", "Sz2")]
    assert max(changes) > 0 and not bool(rows.loc[0.8, "justified"])
    assert {f"noise_{f}" for f in FIELD_NAMES} <= set(table.columns)


def test_ladder_finds_its_own_recipe_in_the_same_states():
    mould = small_mould()
    runs = [recipes.anneal_then_relax(mould, SCENE.depth, 200, seed=50 + k) for k in range(4)]
    from condor.data.fields import cell_fields

    raw = np.stack([cell_fields(r.positions, r.orientations, r.tension, SCENE.box, SCENE.pixels,
                                SCENE.sigma) for r in runs])[None]
    ens = recipes.Ensemble(moulds=np.array([0]), raw=raw, n_cells=np.array([float(runs[0].n_cells)]),
                             inputs=np.ones((1, 2, SCENE.pixels, SCENE.pixels), np.uint8),
                             pixel_size=SCENE.pixel_size, seconds=np.ones((1, 4)),
                             energy_per_cell=np.array([[r.energy_per_cell for r in runs]]))
    table = ladder(ens, [mould], SCENE, budgets=(200,), n_seeds=3, dataset_seed=0)
    rung = table[table["rung"] == "anneal 200 + relax"].iloc[0]
    assert rung["runs"] == 3 and np.isfinite(rung["energy_per_cell"])
    # the same recipe with other seeds: the expected fields agree within the scatter
    assert rung["distance_to_dataset"] < rung["spread"]
    with pytest.raises(ValueError, match="not the ensemble"):
        ladder(ens, [small_mould(5)], SCENE, budgets=(200,), n_seeds=2, dataset_seed=0)


def test_accuracy_tables_take_each_moulds_own_replicas():
    """A few moulds scatter 5x more and hold 16 replicas, NaN-padded beside the others' 4
    (as the tether-free test moulds): the tables recover the known field error of an answer
    off by 0.2 and a perfect answer's r of 1 on every mould, the held-out rows use the 4
    replicas every mould holds, and the seconds ignore the padding."""
    rng = np.random.default_rng(4)
    ens, mu, n_cells, n_pixels = synthetic_ensemble(rng, moulds=60, replicas=16)
    noisy = np.arange(60) % 10 == 0
    raw = ens.raw.astype(np.float64)
    scaled = mu[:, None] * (n_cells / n_pixels)[:, None, None, None, None]
    raw[noisy] = scaled[noisy] + 5 * (raw[noisy] - scaled[noisy])  # 5x the scatter
    raw[~noisy, 4:] = np.nan
    seconds = np.full(raw.shape[:2], 2.0)
    seconds[~noisy, 4:] = np.nan
    seconds[noisy] = 3.0
    ragged = recipes.Ensemble(moulds=ens.moulds, raw=raw.astype(np.float32),
                                n_cells=n_cells, inputs=ens.inputs, pixel_size=0.5,
                                seconds=seconds, energy_per_cell=np.full(raw.shape[:2], 0.01))
    assert list(np.unique(ragged.replica_counts)) == [4, 16]
    raw_of = lambda normalised: normalised * (n_cells / n_pixels)[:, None, None, None]  # noqa: E731
    offset = np.zeros(mu.shape[1:])
    offset[1:] = 0.2
    answers = [accuracy.Answer("perfect", "test", raw_of(mu), np.ones(60)),
               accuracy.Answer("offset", "test", raw_of(mu + offset), np.ones(60))]
    table, stats = accuracy.accuracy_tables(ragged, answers)
    rows = table.set_index("method")
    assert "mean of 4 simulations" not in rows.index  # needs 6 replicas on every mould
    assert rows.loc["single simulation", "cpu_s_per_mould"] == 2.0  # the median, padding ignored
    row = rows.loc["offset"]
    assert row.field_error_lo - 0.01 <= 0.2 * np.sqrt(7 / 8) <= row.field_error_hi + 0.01
    s = stats.set_index(["method", "statistic"])
    assert s.loc[("perfect", "mean_Sx2"), "n"] == 60
    assert s.loc[("perfect", "mean_Sx2"), "r"] > 0.97
    # the same r from the replicas' statistics, one mould at a time
    per_mould = [accuracy.statistics_of(raw[m, :ragged.replica_counts[m]], 0.5,
                                        np.repeat(n_cells[m], ragged.replica_counts[m]))
                 for m in range(60)]
    k = list(accuracy.STATISTICS).index("mean_Sx2")
    means = np.array([p[:, k].mean() for p in per_mould])
    noise = np.array([p[:, k].var(ddof=1) / len(p) for p in per_mould])
    answer = accuracy.statistics_of(raw_of(mu), 0.5, None)[:, k]
    dx, dm = answer - answer.mean(), means - means.mean()
    direct = (dx * dm).mean() / np.sqrt((dx * dx).mean() * ((dm * dm).mean()
                                                           - noise.mean() * 59 / 60))
    assert s.loc[("perfect", "mean_Sx2"), "r"] == pytest.approx(min(direct, 1.0))


def test_study_moulds_take_paper_test_moulds_first_then_lab_ones(caplog):
    """The sweeps' moulds: the paper test set's first, topped up from the lab test set when
    it holds fewer than report.moulds (a run whose test set is all lab still has its studies),
    said in the log."""
    from condor.config import Config, ConfigError

    def config(test, lab_test, moulds):
        return Config.from_dict({"scene": "tiny", "n_moulds": 16, "split": {
            "test": test, "lab_test": lab_test}, "report": {"moulds": moulds}})

    mixed = config(6, 2, 3)
    assert mixed.study_moulds() == mixed.test_moulds("paper")[:3]
    all_lab = config(3, 3, 3)
    with caplog.at_level("WARNING", logger="condor"):
        chosen = all_lab.study_moulds()
    assert chosen == all_lab.test_moulds("lab") and len(chosen) == 3
    assert "paper test set holds 0" in caplog.text
    topped = config(3, 2, 3)
    assert topped.study_moulds() == topped.test_moulds("paper") + topped.test_moulds("lab")
    with pytest.raises(ConfigError, match="config key report/moulds: 3, but the test set holds 2"):
        config(2, 2, 3).study_moulds()  # a report never measures fewer moulds than it says
