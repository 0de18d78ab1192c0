"""The speed/accuracy sweep and the scene convergence study on the tiny scene."""

import numpy as np
import pytest
from matplotlib.image import imread

from condor import tradeoff
from condor.fields import FIELD_NAMES
from condor.lattice import build_lattice
from condor.moulds import generate_mould
from condor.scenes import get_scene
from condor.simulate import simulate
from shapely.geometry import box

TINY = get_scene("tiny")
METHODS = [tradeoff.Method("anneal 10", "anneal", 10.0), tradeoff.Method("minimise", "minimise")]


@pytest.fixture(scope="module")
def table():
    return tradeoff.sweep("tiny", mould_ids=(0,), seeds=(1,), methods=METHODS,
                          reference_budget=100)


def test_sweep_rows_and_comparisons(table):
    roles = ["long anneal", "reference", "tight minimiser", "method", "method"]
    assert list(table["role"]) == roles
    assert (table["status"] == "ok").all() and (table["seconds"] > 0).all()
    # energies are compared with the lowest energy of the mould
    best = table["energy_per_cell"].min()
    assert np.allclose(table["rel_energy"], table["energy_per_cell"] / best - 1, rtol=0, atol=1e-15)
    assert table["rel_energy"].min() == 0.0
    ref = table[table["role"] == "reference"].iloc[0]
    assert ref["rel_energy_ref"] == 0.0 and ref["field_mae"] == 0.0
    # the reference is its long anneal followed by FIRE: lower energy, more time
    long = table[table["role"] == "long anneal"].iloc[0]
    assert ref["energy_per_cell"] < long["energy_per_cell"] and ref["seconds"] > long["seconds"]
    # ten moves per cell are far from the minimum, the minimiser is not
    by = table.set_index("method")
    assert by.loc["anneal 10", "rel_energy"] > 1.0 and by.loc["minimise", "rel_energy"] < 0.05


def test_field_mae_matches_an_independent_recomputation(table):
    mould = generate_mould(0, 0, TINY.box)
    ref = table[table["role"] == "reference"].iloc[0]
    # the reference, rebuilt by hand: long anneal from the seed-0 start, then tight FIRE
    from condor.energy import random_orientations
    from condor.simulate import simulate_lattice

    lat = build_lattice(mould.polygon, mould.tethers, TINY.depth)
    ori = random_orientations(lat.n_cells, np.random.default_rng([0, 1]))
    long = simulate_lattice(lat, lat.positions, ori, "anneal", 100, 0)
    r_ref = simulate_lattice(lat, long.positions, long.orientations, "minimise",
                             tradeoff.TIGHT_MAX_ITER, 0, tradeoff.TIGHT_FTOL)
    assert r_ref.energy_per_cell == pytest.approx(ref["energy_per_cell"], rel=1e-12)
    r = simulate(mould.polygon, mould.tethers, TINY.depth, "minimise", seed=1)
    f_ref = tradeoff.normalised_fields(r_ref, TINY.box, TINY.pixels, TINY.sigma)
    f = tradeoff.normalised_fields(r, TINY.box, TINY.pixels, TINY.sigma)
    row = table[table["method"] == "minimise"].iloc[0]
    per_channel = [np.mean(np.abs(f[k] - f_ref[k])) for k in range(len(FIELD_NAMES))]
    assert row["field_mae"] == pytest.approx(np.mean(per_channel), rel=1e-9)
    assert row["mae_T"] == pytest.approx(per_channel[1], rel=1e-9)
    # normalised: the density field sums to the pixel count for cells away from the border
    assert f[0].sum() == pytest.approx(TINY.pixels**2, rel=0.02)


def test_summary_and_chart(table, tmp_path):
    s = tradeoff.summary(table)
    assert len(s) == 5 and (s["runs"] == 1).all()
    path = tmp_path / "chart.png"
    tradeoff.chart(table, path)
    image = imread(path)
    assert image.ndim == 3 and image.shape[0] > 200 and image.std() > 0


def test_default_methods_span_decades():
    methods = tradeoff.default_methods((10, 100, 1000))
    budgets = [m.budget for m in methods if m.solver == "anneal"]
    assert budgets == [10.0, 100.0, 1000.0]
    assert {m.solver for m in methods} == {"anneal", "minimise", "hybrid"}
    assert any(m.ftol == 1e-4 for m in methods) and any(m.ftol is None for m in methods)


@pytest.mark.parametrize("depth", [0.5, 1.0, 1.5, 2.0, 4.0])
def test_n_layers_counts_the_lattice_layers(depth):
    lat = build_lattice(box(0, 0, 4, 4), np.zeros((0, 3)), depth)
    assert tradeoff.n_layers(depth) == len(np.unique(np.round(lat.positions[:, 2], 9)))


def test_convergence_study(tmp_path):
    df = tradeoff.convergence("tiny", mould_ids=(0,), seeds=(0, 1), depths=(1.0, 2.0),
                              box_scales=(0.5, 1.0))
    # depth: 1.0 at two seeds + the other seed of the reference; box: the same
    assert sorted(df["study"].value_counts().items()) == [("box", 3), ("depth", 3)]
    assert (df["status"] == "ok").all()
    depth = df[df["study"] == "depth"]
    assert set(depth["layers"]) == {2, 3}
    base = depth[depth["baseline"]]
    assert len(base) == 1 and base["value"].iloc[0] == 2.0 and base["seed"].iloc[0] == 1
    # fewer cells at smaller depth and box
    shallow = depth[depth["value"] == 1.0]["n_cells"].iloc[0]
    assert shallow < base["n_cells"].iloc[0]
    # independent check of one relative MAE: depth 1.0, seed 0, against depth 2.0, seed 0
    mould = generate_mould(0, 0, TINY.box)
    fields = {}
    for d in (1.0, 2.0):
        r = simulate(mould.polygon, mould.tethers, d, "hybrid", seed=0)
        fields[d] = tradeoff.normalised_fields(r, TINY.box, TINY.pixels, TINY.sigma)
    expect = np.abs(fields[1.0][0] - fields[2.0][0]).mean() / np.abs(fields[2.0][0]).mean()
    row = depth[(depth["value"] == 1.0) & (depth["seed"] == 0)].iloc[0]
    assert row["rel_P"] == pytest.approx(expect, rel=1e-9)
    s = tradeoff.convergence_summary(df)
    assert set(s["study"]) == {"box", "depth"} and s["noise"].notna().all()
    tradeoff.convergence_chart(df, tmp_path / "conv.png")
    assert imread(tmp_path / "conv.png").shape[0] > 200
    with pytest.raises(ValueError, match=r"\(0,\)"):
        tradeoff.convergence("tiny", seeds=(0,))
