"""The paper reference's runs and data product, and the fidelity of a solver against it."""

import numpy as np
import pytest

from condor.data.fields import FIELD_NAMES, cell_fields, normalise
from condor.model.scenes import get_scene
from condor.studies.fidelity import (
    FIDELITY_COLUMNS, TILT, fidelity_row, mean_orientation, z_symmetrised,
)
from condor.studies.paper_reference import (
    POS_QUANTUM, load_reference, pack_mould, reference_moulds, reference_seed, run_path,
    run_reference,
)


def _draw(rng, mean, sigma, replicas):
    """Replicas (M, R, 8, H, W) of normal noise about `mean` (M, 8, H, W)."""
    return mean[:, None] + sigma * rng.standard_normal((mean.shape[0], replicas) + mean.shape[1:])


def test_fidelity_recovers_a_known_distance_and_noise():
    rng = np.random.default_rng(0)
    m, shape = 12, (8, 6, 6)
    mu = rng.uniform(0.5, 1.5, (m,) + shape)
    shift = 0.05 * rng.standard_normal((m,) + shape)
    true = float(np.sqrt(np.mean(shift**2)))
    a = _draw(rng, mu + shift, 0.2, 40)
    b = _draw(rng, mu, 0.2, 30)
    row = fidelity_row("m", "tiny", "ref", a, b, evaluations=np.full((m, 40), 7.0))
    assert list(row)[:len(FIDELITY_COLUMNS)] == list(FIDELITY_COLUMNS)
    assert row["distance"] == pytest.approx(true, rel=0.15)
    assert row["distance_lo"] <= true <= row["distance_hi"]
    assert row["replica_noise"] == pytest.approx(0.2, rel=0.05)
    assert row["evaluations_per_mould"] == 7.0 and row["n_seeds"] == 40
    assert row["converged"] == (row["distance_hi"] <= 0.5 * row["replica_noise"])
    # the same ensemble against itself (disjoint replicas): no distance
    same = fidelity_row("m", "tiny", "ref", _draw(rng, mu, 0.2, 20), b)
    assert same["distance_lo"] == 0.0 and same["converged"]
    # the verdict is the distance's, whatever the energies say: energies 10% apart (their
    # interval far above the bar's number) leave it converged, and equal energies leave the
    # shifted ensemble unconverged
    energies = {"energy": np.full((m, 20), 1.1), "ref_energy": np.ones((m, 30))}
    same = fidelity_row("m", "tiny", "ref", _draw(rng, mu, 0.2, 20), b, **energies)
    assert same["energy_difference_pct_hi"] == pytest.approx(10.0) and same["converged"]
    far = fidelity_row("m", "tiny", "ref", _draw(rng, mu + 4 * shift, 0.2, 20), b,
                       energy=np.ones((m, 20)), ref_energy=np.ones((m, 30)))
    assert far["energy_difference_pct_hi"] == 0.0 and not far["converged"]


