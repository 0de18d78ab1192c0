"""How new a mould is to a surrogate (condor.surrogate.novelty)."""

import math

import numpy as np
import pytest
import shapely
import torch

from condor.moulds.mould import Mould
from condor.surrogate import novelty
from condor.surrogate.networks import UNetConfig, UNetGenerator


def test_knn_distance_is_the_mean_distance_to_the_k_nearest_over_the_banks_own():
    """Against a brute-force computation on random points, in scaled units."""
    rng = np.random.default_rng(0)
    bank = rng.normal(size=(40, 3)) * [1.0, 10.0, 0.1]
    query = rng.normal(size=(5, 3)) * [1.0, 10.0, 0.1] + [3.0, 0.0, 0.0]
    scale = bank.std(axis=0)
    b, q = bank / scale, query / scale
    own = [np.sort(np.delete(np.linalg.norm(b - b[i], axis=1), i))[:5].mean() for i in range(40)]
    expected = [np.sort(np.linalg.norm(b - x, axis=1))[:5].mean() / np.median(own) for x in q]
    assert novelty.knn_distance(bank, query) == pytest.approx(expected)
    # a bank member's own distance (itself included) is below the typical leave-one-out one
    assert novelty.knn_distance(bank, bank[:1])[0] < 1.0
    assert np.all(novelty.knn_distance(bank, query) > 1.0)  # shifted 3 sd away in x


def test_descriptors_of_a_known_mould():
    box = 10.0
    polygon = shapely.box(1, 3, 9, 7).difference(shapely.box(4, 4, 6, 6))  # 8 x 4, a 2x2 hole
    tethers = np.array([[2.0, 5.0, 0.5], [8.0, 5.0, 0.25]])
    d = dict(zip(novelty.DESCRIPTORS, novelty.descriptors(Mould(box=box, polygon=polygon,
                                                                   tethers=tethers))))
    assert d["area"] == pytest.approx(28 / 100)
    assert d["extent"] == pytest.approx(0.8) and d["aspect"] == pytest.approx(2.0)
    assert d["perimeter_ratio"] == pytest.approx(32 / (2 * math.sqrt(math.pi * 28)))
    assert d["n_posts"] == 2 and d["holes"] == 1 and d["hole_area"] == pytest.approx(0.04)
    assert d["post_radius_max"] == pytest.approx(0.05) and d["post_radius_min"] == 0.025
    assert d["post_spacing"] == pytest.approx(0.6)
    assert d["post_to_wall"] == pytest.approx(0.05)  # the first post: 1 from the wall, r 0.5
    assert d["post_area"] == pytest.approx(math.pi * (0.25 + 0.0625) / 28)
    free = novelty.descriptors(Mould(box=box, polygon=polygon, tethers=np.zeros((0, 3))))
    assert dict(zip(novelty.DESCRIPTORS, free))["n_posts"] == 0 and np.isfinite(free).all()


def test_features_are_invariant_under_the_planar_symmetries():
    """Averaged over the 8 planar transforms, a mould and its mirror image give the same
    bottleneck vector (masks only: the mirror of a mask is a mask)."""
    torch.manual_seed(0)
    model = UNetGenerator(UNetConfig.for_size(16, base=4, depth=3, max_width=8))
    x = (np.random.default_rng(1).random((1, 2, 16, 16)) > 0.6).astype(np.float32)
    mirrored = x[..., ::-1].copy()
    a = novelty.features(model, "mask", x)
    b = novelty.features(model, "mask", mirrored)
    assert a.shape == (1, 8)
    np.testing.assert_allclose(a, b, rtol=1e-5, atol=1e-6)
    assert not np.allclose(a, novelty.features(model, "mask", 1 - x))


def test_the_unseen_kinds_line_reads_only_the_held_out_rows():
    import pandas as pd
    from condor.surrogate.novelty import unseen_kinds_sentence
    table = pd.DataFrame({
        "family": ["strip", "dogbone", "ring", "strip", "paper", "annulus"],
        "held_out": ["strip+dogbone", "strip+dogbone", "ring+annulus", "ring+annulus",
                     "ring+annulus", "ring+annulus"],
        "tension_bias": [0.10, -0.02, 0.04, 0.50, -0.90, -0.12]})
    # held out: strip +10%, dogbone -2%, ring +4%, annulus -12% (a trained-on strip's +50% and
    # the paper moulds' -90% are not unseen kinds): median of |bias| 7%, the largest -12%
    line = unseen_kinds_sentence(table, "study at abc")
    assert "median of 7% over 4 families, up to -12% (family annulus)" in line
    assert "study at abc" in line and "--check 4" in line
    assert unseen_kinds_sentence(table[table["family"] == "paper"], "x") is None
