"""Tests for condor.data.fields (kernel weights, rasterisation, normalisation) and
condor.data.statistics (the paper's whole-mould statistics).

Reference values come from independent computations: Gauss-Legendre and scipy quadrature of
the Gaussian, a direct double loop over all pixels, block sums across resolutions, and
statistics worked out by hand on synthetic fields.
"""

from __future__ import annotations

import math

import numpy as np
import pandas as pd
import pytest

from condor.data import fields as F
from condor.data import statistics as S
from condor.model.scenes import PAPER_BOX, PAPER_PIXELS, SIGMA_L0

PAPER_PS = PAPER_BOX / PAPER_PIXELS


def random_cells(n, box, margin, seed):
    """n cells with x, y uniform in [margin, box - margin], unit orientations, tensions."""
    rng = np.random.default_rng([seed, n])
    xy = rng.uniform(margin, box - margin, size=(n, 2))
    s = rng.normal(size=(n, 3))
    s /= np.linalg.norm(s, axis=1, keepdims=True)
    tau = rng.normal(0.1, 0.05, size=n)
    return xy, s, tau


def gaussian_pixel_mass_gl(cx, cy, x0, y0, ps, sigma, nodes=24):
    """2-D Gauss-Legendre quadrature of the normalised Gaussian over [x0, x0+ps] x [y0, y0+ps]."""
    t, w = np.polynomial.legendre.leggauss(nodes)
    xs = x0 + 0.5 * ps * (t + 1.0)
    ys = y0 + 0.5 * ps * (t + 1.0)
    gx, gy = np.meshgrid(xs, ys, indexing="xy")
    density = np.exp(-((gx - cx) ** 2 + (gy - cy) ** 2) / (2 * sigma**2)) / (2 * np.pi * sigma**2)
    return float((0.5 * ps) ** 2 * np.einsum("i,j,ij->", w, w, density))


def brute_force_fields(xy, values, box, pixels, sigma):
    """Direct double loop over every pixel of the full (untruncated) Gaussian pixel integral."""
    ps = box / pixels
    out = np.zeros((values.shape[1], pixels, pixels))
    r = math.sqrt(2.0) * sigma
    for (cx, cy), v in zip(xy, values):
        for iy in range(pixels):
            wy = 0.5 * (math.erf(((iy + 1) * ps - cy) / r) - math.erf((iy * ps - cy) / r))
            for ix in range(pixels):
                wx = 0.5 * (math.erf(((ix + 1) * ps - cx) / r) - math.erf((ix * ps - cx) / r))
                out[:, iy, ix] += wx * wy * v
    return out


# --- kernel weights -------------------------------------------------------------------------


@pytest.mark.parametrize("pixels, box", [(256, PAPER_BOX), (64, PAPER_BOX / 2), (32, 15.625)])
def test_pixel_weights_match_gauss_legendre_quadrature(pixels, box):
    ps = box / pixels
    rng = np.random.default_rng([1, pixels])
    cells = rng.uniform(0.3 * box, 0.7 * box, size=(3, 2))
    fx, wx = F.pixel_weights(cells[:, 0], pixels, ps, SIGMA_L0)
    fy, wy = F.pixel_weights(cells[:, 1], pixels, ps, SIGMA_L0)
    for i, (cx, cy) in enumerate(cells):
        for ky in range(wy.shape[1]):
            for kx in range(wx.shape[1]):
                x0, y0 = (fx[i] + kx) * ps, (fy[i] + ky) * ps
                exact = gaussian_pixel_mass_gl(cx, cy, x0, y0, ps, SIGMA_L0)
                assert abs(wx[i, kx] * wy[i, ky] - exact) < 1e-9


def test_pixel_weights_match_scipy_dblquad():
    integrate = pytest.importorskip("scipy.integrate")
    ps, sigma, cx, cy = PAPER_PS, SIGMA_L0, 30.1234, 29.87
    fx, wx = F.pixel_weights(np.array([cx]), PAPER_PIXELS, ps, sigma)
    fy, wy = F.pixel_weights(np.array([cy]), PAPER_PIXELS, ps, sigma)
    norm = 1.0 / (2 * np.pi * sigma**2)
    rng = np.random.default_rng([2])
    for kx, ky in rng.integers(0, wx.shape[1], size=(8, 2)):
        x0, y0 = (fx[0] + kx) * ps, (fy[0] + ky) * ps
        exact, _ = integrate.dblquad(
            lambda y, x: norm * math.exp(-((x - cx) ** 2 + (y - cy) ** 2) / (2 * sigma**2)),
            x0, x0 + ps, y0, y0 + ps, epsabs=1e-13, epsrel=1e-12,
        )
        assert abs(wx[0, kx] * wy[0, ky] - exact) < 1e-6
        assert abs(wx[0, kx] * wy[0, ky] - exact) < 1e-6 * max(exact, 1e-6)