def test_z_symmetric_distance_is_the_same_quantity_without_the_tilt_noise():
    """Synthetic ensembles whose tilt fields have mean 0 (the reflection's twins equally likely)
    and 5x the other fields' scatter, the other six shifted by a known amount: over many draws
    both estimators recover the true squared distance (the tilt fields add nothing to it), the
    symmetrised one with a far smaller spread; the replica noise keeps the tilt scatter."""
    rng = np.random.default_rng(3)
    m, shape = 6, (8, 5, 5)
    sigma = np.full(8, 0.1)
    sigma[list(TILT)] = 0.5
    mu = rng.uniform(0.5, 1.5, (m,) + shape)
    mu[:, list(TILT)] = 0.0
    shift = 0.04 * rng.standard_normal((m,) + shape)
    shift[:, list(TILT)] = 0.0
    true_sq = float(np.mean(shift**2))
    plain, symmetric = [], []
    for _ in range(300):
        a = (mu + shift)[:, None] + sigma[:, None, None] * rng.standard_normal((m, 4) + shape)
        b = mu[:, None] + sigma[:, None, None] * rng.standard_normal((m, 3) + shape)
        plain.append(fidelity_row("m", "tiny", "ref", a, b)["distance"])
        row = fidelity_row("m", "tiny", "ref", a, b, z_symmetric=True)
        symmetric.append(row["distance"])
        assert row["z_symmetric"] is True
    plain, symmetric = np.array(plain), np.array(symmetric)
    assert np.mean(symmetric**2) == pytest.approx(true_sq, rel=0.05)
    assert np.std(symmetric**2) < 0.25 * np.std(plain**2)
    # the plain estimator's mean is unbiased too before its floor at 0; floored, it reads high
    assert np.mean(plain**2) > true_sq
    assert row["replica_noise"] == pytest.approx(float(np.sqrt(np.mean(sigma**2))), rel=0.1)
    assert "z_symmetric" not in fidelity_row("m", "tiny", "ref", a, b)
    # the twin average: tilt fields 0, missing runs stay missing, the others untouched
    a[0, 1] = np.nan
    sym = z_symmetrised(a)
    assert np.all(sym[1:, :, list(TILT)] == 0) and np.isnan(sym[0, 1]).all()
    keep = [f for f in range(8) if f not in TILT]
    assert np.array_equal(sym[1:, :, keep], a[1:, :, keep])


def test_mean_orientation_is_the_cell_average():
    f = np.zeros((8, 4, 4))
    f[FIELD_NAMES.index("P")] = 2.0
    f[FIELD_NAMES.index("Sx2")] = 1.0
    f[FIELD_NAMES.index("Sz2")] = 0.5
    assert np.allclose(mean_orientation(f), [0.5, 0.0, 0.25])


def test_reference_runs_resume_pack_and_load(tmp_path):
    scene = get_scene("tiny")
    cache, folder = tmp_path / "cache", tmp_path / "product"
    r = run_reference(cache, scene, 2026, 5, 20, 0)
    assert r.status == "ok" and r.seed == reference_seed(2026, 5, 0)
    assert run_path(cache, scene, 2026, 5, 20, 0).exists()
    assert not list(cache.rglob("*.checkpoint.npz"))  # removed once the run is kept
    again = run_reference(cache, scene, 2026, 5, 20, 0)  # read, not rerun
    assert np.array_equal(again.positions, r.positions)
    run_reference(cache, scene, 2026, 5, 20, 1)
    out = pack_mould(cache, scene, 2026, 5, [20, 40], 2, {"commit": "test"}, folder)
    assert out.stat().st_size < 64_000
    assert reference_moulds("tiny", 2026, folder) == [5]
    runs = load_reference("tiny", 2026, 5, folder=folder)
    assert [x.run for x in runs] == [0, 1] and runs[0].budget == 20  # 40 never ran
    assert np.abs(runs[0].positions - r.positions).max() <= POS_QUANTUM / 2 + 1e-12
    assert runs[0].energy_per_cell == r.energy_per_cell
    # the fields of the quantised state are the run's to a thousandth
    f = normalise(cell_fields(r.positions, r.orientations, r.tension, scene.box, scene.pixels,
                              scene.sigma), r.n_cells)
    assert np.abs(runs[0].fields(scene) - f).max() < 2e-3 * np.abs(f).max()
    with pytest.raises(FileNotFoundError, match="no paper reference of tiny mould 6"):
        load_reference("tiny", 2026, 6, folder=folder)


