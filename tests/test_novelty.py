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
    # where predict checks the mould anyway, the line does not ask for a check
    assert "--check" not in unseen_kinds_sentence(table, "x", novelty.CHECKED_ADVICE)


def test_the_never_drawn_line_counts_the_moulds_above_the_scatter_and_the_worst_tension():
    import pandas as pd
    from condor.surrogate.novelty import never_drawn_sentence
    table = pd.DataFrame({"kind": ["tee", "tee", "star", "you", "you"],
                          "ratio": [1.8, 0.5, 1.2, 0.9, 0.7],
                          "tension_bias": [0.04, -0.01, -0.16, -0.19, 0.02]})
    # ratios sorted 0.5 0.7 0.9 1.2 1.8: median 0.90, 2 above 1; |bias| 1 2 4 16 19%: median 4%
    line = never_drawn_sentence(table, "study at abc")
    assert "on 5 moulds of 3 kinds" in line and "a median 0.90x" in line
    assert "(2 above it)" in line and "median of 4%, up to -19% (a you)" in line
    assert "study at abc" in line
    assert never_drawn_sentence(table.iloc[:0], "x") is None


def test_inverse_spread_is_one_over_the_spread_maps_rms_over_the_tissue():
    rng = np.random.default_rng(4)
    spread = rng.uniform(0.01, 0.2, size=(2, 8, 6, 6))
    normalised = np.zeros((2, 8, 6, 6))
    normalised[0, 0, 1:4, 2:5] = 1.0  # 9 tissue pixels
    by_hand = 1 / np.sqrt(np.mean([spread[0, f, y, x] ** 2 for f in range(8)
                                   for y in range(1, 4) for x in range(2, 5)]))
    got = novelty.inverse_spread(spread, normalised)
    assert got[0] == pytest.approx(by_hand) and np.isnan(got[1])  # no tissue: no score


def test_the_scatter_verdict_flags_tight_moulds_with_the_error_measured_that_tight():
    import pandas as pd

    calibration = pd.DataFrame({"score_lo": [-np.inf, 10.0, 20.0], "score_hi": [10.0, 20.0, np.inf],
                                "n_moulds": [5, 5, 5], "ratio_median": [0.4, 0.8, 1.5],
                                "ratio_lo": [0.1, 0.3, 0.9], "ratio_hi": [0.7, 1.2, 2.5],
                                "share_above_ceiling": [0.0, 0.2, 0.8]})
    tight, numbers = novelty.novelty_verdict(25.0, calibration, 20.0, "here", "inverse_spread",
                                             1.1)
    assert "TIGHT" in tight and "tightness 25 " in tight
    assert "flagged above 20)" in tight and "novelty 1.10" in tight
    assert "lay 1.5x [0.9, 2.5]" in tight and "80% above it" in tight
    assert numbers["outside"] and numbers["expected_error_ratio"] == 1.5
    assert numbers["inverse_spread"] == 25.0 and numbers["novelty"] == 1.1
    assert novelty.CHECK_ADVICE in tight
    checking, _ = novelty.novelty_verdict(25.0, calibration, 20.0, "here", "inverse_spread",
                                          1.1, novelty.CHECKED_ADVICE)
    assert "TIGHT" in checking and novelty.CHECKED_ADVICE in checking and "--check" not in checking
    loose, numbers = novelty.novelty_verdict(12.0, calibration, 20.0, "here", "inverse_spread")
    assert "TIGHT" not in loose and "within one simulation's scatter" in loose
    assert not numbers["outside"] and numbers["expected_error_ratio"] == 0.8
    new, numbers = novelty.novelty_verdict(12.0, calibration, 20.0, "here")  # the distance
    assert "OUTSIDE" not in new and numbers["novelty"] == 12.0