@pytest.mark.parametrize("pixels, box", [(256, PAPER_BOX), (64, PAPER_BOX / 2), (512, PAPER_BOX)])
def test_window_neglects_less_than_1e7_of_the_mass(pixels, box):
    rng = np.random.default_rng([3, pixels])
    coords = rng.uniform(0.4 * box, 0.6 * box, size=500)
    first, weights = F.pixel_weights(coords, pixels, box / pixels, SIGMA_L0)
    per_axis = weights.sum(axis=1)
    assert np.all(per_axis <= 1.0 + 1e-12)
    assert np.all(1.0 - per_axis**2 < 1e-7)  # 2-D mass lost by truncation
    # The window is where the mass is: centred on the cell.
    centre_px = first + weights.shape[1] / 2
    assert np.all(np.abs(centre_px - coords / (box / pixels)) <= 1.0)


# --- rasterisation --------------------------------------------------------------------------


def test_matches_brute_force_double_loop_including_border_cells():
    box, pixels = 15.625, 32
    rng = np.random.default_rng([4])
    xy = np.array([[7.3, 8.1], [0.2, 14.9], [15.5, 3.3], [-0.5, 7.0], [4.0, 16.2]])
    values = rng.normal(size=(xy.shape[0], 3))
    expected = brute_force_fields(xy, values, box, pixels, SIGMA_L0)
    got = F.rasterise(xy, values, box, pixels)
    assert got.shape == (3, pixels, pixels) and got.dtype == np.float32
    np.testing.assert_allclose(got, expected, atol=2e-7, rtol=1e-6)


def test_cells_far_off_the_grid_add_nothing():
    box, pixels = 15.625, 32
    inside = np.array([[7.0, 8.0]])
    far = np.array([[1e300, 8.0], [-1e300, 3.0], [5.0, 40.0], [-9.0, -9.0]])
    alone = F.rasterise(inside, np.ones(1), box, pixels)
    together = F.rasterise(np.vstack([inside, far]), np.ones(5), box, pixels)
    np.testing.assert_array_equal(together, alone)


def test_axis_convention_rows_are_y_columns_are_x():
    box, pixels = 31.25, 64
    ps = box / pixels
    xy = np.array([[(10 + 0.5) * ps, (50 + 0.5) * ps]])  # x in column 10, y in row 50
    field = F.rasterise(xy, np.ones(1), box, pixels)[0]
    assert np.unravel_index(np.argmax(field), field.shape) == (50, 10)


@pytest.mark.parametrize("pixels, box", [(256, PAPER_BOX), (64, PAPER_BOX / 2), (32, 15.625)])
def test_density_sums_to_number_of_cells_away_from_border(pixels, box):
    xy, s, tau = random_cells(2000, box, margin=6 * SIGMA_L0, seed=5)
    fields = F.cell_fields(xy, s, tau, box, pixels)
    assert fields.shape == (8, pixels, pixels)
    assert abs(fields[0].astype(np.float64).sum() - 2000) < 2000 * 1e-6


def test_single_cell_at_pixel_centre_is_symmetric():
    box, pixels = PAPER_BOX, PAPER_PIXELS
    ps = box / pixels
    iy, ix = 100, 140
    xy = np.array([[(ix + 0.5) * ps, (iy + 0.5) * ps]])
    field = F.rasterise(xy, np.ones(1), box, pixels)[0]
    k = 20
    blob = field[iy - k : iy + k + 1, ix - k : ix + k + 1]
    assert blob.max() == field[iy, ix]
    assert abs(blob.sum() - 1.0) < 1e-6
    scale = blob.max()
    for image in (blob[::-1], blob[:, ::-1], blob.T, blob[::-1, ::-1].T):
        np.testing.assert_allclose(image, blob, atol=1e-6 * scale, rtol=0)
    # Isotropic Gaussian: the central profile is the 1-D pixel-integrated Gaussian.
    r = math.sqrt(2.0) * SIGMA_L0
    offsets = np.arange(-k, k + 1)
    profile = [0.5 * (math.erf((j + 0.5) * ps / r) - math.erf((j - 0.5) * ps / r)) for j in offsets]
    centre_weight = profile[k]
    np.testing.assert_allclose(blob[k], np.array(profile) * centre_weight, atol=1e-7)