def test_packing_adds_to_the_product_and_a_lost_cache_loses_no_run(tmp_path):
    import json
    import shutil
    from condor.studies.paper_reference import reference_file, reference_rung, shipped_runs
    scene = get_scene("tiny")
    cache, folder = tmp_path / "cache", tmp_path / "product"
    first = run_reference(cache, scene, 2026, 5, 20, 0)
    pack_mould(cache, scene, 2026, 5, [20], 3, {"commit": "a"}, folder)
    shutil.rmtree(cache)  # a new machine: the cache is gone, the product is not
    second = run_reference(cache, scene, 2026, 5, 20, 1)
    pack_mould(cache, scene, 2026, 5, [20], 3, {"commit": "b"}, folder)
    runs = load_reference("tiny", 2026, 5, folder=folder)
    assert [r.run for r in runs] == [0, 1]
    assert [r.energy_per_cell for r in runs] == [first.energy_per_cell, second.energy_per_cell]
    # the worker skips what the product holds, though this cache never ran run 0
    assert shipped_runs("tiny", 2026, 5, folder) == {"anneal2e1_k0", "anneal2e1_k1"}
    assert shipped_runs("tiny", 2026, 6, folder) == set()
    with np.load(reference_file("tiny", 2026, 5, folder)) as data:
        meta = json.loads(str(data["meta"]))
    assert [r["commit"] for r in meta["runs"]] == ["a", "b"]  # each run keeps its own
    fields, energies = reference_rung(scene, 2026, 5, 20, folder)
    assert len(fields) == 2 and fields[1].shape == (8, scene.pixels, scene.pixels)
    assert energies == [first.energy_per_cell, second.energy_per_cell]
    assert reference_rung(scene, 2026, 5, 40, folder) == ([], [])
    assert reference_rung(scene, 2026, 6, 20, folder) == ([], [])


def test_fidelity_table_scores_solvers_against_the_shipped_reference(tmp_path):
    from condor.studies.fidelity import fidelity_table
    scene = get_scene("tiny")
    cache, folder = tmp_path / "cache", tmp_path / "product"
    for m in (5, 27):
        for k in range(2):
            run_reference(cache, scene, 2026, m, 20, k)
        pack_mould(cache, scene, 2026, m, [20], 2, {}, folder)
    table = fidelity_table(scene, 2026, [("lbfgs", None), ("anneal", 20.0)], 2, folder=folder)
    assert list(table["method"]) == ["lbfgs", "anneal"]
    assert list(table.columns[:len(FIDELITY_COLUMNS)]) == list(FIDELITY_COLUMNS)
    assert set(table["n_moulds"]) == {2} and set(table["reference"]) == {"anneal 2e1"}
    assert (table["evaluations_per_mould"] > 0).all() and (table["replica_noise"] > 0).all()
    assert table.loc[0, "moulds"] == "5 27"
    # a scene that is not the preset the references were run in has none
    other = fidelity_table(get_scene("tiny", depth=3.0), 2026, [("lbfgs", None)], 2,
                           folder=folder)
    assert other.empty and list(other.columns) == list(FIDELITY_COLUMNS)


def test_prediction_row_recovers_a_predictors_known_error():
    from condor.studies.fidelity import prediction_row
    rng = np.random.default_rng(1)
    m, shape = 16, (8, 6, 6)
    mu = rng.uniform(0.5, 1.5, (m,) + shape)
    shift = 0.04 * rng.standard_normal((m,) + shape)
    refs = _draw(rng, mu, 0.2, 6)
    row = prediction_row("surrogate unet", "tiny", "ref", mu + shift, refs, list(range(m)))
    true = float(np.sqrt(np.mean(shift**2)))
    assert row["distance"] == pytest.approx(true, rel=0.25)  # the 6 replicas' noise removed
    assert row["distance_lo"] <= true <= row["distance_hi"]
    assert row["n_seeds"] == 1 and np.isnan(row["evaluations_per_mould"])
    plain = float(np.sqrt(np.mean((mu + shift - refs.mean(axis=1)) ** 2)))
    assert plain > 2 * true  # what the uncorrected error would have said


def test_the_paper_ensemble_takes_each_mould_at_its_highest_rung_with_two_runs(tmp_path):
    """A rung whose first run alone is done (a ladder stopped between seeds) leaves the mould
    at the rung below, instead of dropping it from the ensemble; its second run moves it up."""
    from condor.studies.fidelity import paper_ensemble
    from condor.studies.paper_reference import budget_tag

    scene = get_scene("tiny")
    cache, folder = tmp_path / "cache", tmp_path / "product"
    for budget, k in ((20, 0), (20, 1), (40, 0)):
        run_reference(cache, scene, 2026, 5, budget, k)
    pack_mould(cache, scene, 2026, 5, [20, 40], 2, {"commit": "test"}, folder)
    assert [r.budget for r in load_reference("tiny", 2026, 5, folder=folder)] == [40]
    assert load_reference("tiny", 2026, 5, folder=folder, min_runs=3) == []
    moulds, fields, energy, label = paper_ensemble(scene, 2026, folder)
    assert moulds == [5] and label == f"anneal {budget_tag(20)}" and fields.shape[1] == 2
    low = load_reference("tiny", 2026, 5, 20, folder=folder)
    assert list(energy[0]) == [r.energy_per_cell for r in low]
    run_reference(cache, scene, 2026, 5, 40, 1)
    pack_mould(cache, scene, 2026, 5, [20, 40], 2, {"commit": "test"}, folder)
    moulds, fields, energy, label = paper_ensemble(scene, 2026, folder)
    assert label == f"anneal {budget_tag(40)}" and fields.shape[1] == 2


def test_paired_rungs_pair_run_k_with_run_k_whatever_order_the_runs_were_packed(tmp_path):
    """Rung 20 holds runs 0, 2 and 1 (packed in that order), rung 40 runs 0 and 2 only: the
    pairs are (0, 0) and (2, 2), each pair of one seed, in run order; run 1 of rung 20 has no
    partner and is left out."""
    from condor.studies.paper_reference import paired_rungs

    scene = get_scene("tiny")
    cache, folder = tmp_path / "cache", tmp_path / "product"
    for budget, ks in ((20, (0, 2)), (40, (0, 2))):
        for k in ks:
            run_reference(cache, scene, 2026, 5, budget, k)
        pack_mould(cache, scene, 2026, 5, [20, 40], 3, {"commit": "test"}, folder)
    run_reference(cache, scene, 2026, 5, 20, 1)
    pack_mould(cache, scene, 2026, 5, [20, 40], 3, {"commit": "test"}, folder)
    assert [r.run for r in load_reference("tiny", 2026, 5, 20, folder=folder)] == [0, 1, 2]
    low, high, e_low, e_high = paired_rungs(scene, 2026, 5, 20, 40, (folder,))
    assert len(low) == len(high) == 2
    for i, k in enumerate((0, 2)):
        for budget, energies in ((20, e_low), (40, e_high)):
            own = run_reference(cache, scene, 2026, 5, budget, k)  # read from the cache
            assert own.seed == reference_seed(2026, 5, k)
            assert energies[i] == own.energy_per_cell
    assert paired_rungs(scene, 2026, 6, 20, 40, (folder,)) == ([], [], [], [])


def test_rung_by_run_gathers_a_rungs_runs_from_every_folder_by_run_number(tmp_path):
    """Runs 0 and 1 shipped in one folder, run 2 packed in another (a study's more_runs_*),
    a folder without the mould passed over: the rung holds all three, in run order, each the
    run its own seed made."""
    from condor.studies.paper_reference import rung_by_run

    scene = get_scene("tiny")
    product, more = tmp_path / "product", tmp_path / "more"
    for k in (0, 1):
        run_reference(tmp_path / "cache", scene, 2026, 5, 20, k)
    pack_mould(tmp_path / "cache", scene, 2026, 5, [20], 3, {"commit": "test"}, product)
    third = run_reference(tmp_path / "cache_more", scene, 2026, 5, 20, 2)
    pack_mould(tmp_path / "cache_more", scene, 2026, 5, [20], 3, {"commit": "test"}, more)
    assert [r.run for r in load_reference("tiny", 2026, 5, 20, folder=more)] == [2]
    runs = rung_by_run(scene, 2026, 5, 20, (tmp_path / "empty", product, more))
    assert list(runs) == [0, 1, 2]
    assert runs[2][1] == third.energy_per_cell
    shipped = load_reference("tiny", 2026, 5, 20, folder=product)
    assert np.array_equal(runs[1][0], shipped[1].fields(scene))
    # the product's runs alone where the other folder adds none of this rung
    assert list(rung_by_run(scene, 2026, 5, 40, (product, more))) == []