def test_orientation_squares_sum_to_density_everywhere():
    box, pixels = 31.25, 64
    xy, s, tau = random_cells(3000, box, margin=-2.0, seed=6)  # includes cells past the border
    fields = F.cell_fields(xy, s, tau, box, pixels)
    np.testing.assert_allclose(fields[2] + fields[3] + fields[4], fields[0], atol=1e-5, rtol=1e-5)


def test_rasterise_is_linear_in_values_and_additive_over_cells():
    box, pixels = 31.25, 64
    rng = np.random.default_rng([7])
    xy = rng.uniform(-1, box + 1, size=(400, 2))
    v1, v2 = rng.normal(size=(400, 2)), rng.normal(size=(400, 2))
    a, b = 2.5, -0.75
    combined = F.rasterise(xy, a * v1 + b * v2, box, pixels).astype(np.float64)
    separate = a * F.rasterise(xy, v1, box, pixels) + b * F.rasterise(xy, v2, box, pixels)
    np.testing.assert_allclose(combined, separate, atol=1e-5)
    a_, b_ = slice(None, 150), slice(150, None)
    halves = F.rasterise(xy[a_], v1[a_], box, pixels) + F.rasterise(xy[b_], v1[b_], box, pixels)
    np.testing.assert_allclose(F.rasterise(xy, v1, box, pixels), halves, atol=1e-5)


def test_sigma_is_fixed_in_l0_block_sums_across_resolutions_agree():
    box = 31.25
    xy, s, tau = random_cells(800, box, margin=0.0, seed=8)
    fine = F.cell_fields(xy, s, tau, box, 256).astype(np.float64)
    coarse = F.cell_fields(xy, s, tau, box, 64).astype(np.float64)
    block_sums = fine.reshape(8, 64, 4, 64, 4).sum(axis=(2, 4))
    np.testing.assert_allclose(block_sums, coarse, atol=5e-5)


# The rasteriser as it was before the Taylor weights and the grouped splat (e900e43): each
# weight a difference of two erf values, each cell added to a float64 grid in turn as
# wy * (wx * value). It gives that version's float64 grids bit for bit (checked against it on
# the cases below when it was written) and is the reference the fast one must equal to
# float64 rounding.


def erf_pixel_weights(coord_px, sigma_px):
    """(first, weights) the old way: W + 1 erf calls at the window's edges (pixel units)."""
    reach = F.WINDOW_SIGMAS * sigma_px
    width = F.window_width(sigma_px)
    scale = 1.0 / (math.sqrt(2.0) * sigma_px)
    first = np.floor(coord_px - reach).astype(np.int64)
    weights = np.empty((coord_px.shape[0], width))
    for i, (u, k0) in enumerate(zip(coord_px, first)):
        edges = [math.erf((k0 + k - u) * scale) for k in range(width + 1)]
        weights[i] = 0.5 * np.diff(edges)
    return first, weights


def erf_rasterise64(xy, values, box, pixels, sigma=SIGMA_L0):
    """The old float64 grid (pixels, pixels, C) [y, x, channel], cell by cell."""
    ps = box / pixels
    sigma_px = sigma / ps
    margin = (F.WINDOW_SIGMAS * sigma_px + 3.0) * ps
    coord_px = np.clip(xy, -margin, box + margin) / ps
    first_x, wx = erf_pixel_weights(coord_px[:, 0], sigma_px)
    first_y, wy = erf_pixel_weights(coord_px[:, 1], sigma_px)
    width = wx.shape[1]
    grid = np.zeros((pixels, pixels, values.shape[1]))
    for i in range(xy.shape[0]):
        y0, y1 = max(0, first_y[i]), min(pixels, first_y[i] + width)
        x0, x1 = max(0, first_x[i]), min(pixels, first_x[i] + width)
        if y1 <= y0 or x1 <= x0:
            continue
        template = wx[i, x0 - first_x[i] : x1 - first_x[i], None] * values[i]
        grid[y0:y1, x0:x1] += wy[i, y0 - first_y[i] : y1 - first_y[i], None, None] * template
    return grid


def cells_everywhere(n, box, channels, seed):
    """n cells over the grid, across its borders and outside it (some far off), with random
    values of either sign."""
    rng = np.random.default_rng([seed, n, channels])
    xy = rng.uniform(-0.15 * box, 1.15 * box, size=(n, 2))
    xy[: n // 10] = box / 2 + rng.normal(scale=0.05 * box, size=(n // 10, 2))  # a crowd
    xy[-3:] = [[1e300, 0.3 * box], [-0.3 * box, -1e300], [2 * box, 0.5 * box]]
    return xy, rng.normal(size=(n, channels))


@pytest.mark.parametrize(
    "pixels, box, channels",
    [(256, PAPER_BOX, 8), (64, PAPER_BOX, 8), (64, PAPER_BOX / 2, 2), (32, 15.625, 1),
     (96, 20.0, 3)],
)
def test_rasterise_equals_the_erf_rasteriser_to_float64_rounding(pixels, box, channels):
    xy, values = cells_everywhere(3000, box, channels, seed=11)
    old = erf_rasterise64(xy, values, box, pixels)
    new = F._fields64(xy, values, box, pixels, SIGMA_L0)
    assert new.shape == old.shape and new.dtype == np.float64
    # Only the rounding differs: the order in which a pixel's terms are added, and weights
    # within 1e-16 of each other; so the bound scales with the pixel sums of |terms| (the
    # fields of |values|). Measured: at most 2e-15 of the largest such sum, here and on random
    # grids of 1-100 px, sigma 0.05-5 l0 and 1-9 channels.
    sums = erf_rasterise64(xy, np.abs(values), box, pixels)
    assert np.abs(new - old).max() <= 1e-14 * sums.max()
    # The float32 fields agree to within float32 rounding.
    got = F.rasterise(xy, values, box, pixels)
    expected = old.transpose(2, 0, 1).astype(np.float32)
    assert np.abs(got - expected).max() <= np.spacing(np.float32(np.abs(old).max()))


@pytest.mark.parametrize("sigma_px", [3.0, 1.5, 0.75, 6.0, 0.3, 11.0])
def test_taylor_weights_match_erfc_to_1e13_relative_in_every_pixel(sigma_px):
    # Reference: each pixel's mass from erfc on the side of the window where both edges lie
    # (no cancellation of erf values near 1), so it is relatively accurate in the tails too.
    rng = np.random.default_rng([12, int(100 * sigma_px)])
    coord_px = np.concatenate([rng.uniform(-40, 300, size=300), [0.0, 1.0, -0.5, 255.999]])
    first, weights = F.pixel_weights(coord_px, 256, 1.0, sigma_px)
    expected_first, old = erf_pixel_weights(coord_px, sigma_px)
    np.testing.assert_array_equal(first, expected_first)
    scale = 1.0 / (math.sqrt(2.0) * sigma_px)
    for i, (u, k0) in enumerate(zip(coord_px, first)):
        for k in range(weights.shape[1]):
            a, b = (k0 + k - u) * scale, (k0 + k + 1 - u) * scale
            if a >= 0:
                exact = 0.5 * (math.erfc(a) - math.erfc(b))
            elif b <= 0:
                exact = 0.5 * (math.erfc(-b) - math.erfc(-a))
            else:
                exact = 0.5 * (math.erf(b) - math.erf(a))
            assert abs(weights[i, k] - exact) <= 1e-13 * exact, (i, k, weights[i, k], exact)
    # The old erf differences agree to float64 rounding of values up to 1.
    assert np.abs(weights - old).max() <= 4 * np.finfo(np.float64).eps


def test_rasterise_gives_the_same_bits_on_any_number_of_threads_and_bands():
    box, pixels = PAPER_BOX, PAPER_PIXELS  # groups spread over up to 4 rows of window starts
    xy, values = cells_everywhere(4000, box, 8, seed=13)
    one = F.rasterise(xy, values, box, pixels)
    for threads in (2, 3, 8):
        np.testing.assert_array_equal(F.rasterise(xy, values, box, pixels, threads=threads), one)
    # The bands one after another, uneven, some narrower than a window: the same bits again.
    grid = F._fields64(xy, values, box, pixels, SIGMA_L0)
    sigma_px = SIGMA_L0 / (box / pixels)
    reach = F.WINDOW_SIGMAS * sigma_px
    width = F.window_width(sigma_px)
    span = F._group_span(width)
    coord_px = np.clip(xy, -(reach + 3) * box / pixels, box + (reach + 3) * box / pixels)
    coord_px = coord_px / (box / pixels)
    order = F._cell_order(coord_px, reach, width, pixels, pixels, max(1, span // 2))
    first_x, wx = F.pixel_weights(coord_px[order, 0], pixels, 1.0, sigma_px)
    first_y, wy = F.pixel_weights(coord_px[order, 1], pixels, 1.0, sigma_px)
    bounds, boxes = F._cell_groups(first_y, first_x, width, pixels, pixels, span)
    assert set(np.diff(bounds)) == {1, 4, 8}  # every kind of group is exercised
    # Uneven bands, most narrower than a window, so that a group's box crosses several and
    # some of its cells have no rows in a band it meets.
    for edges in ([0, 1, 5, 40, 41, 90, 255, 256], list(range(0, 256, 3)) + [256]):
        banded = F._zeros_aligned(grid.shape)
        F._splat_serial(first_y, wy, first_x, wx, np.ascontiguousarray(values[order]), bounds,
                        boxes, span, np.array(edges), banded)
        np.testing.assert_array_equal(banded, grid)


def test_cell_fields_drops_z_and_counts_every_cell_passed():
    box, pixels = 15.625, 32
    xy, s, tau = random_cells(50, box, margin=5.0, seed=9)
    z = np.random.default_rng([9]).uniform(0, 2, size=(50, 1))
    fields_3d = F.cell_fields(np.hstack([xy, z]), s, tau, box, pixels)
    np.testing.assert_array_equal(fields_3d, F.cell_fields(xy, s, tau, box, pixels))


def test_cell_values_channels_in_field_order():
    s = np.array([[0.6, 0.0, 0.8], [0.0, -1.0, 0.0]])
    values = F.cell_values(s, np.array([2.0, -0.5]))
    expected = np.array([[1, 2.0, 0.36, 0, 0.64, 0, 0.48, 0], [1, -0.5, 0, 1, 0, 0, 0, 0]])
    np.testing.assert_allclose(values, expected, atol=1e-15)
    assert F.FIELD_NAMES == ("P", "T", "Sx2", "Sy2", "Sz2", "SxSy", "SxSz", "SySz")


def test_no_cells_gives_zero_fields():
    fields = F.cell_fields(np.empty((0, 3)), np.empty((0, 3)), np.empty(0), 15.625, 32)
    assert fields.shape == (8, 32, 32) and not fields.any()


# --- normalisation and statistics -----------------------------------------------------------


def test_normalise_multiplies_by_pixels_over_cells():
    box, pixels = 31.25, 64
    xy, s, tau = random_cells(1000, box, margin=6 * SIGMA_L0, seed=10)
    fields = F.cell_fields(xy, s, tau, box, pixels)
    normed = F.normalise(fields, 1000)
    assert normed.dtype == np.float32
    np.testing.assert_allclose(normed, fields.astype(np.float64) * 4096 / 1000, rtol=1e-6)
    assert abs(normed[0].astype(np.float64).mean() - 1.0) < 1e-6  # mean normalised density
    # Batch form: one N_c per sample.
    batch = np.stack([fields, 2 * fields])
    normed_batch = F.normalise(batch, np.array([1000, 2000]))
    np.testing.assert_allclose(normed_batch[1], normed, rtol=1e-6)


def synthetic_fields(pixels, pixel_size, square_l0, density_per_paper_px, t, sx2, sy2):
    """Fields that are uniform on a centred square of side square_l0 (zero elsewhere): density
    `density_per_paper_px` cells per paper pixel; T, Sx2, Sy2 are per-cell values times P."""
    fields = np.zeros((8, pixels, pixels))
    n_side = int(round(square_l0 / pixel_size))
    lo = (pixels - n_side) // 2
    p = density_per_paper_px * (pixel_size / PAPER_PS) ** 2
    region = (slice(lo, lo + n_side), slice(lo, lo + n_side))
    for channel, value in zip((0, 1, 2, 3), (1.0, t, sx2, sy2)):
        fields[channel][region] = value * p
    return fields


def test_statistics_by_hand_at_paper_resolution():
    # A 25 l0 square (102.4 paper px -> 102 px a side, rounded) at 0.5 cells per paper pixel.
    fields = synthetic_fields(256, PAPER_PS, 25.0, 0.5, t=0.2, sx2=0.7, sy2=0.25)
    n_px = 102 * 102
    stats = S.mould_statistics(fields, PAPER_PS)
    expected = {
        "mean_P": 0.5 * n_px / 65536,
        "n_P_gt_0.2": n_px,
        "mean_T": 0.2 * 0.5 * n_px / 65536,
        "mean_T_norm": 0.2,
        "mean_Sx2": 0.7 * 0.5 * n_px / 65536,
        "mean_Sx2_norm": 0.7,
        "mean_Sy2": 0.25 * 0.5 * n_px / 65536,
        "mean_Sy2_norm": 0.25,
    }
    assert tuple(stats) == S.STATISTICS
    for name, value in expected.items():
        assert stats[name] == pytest.approx(value, rel=1e-12), name
    # Given N_c, the normalised means are field sums over N_c (paper N_p / N_c scaling).
    given = S.mould_statistics(fields, PAPER_PS, n_cells=2 * 0.5 * n_px)
    assert given["mean_T_norm"] == pytest.approx(0.1, rel=1e-12)
    assert given["mean_P"] == stats["mean_P"]


def test_density_below_threshold_is_not_counted():
    fields = synthetic_fields(256, PAPER_PS, 25.0, 0.19, t=0.0, sx2=0.0, sy2=0.0)
    assert S.mould_statistics(fields, PAPER_PS)["n_P_gt_0.2"] == 0.0


def test_statistics_by_hand_are_resolution_independent():
    # The same mould (a 25 l0 square at 0.5 cells per paper pixel) on a 62.5 l0 box at
    # 128 px (pixel 2 l_p) and 256 px: each pixel holds 4x the cells at 128 px.
    coarse = synthetic_fields(128, 2 * PAPER_PS, 25.0, 0.5, t=0.2, sx2=0.7, sy2=0.25)
    stats = S.mould_statistics(coarse, 2 * PAPER_PS)
    n_paper_px = 51 * 51 * 4  # 51 coarse pixels a side, each 4 paper pixels
    assert stats["n_P_gt_0.2"] == pytest.approx(n_paper_px)
    assert stats["mean_P"] == pytest.approx(0.5 * n_paper_px / 65536)
    assert stats["mean_Sx2_norm"] == pytest.approx(0.7)


def test_statistics_of_rasterised_cells_agree_across_resolutions():
    box = 31.25
    xy, s, tau = random_cells(1500, box, margin=8.0, seed=11)
    by_res = {}
    for pixels in (64, 128, 256):
        fields = F.cell_fields(xy, s, tau, box, pixels)
        by_res[pixels] = S.mould_statistics(fields, box / pixels)
    # Means are exact (field sums): mean_P = N_c l_p^2 / box^2 at every resolution.
    for pixels, stats in by_res.items():
        assert stats["mean_P"] == pytest.approx(1500 * PAPER_PS**2 / box**2, rel=1e-5)
        assert stats["mean_T_norm"] == pytest.approx(tau.mean(), rel=1e-4, abs=1e-6)
        assert stats["mean_Sx2_norm"] == pytest.approx(np.mean(s[:, 0] ** 2), rel=1e-4)
        # The area over threshold is a count: agrees to a few pixel rims.
        assert stats["n_P_gt_0.2"] == pytest.approx(by_res[256]["n_P_gt_0.2"], rel=0.03)


def test_statistics_without_n_cells_use_the_density_sum():
    box, pixels = 31.25, 64
    xy, s, tau = random_cells(900, box, margin=6 * SIGMA_L0, seed=12)
    fields = F.cell_fields(xy, s, tau, box, pixels)
    free = S.mould_statistics(fields, box / pixels)
    given = S.mould_statistics(fields, box / pixels, n_cells=900)
    for name in S.STATISTICS:
        assert free[name] == pytest.approx(given[name], rel=1e-5, abs=1e-9)


def test_statistics_table_has_one_row_per_sample():
    box, pixels = 15.625, 32
    samples = [F.cell_fields(*random_cells(200, box, 4.0, seed), box, pixels) for seed in (13, 14)]
    table = S.statistics_table(np.stack(samples), box / pixels)
    assert isinstance(table, pd.DataFrame)
    assert list(table.columns) == list(S.STATISTICS) and len(table) == 2
    for i, fields in enumerate(samples):
        assert table.iloc[i].to_dict() == pytest.approx(S.mould_statistics(fields, box / pixels))


# --- bad input ------------------------------------------------------------------------------


@pytest.mark.parametrize(
    "call, match",
    [
        (lambda: F.rasterise(np.zeros((3, 3)), np.zeros((3, 1)), 10.0, 16), "xy"),
        (lambda: F.rasterise(np.zeros((3, 2)), np.zeros((4, 1)), 10.0, 16), "values"),
        (lambda: F.rasterise(np.array([[1.0, np.nan]]), np.ones((1, 1)), 10.0, 16), "xy.*NaN"),
        (lambda: F.rasterise(np.ones((1, 2)), np.array([[np.inf]]), 10.0, 16), "values.*NaN"),
        (lambda: F.rasterise(np.ones((1, 2)), np.ones(1), 10.0, 0), "pixels"),
        (lambda: F.rasterise(np.ones((1, 2)), np.ones(1), 10.0, 16.0), "pixels"),
        (lambda: F.rasterise(np.ones((1, 2)), np.ones(1), -1.0, 16), "box"),
        (lambda: F.rasterise(np.ones((1, 2)), np.ones(1), 10.0, 16, sigma=0.0), "sigma"),
        (lambda: F.cell_values(np.ones((2, 2)), np.ones(2)), "orientations"),
        (lambda: F.cell_values(np.eye(3), np.ones(2)), "tension"),
        (lambda: F.cell_values(np.array([[np.nan, 0, 1.0]]), np.ones(1)), "orientations.*NaN"),
        (lambda: F.cell_values(np.array([[1.0, 1.0, 0.0]]), np.ones(1)), "unit"),
        (lambda: F.cell_fields(np.ones((2, 3)), np.eye(3), np.ones(3), 10.0, 16), "positions"),
        (lambda: F.cell_fields(np.ones((2, 4)), np.eye(3)[:2], np.ones(2), 10.0, 16), "positions"),
        (lambda: F.normalise(np.ones((8, 4, 4)), 0), "n_cells"),
        (lambda: F.normalise(np.ones((2, 8, 4, 4)), np.ones(3)), "n_cells"),
        (lambda: S.mould_statistics(np.ones((7, 4, 4)), 1.0), "fields"),
        (lambda: S.mould_statistics(np.full((8, 4, 4), np.nan), 1.0), "fields.*NaN"),
        (lambda: S.mould_statistics(np.zeros((8, 4, 4)), 1.0), "n_cells"),
        (lambda: S.statistics_table(np.ones((8, 4, 4)), 1.0), "fields_batch"),
        (lambda: F.pixel_weights(np.ones((2, 2)), 16, 1.0, 1.0), "coord"),
        (lambda: F.pixel_weights(np.array([1.0, 1e300]), 16, 1.0, 1.0), "coord.*too far"),
    ],
)
def test_bad_input_raises_value_error_naming_it(call, match):
    with pytest.raises(ValueError, match=match):
        call()


def test_axes_average_and_differ_across_the_wrap_at_180_degrees():
    """Axes in degrees: 89 and -89 lie 2 degrees apart, their mean axis is 90 (= -90), and
    the spread is that of the doubled angles (brute force: the nearest of a - b + 180 k; a
    tight cluster's spread is its plain standard deviation, population form)."""
    from condor.data.statistics import axial_difference, axial_mean_sd

    rng = np.random.default_rng(3)
    for a, b in rng.uniform(-90, 90, (50, 2)):
        nearest = min((a - b + 180 * k for k in (-1, 0, 1)), key=abs)
        assert axial_difference(a, b) == pytest.approx(nearest)
    assert axial_difference(74.91, -73.51) == pytest.approx(-31.58)
    mean, spread = axial_mean_sd([89.0, -89.0])
    assert abs(axial_difference(mean, 90.0)) < 1e-9 and spread == pytest.approx(1.0, rel=1e-3)
    cluster = 30.0 + rng.normal(0, 0.5, 400)
    mean, spread = axial_mean_sd(cluster)
    assert mean == pytest.approx(np.mean(cluster), abs=1e-3)
    assert spread == pytest.approx(np.std(cluster), rel=1e-2)
    shifted = ((cluster + 60.0 + 90.0) % 180.0) - 90.0  # across the wrap: 90 -> -90
    assert axial_difference(axial_mean_sd(shifted)[0], np.mean(cluster) + 60.0) == \
        pytest.approx(0.0, abs=1e-3)
