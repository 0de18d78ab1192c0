"""The physics head: exact relations, the loss's minimiser (mean and spread), the cell count,
symmetrised prediction, resumable training, the spread in predictions and their files, and the
calibration measures."""

from dataclasses import replace

import numpy as np
import pytest
import torch
import xarray as xr
from shapely.geometry import Polygon, box

from condor import cli
from condor.prediction_page import prediction_panels
from condor.model.lattice import build_lattice
from condor.model.scenes import get_scene
from condor.moulds.paper import generate_mould
from condor.moulds.mould import save_json
from condor.surrogate.calibration import (checkerboard, interval_coverage, spread_agreement,
                                          tissue_pixels, z_of)
from condor.surrogate.checkpoint import CheckpointMismatchError, load_checkpoint
from condor.surrogate.samples import FIELD_NAMES, apply_symmetry, usable_samples
from condor.surrogate.networks import UNetConfig, UNetGenerator
from condor.data.statistics import mould_statistics
from condor.surrogate.physics import (NOISE_WEIGHT_RANGE, PhysicsHead, area_threshold_per_pixel,
                                      estimate_n_cells, n_cells_of_mould)
from condor.surrogate.predict import Predictor, predict
from condor.surrogate.prediction_zarr import write_prediction
from condor.surrogate.synthetic import synthetic_dataset
from condor.surrogate.train import TrainConfig, train

QUIET = lambda message: None
I = {f: k for k, f in enumerate(FIELD_NAMES)}


def _head():
    return PhysicsHead(np.linspace(0.5, 1.5, 8), tension_scale=0.02)


def test_decode_is_exact_for_any_output():
    out = torch.randn(3, 16, 12, 12, dtype=torch.float64) * 3
    n_cells = torch.tensor([100.0, 2345.0, 7.5], dtype=torch.float64)
    fields, spread = _head().decode(out, n_cells)
    p = fields[:, I["P"]]
    assert torch.all(p > 0)
    torch.testing.assert_close(p.sum(dim=(1, 2)), n_cells, rtol=1e-12, atol=0)
    trace = fields[:, I["Sx2"]] + fields[:, I["Sy2"]] + fields[:, I["Sz2"]]
    torch.testing.assert_close(trace, p, rtol=1e-12, atol=1e-15)
    s = torch.stack([torch.stack([fields[:, I[a]] for a in row]) for row in
                     (("Sx2", "SxSy", "SxSz"), ("SxSy", "Sy2", "SySz"), ("SxSz", "SySz", "Sz2"))])
    eigenvalues = torch.linalg.eigvalsh(s.permute(2, 3, 4, 0, 1))
    assert eigenvalues.min() >= -1e-12 * p.max()
    assert torch.all(spread > 0)


def test_loss_minimiser_is_the_mean_and_the_spread_the_std():
    """Fit the raw outputs of one 4x4 image directly to skewed draws: the decoded tension
    converges to the draws' mean (not their median) and the spread to their std."""
    rng = np.random.default_rng(0)
    head = PhysicsHead(np.ones(8), tension_scale=1.0)
    n_cells = torch.tensor([16.0], dtype=torch.float64)
    mean_t = np.linspace(0.5, 2.0, 16).reshape(4, 4)
    draws = rng.exponential(mean_t, size=(1000, 4, 4))  # skewed: median = 0.69 mean
    target = torch.zeros(len(draws), 8, 4, 4, dtype=torch.float64)
    target[:, I["P"]] = 1.0  # 16 cells on 16 pixels
    target[:, I["T"]] = torch.from_numpy(draws)
    target[:, I["Sx2"]] = target[:, I["Sy2"]] = target[:, I["Sz2"]] = 1 / 3
    out = torch.zeros(1, 16, 4, 4, dtype=torch.float64, requires_grad=True)
    opt = torch.optim.Adam([out], lr=0.05)
    for step in range(800):  # full batch: the optimum is the sample's own mean and std
        loss, _ = head.loss(out.expand(len(draws), -1, -1, -1), target, n_cells.expand(len(draws)))
        opt.zero_grad()
        loss.backward()
        opt.step()
    with torch.no_grad():
        fields, spread = head.decode(out, n_cells)
    t = fields[0, I["T"]].numpy()
    np.testing.assert_allclose(t, draws.mean(0), rtol=0.01)
    assert np.all(np.abs(t - np.median(draws, 0)) > 0.15 * mean_t)  # not the median
    np.testing.assert_allclose(spread[0, I["T"]].numpy(), draws.std(0), rtol=0.02)


def test_tension_sum_term_targets_the_median_ratio(monkeypatch):
    """With sum_weight, fit one image to draws whose tension is one pattern times a lognormal
    factor: the fitted sum(T) + floor is sqrt(sum(t') / sum(1 / t')) over the draws' sums
    t' = sum(T) + floor, the minimiser of sum((p' - t')^2 / (p' t')), which for a lognormal
    is its median; the pixel error's mean (exp(s^2 / 2) x median) and the relative squared
    error's minimiser (exp(-1.5 s^2) x median) are both far from it."""
    from condor.surrogate import physics

    monkeypatch.setattr(physics, "SUM_HUBER", 1e9)  # the quadratic loss, for the closed form
    rng = np.random.default_rng(1)
    scale = np.ones(8)
    scale[I["T"]] = 1e4  # the pixel error of T vanishes: the sum term alone sets sum(T)
    head = PhysicsHead(scale, tension_scale=1.0, sum_weight=1.0)
    n_cells = torch.full((400,), 16.0, dtype=torch.float64)
    factor = np.exp(rng.normal(0.0, 0.5, size=400))
    pattern = np.linspace(0.5, 2.0, 16).reshape(4, 4)
    target = torch.zeros(400, 8, 4, 4, dtype=torch.float64)
    target[:, I["P"]] = 1.0
    target[:, I["T"]] = torch.from_numpy(factor[:, None, None] * pattern)
    target[:, I["Sx2"]] = target[:, I["Sy2"]] = target[:, I["Sz2"]] = 1 / 3
    out = torch.zeros(1, 16, 4, 4, dtype=torch.float64, requires_grad=True)
    opt = torch.optim.LBFGS([out], max_iter=500, tolerance_grad=1e-12, tolerance_change=1e-15,
                            line_search_fn="strong_wolfe")

    def closure():
        opt.zero_grad()
        loss, _ = head.loss(out.expand(400, -1, -1, -1), target, n_cells)
        loss.backward()
        return loss

    opt.step(closure)
    _, parts = head.loss(out.expand(400, -1, -1, -1), target, n_cells)
    floor = physics.SUM_FLOOR * 1.0 * 16.0
    with torch.no_grad():
        fitted = head.decode(out, n_cells[:1])[0][0, I["T"]].sum().item() + floor
    sums = factor * pattern.sum() + floor
    expected = np.sqrt(sums.sum() / (1 / sums).sum())
    assert fitted == pytest.approx(expected, rel=2e-3)
    assert abs(fitted / sums.mean() - 1) > 0.08
    assert abs(fitted / ((1 / sums).sum() / (1 / sums ** 2).sum()) - 1) > 0.2
    assert "sum_T" in parts


def test_tension_sum_term_is_finite_for_zero_and_negative_sums():
    head = PhysicsHead(np.ones(8), tension_scale=0.02, sum_weight=1.0)
    out = torch.randn(2, 16, 6, 6, dtype=torch.float64)
    out[:, 1] = -5.0  # negative predicted tension
    target = torch.zeros(2, 8, 6, 6, dtype=torch.float64)
    target[:, I["P"]] = 1.0
    target[1, I["T"]] = -1e-3  # a compressed mould: negative sum(T)
    loss, parts = head.loss(out, target, torch.tensor([36.0, 36.0], dtype=torch.float64))
    assert torch.isfinite(loss) and parts["sum_T"] > 0
    baseline, _ = PhysicsHead(np.ones(8), tension_scale=0.02).loss(out, target, [36.0, 36.0])
    assert loss.item() > baseline.item()


def test_field_weights_weigh_each_fields_squared_error():
    """The weighted loss against a numpy sum over fields, weights normalised to mean 1."""
    rng = np.random.default_rng(3)
    scale = np.linspace(0.5, 1.5, 8)
    weights = np.array([2.0, 1.0, 3.0, 3.0, 1.0, 0.5, 0.25, 0.25])
    out = torch.from_numpy(rng.normal(size=(2, 16, 6, 6)))
    target = torch.from_numpy(np.abs(rng.normal(size=(2, 8, 6, 6))))
    n_cells = [30.0, 40.0]
    head = PhysicsHead(scale, 0.02, nll_weight=0.0, field_weights=weights)
    loss, parts = head.loss(out, target, n_cells)
    fields, _ = head.decode(out, torch.tensor(n_cells, dtype=torch.float64), calibrated=False)
    per_field = (((fields - target).numpy() / scale[None, :, None, None]) ** 2).mean(axis=(0, 2, 3))
    expected = (weights / weights.mean() * per_field).mean()
    assert parts["mse"] == pytest.approx(expected, rel=1e-12)
    plain, _ = PhysicsHead(scale, 0.02, nll_weight=0.0).loss(out, target, n_cells)
    assert plain.item() == pytest.approx(per_field.mean(), rel=1e-12)
    assert abs(loss.item() - plain.item()) > 1e-3  # the weights change it
    restored = PhysicsHead.from_dict(head.to_dict())
    assert restored.loss(out, target, n_cells)[0].item() == loss.item()


def test_tension_floor_weighs_each_moulds_tension_error_by_its_own_tension():
    """The T term against a numpy sum: each mould's squared T error times
    ((1 + f) / (t + f))^2, t = its target's sum(T) / (N_c tau_0); the other fields unchanged."""
    rng = np.random.default_rng(4)
    scale, tau, floor = np.linspace(0.5, 1.5, 8), 0.02, 0.5
    out = torch.from_numpy(rng.normal(size=(3, 16, 6, 6)))
    target = torch.from_numpy(np.abs(rng.normal(size=(3, 8, 6, 6))))
    target[:, I["T"]] *= torch.tensor([0.01, 0.1, 1.0], dtype=torch.float64)[:, None, None]
    n_cells = [30.0, 40.0, 50.0]
    head = PhysicsHead(scale, tau, nll_weight=0.0, tension_floor=floor)
    _, parts = head.loss(out, target, n_cells)
    fields, _ = head.decode(out, torch.tensor(n_cells, dtype=torch.float64), calibrated=False)
    squared = ((fields - target).numpy() / scale[None, :, None, None]) ** 2
    per_cell = target[:, I["T"]].numpy().sum(axis=(1, 2)) / (np.array(n_cells) * tau)
    squared[:, I["T"]] *= ((1 + floor) / (per_cell + floor))[:, None, None] ** 2
    assert parts["mse"] == pytest.approx(squared.mean(), rel=1e-12)
    weights = head.tension_weights(target, n_cells).numpy()
    assert weights[0] > weights[1] > weights[2]  # the lowest tension weighs most
    assert PhysicsHead.from_dict(head.to_dict()).tension_floor == floor
    for bad in (0.0, -1.0, float("nan")):
        with pytest.raises(ValueError, match="tension_floor"):
            PhysicsHead(scale, tau, tension_floor=bad)
        with pytest.raises(ValueError, match="TrainConfig.tension_floor"):
            TrainConfig(network="unet", head="physics", loss="gaussian", tension_floor=bad)
    with pytest.raises(ValueError, match="needs head 'physics'"):
        TrainConfig(network="unet", loss="mse", tension_floor=0.5)


def test_noise_weight_weighs_each_moulds_error_against_its_predicted_noise():
    """The mean's term against a numpy sum: each mould's squared error times its predicted
    noise (the mean of (spread / scale)^2) to the power -noise_weight, over the batch's mean
    and clipped to NOISE_WEIGHT_RANGE;
    no gradient through the weights, and noise_weight 0 the plain mean."""
    rng = np.random.default_rng(5)
    scale, tau, gamma = np.linspace(0.5, 1.5, 8), 0.02, 1.0
    out = torch.from_numpy(rng.normal(size=(3, 16, 6, 6)))
    out[:, 8:] += torch.tensor([-2.0, 0.0, 2.0], dtype=torch.float64)[:, None, None, None]
    target = torch.from_numpy(np.abs(rng.normal(size=(3, 8, 6, 6))))
    n_cells = [30.0, 40.0, 50.0]
    head = PhysicsHead(scale, tau, nll_weight=0.0, noise_weight=gamma)
    _, parts = head.loss(out, target, n_cells)
    fields, spread = head.decode(out, torch.tensor(n_cells, dtype=torch.float64),
                                 calibrated=False)
    squared = ((fields - target).numpy() / scale[None, :, None, None]) ** 2
    noise = ((spread.numpy() / scale[None, :, None, None]) ** 2).mean(axis=(1, 2, 3))
    w = np.clip(noise ** -gamma / np.mean(noise ** -gamma), *NOISE_WEIGHT_RANGE)
    assert w[0] > w[1] > w[2]  # the quietest mould weighs most
    assert parts["mse"] == pytest.approx(np.mean(squared.mean(axis=(1, 2, 3)) * w), rel=1e-12)
    plain = PhysicsHead(scale, tau, nll_weight=0.0)
    assert plain.loss(out, target, n_cells)[1]["mse"] == pytest.approx(squared.mean(), rel=1e-12)
    x = out.clone().requires_grad_(True)
    head.loss(x, target, n_cells)[0].backward()
    assert torch.all(x.grad[:, 8:] == 0)  # with nll_weight 0 nothing trains the spread
    assert PhysicsHead.from_dict(head.to_dict()).noise_weight == gamma
    for bad in (-1.0, float("nan")):
        with pytest.raises(ValueError, match="noise_weight"):
            PhysicsHead(scale, tau, noise_weight=bad)
        with pytest.raises(ValueError, match="TrainConfig.noise_weight"):
            TrainConfig(network="unet", head="physics", loss="gaussian", noise_weight=bad)


@pytest.mark.parametrize("weights, match", [
    ([1.0] * 7, "8 finite values"), ([1, 1, 1, 1, 1, 1, -1, -1], "8 finite values"),
    ([0.0] * 8, "not all 0"), ([1, 1, 2, 1, 1, 1, 1, 1], "Sx2 and Sy2 must be equal"),
    ([1, 1, 1, 1, 1, 1, 2, 1], "SxSz and SySz must be equal")])
def test_field_weights_are_checked(weights, match):
    with pytest.raises(ValueError, match=match):
        PhysicsHead(np.ones(8), 1.0, field_weights=weights)
    with pytest.raises(ValueError, match="TrainConfig.field_weights"):
        TrainConfig(network="unet", head="physics", loss="gaussian", field_weights=weights)


def test_area_threshold_is_the_statistics_threshold():
    """Pixels above area_threshold_per_pixel are the area mould_statistics counts, at any
    pixel size, and the soft area approaches that count for values off the threshold."""
    rng = np.random.default_rng(4)
    for pixel in (31.25 / 64, 0.25, 62.5 / 256):
        threshold = area_threshold_per_pixel(pixel)
        fields = np.zeros((8, 40, 40))
        # densities at least half the threshold away from it (the soft count is exact there
        # up to the sigmoid's tails, < 0.02 per pixel)
        fields[0] = threshold * rng.choice([0.0, 0.5, 1.5, 2.0, 3.0], size=(40, 40))
        per_paper_pixel = (62.5 / 256 / pixel) ** 2
        count = mould_statistics(fields, pixel)["n_P_gt_0.2"] * per_paper_pixel
        assert count == pytest.approx(np.count_nonzero(fields[0] > threshold))
        head = PhysicsHead(np.ones(8), 1.0, area_weight=1.0, area_threshold=threshold)
        soft = head.soft_area(torch.from_numpy(fields[None, 0])).item()
        assert soft == pytest.approx(count, abs=1600 * 0.02)


def test_area_term_adds_the_relative_soft_area_error():
    rng = np.random.default_rng(5)
    out = torch.from_numpy(rng.normal(size=(2, 16, 8, 8)))
    target = torch.zeros(2, 8, 8, 8, dtype=torch.float64)
    target[0, I["P"], 2:6, 2:6] = 4.0  # 16 pixels well above the threshold 1
    target[1, I["P"], 1:7, 1:7] = 1.5
    n_cells = [64.0, 54.0]
    plain = PhysicsHead(np.ones(8), 0.02)
    head = PhysicsHead(np.ones(8), 0.02, area_weight=0.7, area_threshold=1.0)
    loss, parts = head.loss(out, target, n_cells)
    fields, _ = head.decode(out, torch.tensor(n_cells, dtype=torch.float64))
    sigmoid = lambda x: 1 / (1 + np.exp(-x))
    soft = lambda p: sigmoid((p - 1.0) / 0.125).sum(axis=(1, 2))
    pred, true = soft(fields[:, I["P"]].numpy()), soft(target[:, I["P"]].numpy())
    expected = (np.abs(pred - true) / (true + 1)).mean()
    assert parts["area"] == pytest.approx(expected, rel=1e-10)
    assert loss.item() == pytest.approx(plain.loss(out, target, n_cells)[0].item()
                                        + 0.7 * expected, rel=1e-12)
    # a perfect density costs nothing
    exact = out.clone()
    exact[:, 0] = torch.log(target[:, I["P"]] + 1e-300)
    assert head.loss(exact, target, n_cells)[1]["area"] < 1e-9
    with pytest.raises(ValueError, match="area_threshold"):
        PhysicsHead(np.ones(8), 1.0, area_weight=1.0)
    with pytest.raises(ValueError, match="area_weight.*needs head 'physics'"):
        TrainConfig(network="unet_l1", area_weight=1.0)


def test_cell_count_of_a_pixel_aligned_rectangle_is_exact():
    pixel, depth = 0.5, 4.0
    inputs = np.zeros((2, 40, 40), dtype=np.uint8)
    inputs[0, 6:30, 4:33] = 1  # rows y 3..15 l0, columns x 2..16.5 l0
    polygon = box(4 * pixel, 6 * pixel, 33 * pixel, 30 * pixel)
    exact = build_lattice(polygon, np.zeros((0, 3)), depth).n_cells
    assert n_cells_of_mould(polygon, np.zeros((0, 3)), depth) == exact
    assert estimate_n_cells(inputs, pixel, depth) == exact
    batch = estimate_n_cells(np.stack([inputs, inputs]), pixel, depth)
    assert batch.shape == (2,) and np.all(batch == exact)
    with pytest.raises(ValueError, match="pixel_size"):
        estimate_n_cells(inputs, -1.0, depth)


def test_cell_count_estimate_of_a_slanted_mould_is_close():
    pixel, depth, n = 0.25, 2.0, 64
    polygon = Polygon([(3.1, 2.2), (13.3, 4.9), (11.0, 13.7), (2.6, 10.4)])
    centres = (np.arange(n) + 0.5) * pixel
    x, y = np.meshgrid(centres, centres)
    from shapely import contains_xy
    inputs = np.stack([contains_xy(polygon, x, y), np.zeros_like(x, bool)]).astype(np.uint8)
    exact = build_lattice(polygon, np.zeros((0, 3)), depth).n_cells
    assert abs(estimate_n_cells(inputs, pixel, depth) / exact - 1) < 0.03


@pytest.fixture(scope="module")
def physics_ds():
    ds = synthetic_dataset(12, 32, splits=("train",) * 8 + ("val", "test"))
    ds.attrs["scene"] = {"depth": 2.0}  # recorded in the checkpoint, for estimate_n_cells
    return ds


PHYSICS = dict(network="unet", head="physics", loss="gaussian",
               unet=UNetConfig.for_size(32, base=8, upsample="bilinear"), batch_size=4,
               lr=2e-3, seed=2, augment=True)


class Killed(Exception):
    pass


def kill(line):  # called after the epoch's checkpoint is written
    raise Killed(line)


def test_physics_training_resumes_bit_identically(physics_ds, tmp_path):
    cfg = TrainConfig(**PHYSICS, epochs=2)
    full = train(physics_ds, cfg, tmp_path / "full.pt", log=QUIET)
    with pytest.raises(Killed):
        train(physics_ds, cfg, tmp_path / "resumed.pt", log=kill)
    resumed = train(physics_ds, cfg, tmp_path / "resumed.pt", log=QUIET)
    a, b = (load_checkpoint(tmp_path / f)["generator"] for f in ("full.pt", "resumed.pt"))
    assert all(torch.equal(a[k], b[k]) for k in a)
    assert [h["mse"] for h in resumed] == [h["mse"] for h in full]
    assert {"mse", "nll", "val_mae"} <= set(full[-1])
    with pytest.raises(CheckpointMismatchError, match="head: checkpoint 'physics' vs now 'tanh'"):
        train(physics_ds, TrainConfig(network="unet", unet=PHYSICS["unet"], epochs=2, batch_size=4,
                                      lr=2e-3, seed=2, augment=True), tmp_path / "full.pt",
              log=QUIET)


def test_validating_less_often_leaves_the_weights_and_the_calibration_alone(physics_ds, tmp_path):
    """val_every only skips the diagnostic val_mae of the epochs between: the weights are
    bit-identical and the last epoch, always validated, sets the same spread calibration (to
    rounding: each validation rescales the factor by the coverage it finds)."""
    every = train(physics_ds, TrainConfig(**PHYSICS, epochs=3), tmp_path / "every.pt", log=QUIET)
    sparse = train(physics_ds, TrainConfig(**PHYSICS, epochs=3, val_every=5),
                   tmp_path / "sparse.pt", log=QUIET)
    a, b = (load_checkpoint(tmp_path / f) for f in ("every.pt", "sparse.pt"))
    assert all(torch.equal(a["generator"][k], b["generator"][k]) for k in a["generator"])
    assert b["scaling"]["spread_factor"] == pytest.approx(a["scaling"]["spread_factor"], rel=1e-6)
    assert [h["val_mae"] is None for h in sparse] == [True, True, False]
    assert all(h["val_mae"] is not None for h in every)
    assert sparse[-1]["val_mae"] == every[-1]["val_mae"]


def test_checkpoint_records_the_kernel_width_and_older_ones_still_resume(physics_ds, tmp_path):
    """A store drawn with another kernel width (scene_overrides sigma): the Predictor draws a
    new mould's lattice channels with that width, not the default's; a checkpoint written
    before the width was recorded still resumes."""
    from condor.data.inputs import lattice_channels
    from condor.model.scenes import SIGMA_L0

    ds = physics_ds.copy()
    ds.attrs = {**physics_ds.attrs, "scene": {"depth": 2.0, "sigma": 1.7}}
    path = tmp_path / "m.pt"
    train(ds, TrainConfig(**PHYSICS, epochs=1), path, log=QUIET)
    predictor = Predictor(path)
    assert predictor.sigma == 1.7 != SIGMA_L0
    polygon, tethers = box(3, 3, 12, 12), np.array([[4.0, 4.0, 1.0]])  # x, y, radius
    mould = type("Mould", (), {"polygon": polygon, "tethers": tethers})()
    box_side = predictor.pixel_size * predictor.native
    np.testing.assert_array_equal(
        predictor.lattice_of(mould), lattice_channels(polygon, tethers, 2.0, box_side, 32, 1.7))
    assert not np.allclose(predictor.lattice_of(mould),
                           lattice_channels(polygon, tethers, 2.0, box_side, 32, SIGMA_L0))
    # as written before the width was recorded: an interrupted run still resumes
    with pytest.raises(Killed):
        train(ds, TrainConfig(**PHYSICS, epochs=2), path, log=kill, resume=False)
    state = load_checkpoint(path)
    del state["data"]["sigma"]
    torch.save(state, path)
    lines = []
    history = train(ds, TrainConfig(**PHYSICS, epochs=2), path, log=lines.append)
    assert len(history) == 2 and lines[0].startswith("resuming") and len(lines) == 2
    with pytest.raises(CheckpointMismatchError, match="data sigma: checkpoint 1.7 vs now"):
        train(physics_ds, TrainConfig(**PHYSICS, epochs=3), path, log=QUIET)


def test_physics_prediction_keeps_relations_and_writes_spread(physics_ds, tmp_path):
    path = tmp_path / "m.pt"
    train(physics_ds, TrainConfig(**PHYSICS, epochs=1, symmetrise=True), path, log=QUIET)
    test = usable_samples(physics_ds, "test")
    inputs = physics_ds["inputs"].values[test].astype(np.float32)
    n_cells = np.array([123.0])
    predictor = Predictor(path)
    assert predictor.needs_n_cells
    p = predictor(inputs, n_cells=n_cells)
    assert p.spread.shape == p.raw.shape and np.all(p.spread > 0)
    np.testing.assert_allclose(p.raw[:, I["P"]].sum(axis=(1, 2)), n_cells, rtol=1e-5)
    np.testing.assert_allclose(p.raw[:, I["Sx2"]] + p.raw[:, I["Sy2"]] + p.raw[:, I["Sz2"]],
                               p.raw[:, I["P"]], rtol=1e-4, atol=1e-6)
    np.testing.assert_array_equal(p.raw[:, I["SxSz"]], 0)  # z-flip symmetrised
    # symmetrised: the prediction of a transformed mould is the transformed prediction
    for k in (1, 2, 7):
        gx, _ = apply_symmetry(k, inputs=inputs)
        q = predictor(np.ascontiguousarray(gx), n_cells=n_cells)
        np.testing.assert_allclose(q.raw, apply_symmetry(k, fields=p.raw)[1], atol=1e-5)
        spread_k = np.abs(apply_symmetry(k, fields=p.spread)[1])
        np.testing.assert_allclose(q.spread, spread_k, rtol=1e-4, atol=1e-7)
    single = predict(path, inputs[0])  # N_c estimated from the pixels
    assert single.n_cells == pytest.approx(predictor.estimate_n_cells(inputs[0]), rel=1e-5)
    write_prediction(tmp_path / "p.zarr", predictor(inputs[0], n_cells=123), inputs[0], 0.5)
    written = xr.open_zarr(tmp_path / "p.zarr")
    assert written["spread"].dims == ("field", "y", "x")
    assert float(written["raw"].sel(field="P").sum()) == pytest.approx(123, rel=1e-5)
    prediction_panels(inputs[0], single, tmp_path / "p.png")
    assert (tmp_path / "p.png").stat().st_size > 0
    # a mould JSON through `condor predict`: N_c is its exact lattice count at the scene's depth
    mould = generate_mould(3, 1, replace(get_scene("tiny"), box=predictor.box))
    save_json(mould, tmp_path / "m.json")
    cli.main(["predict", str(tmp_path / "m.json"), "--checkpoint", str(path), "--out",
              str(tmp_path / "m.zarr"), "--check", "0"])  # the surrogate's own prediction
    from_file = xr.open_zarr(tmp_path / "m.zarr")
    exact = build_lattice(mould.polygon, mould.tethers, 2.0).n_cells
    assert float(from_file["raw"].sel(field="P").sum()) == pytest.approx(exact, rel=1e-5)
    assert "spread" in from_file


def test_old_tanh_checkpoints_still_predict_without_spread(physics_ds, tmp_path):
    path = tmp_path / "old.pt"
    train(physics_ds, TrainConfig(network="unet_l1", unet=UNetConfig.for_size(32, base=8),
                                  epochs=1, batch_size=4), path, log=QUIET)
    state = load_checkpoint(path)
    for key in ("upsample", "output"):  # written before these settings existed
        state["generator_config"].pop(key)
    torch.save(state, path)
    p = predict(path, physics_ds["inputs"].values[:2].astype(np.float32))
    assert p.spread is None and p.raw.shape == (2, 8, 32, 32)


def test_config_rejects_inconsistent_heads():
    with pytest.raises(ValueError, match="gaussian.*physics"):
        TrainConfig(network="unet", loss="gaussian")
    with pytest.raises(ValueError, match="needs network 'unet'"):
        TrainConfig(network="unet_l1", head="physics", loss="gaussian")
    with pytest.raises(ValueError, match="sum_weight.*needs head 'physics'"):
        TrainConfig(network="unet_l1", sum_weight=1.0)
    with pytest.raises(ValueError, match="sum_weight = -1"):
        TrainConfig(network="unet", head="physics", loss="gaussian", sum_weight=-1.0)
    with pytest.raises(ValueError, match="sum_weight must be finite"):
        PhysicsHead(np.ones(8), 1.0, sum_weight=float("nan"))
    with pytest.raises(ValueError, match="upsample 'cubic'"):
        UNetConfig(size=32, depth=3, upsample="cubic")


def test_upsampling_without_transpose_has_no_checkerboard():
    """A constant feature map through an untrained decoder: the transposed convolution's
    uneven overlap imprints a period-2 pattern, resizing does not."""
    torch.manual_seed(0)
    amplitude = {}
    for mode in ("transpose", "resize", "bilinear"):
        g = UNetGenerator(UNetConfig.for_size(32, base=8, upsample=mode, output="linear"),
                          torch.Generator().manual_seed(0)).eval()
        with torch.no_grad():
            y = g(torch.ones(1, 2, 32, 32)).numpy()[0, :, 4:-4, 4:-4]
        amplitude[mode] = checkerboard(y).mean() / np.abs(y).mean()
    assert amplitude["transpose"] > 10 * max(amplitude["resize"], amplitude["bilinear"])


def test_interval_coverage_and_spread_agreement_on_gaussian_draws():
    rng = np.random.default_rng(1)
    mean = rng.normal(size=(6, 2, 8, 8))
    std = rng.uniform(0.2, 2.0, size=(6, 1, 1, 1)) * rng.uniform(0.5, 1.5, size=(6, 2, 8, 8))
    replicas = mean[:, None] + std[:, None] * rng.normal(size=(6, 400, 2, 8, 8))
    mask = np.zeros((6, 8, 8), bool)
    mask[:, 2:7, 1:6] = True
    coverage = interval_coverage(mean, std, replicas, mask)
    for level, per_mould in coverage.items():
        np.testing.assert_allclose(per_mould, level, atol=0.02)
    assert interval_coverage(mean, 0.5 * std, replicas, mask)[0.9].mean() < 0.65
    agree = spread_agreement(std, replicas, mask)
    assert agree["r"] > 0.99 and agree["ratio"] == pytest.approx(1, abs=0.03)
    assert np.all(agree["pixel_r"] > 0.9)
    assert z_of(0.9) == pytest.approx(1.6449, abs=1e-4)
    inputs = np.zeros((1, 2, 4, 4))
    inputs[0, 0, 1, 1] = inputs[0, 1, 2, 2] = 1
    assert tissue_pixels(inputs).sum() == 2


def test_checkerboard_measures_the_period_two_pattern():
    yy, xx = np.mgrid[0:16, 0:16]
    pattern = 0.3 * (-1.0) ** (xx + yy)
    smooth = np.sin(xx / 5.0) + yy / 16
    assert checkerboard(pattern) == pytest.approx(0.3)
    assert checkerboard(smooth + pattern) == pytest.approx(0.3, abs=0.01)
    assert checkerboard(smooth) < 0.01


def test_cosine_schedule_resumes_bit_identically_and_ends_near_zero(physics_ds, tmp_path):
    cfg = TrainConfig(**PHYSICS, epochs=3, lr_schedule="cosine")
    train(physics_ds, cfg, tmp_path / "full.pt", log=QUIET)
    with pytest.raises(Killed, match="epoch 1/3"):
        train(physics_ds, cfg, tmp_path / "resumed.pt", log=kill)
    train(physics_ds, cfg, tmp_path / "resumed.pt", log=QUIET)
    a, b = (load_checkpoint(tmp_path / f) for f in ("full.pt", "resumed.pt"))
    assert all(torch.equal(a["generator"][k], b["generator"][k]) for k in a["generator"])
    # the last epoch's rate: 2e-3 * (1 + cos(2 pi / 3)) / 2 = 5e-4; constant stays at 2e-3
    assert a["opt_g"]["param_groups"][0]["lr"] == pytest.approx(5e-4)
    constant = train(physics_ds, TrainConfig(**PHYSICS, epochs=3), tmp_path / "const.pt",
                     log=QUIET)
    assert load_checkpoint(tmp_path / "const.pt")["opt_g"]["param_groups"][0]["lr"] == 2e-3
    scheduled = a["history"]
    assert constant[0]["mse"] == scheduled[0]["mse"]  # epoch 0: equal rates, equal steps
    assert constant[2]["mse"] != scheduled[2]["mse"]


def test_checkpoint_from_before_a_new_setting_resumes(physics_ds, tmp_path):
    """A checkpoint written before lr_schedule existed resumes under the setting's default and
    is refused under another value."""
    path = tmp_path / "old.pt"
    with pytest.raises(Killed):  # interrupted after epoch 1 of 2
        train(physics_ds, TrainConfig(**PHYSICS, epochs=2), path, log=kill)
    state = load_checkpoint(path)
    del state["config"]["lr_schedule"]
    torch.save(state, path)
    with pytest.raises(CheckpointMismatchError, match="lr_schedule: checkpoint 'constant' vs now 'cosine'"):
        train(physics_ds, TrainConfig(**PHYSICS, epochs=2, lr_schedule="cosine"), path, log=QUIET)
    assert len(train(physics_ds, TrainConfig(**PHYSICS, epochs=2), path, log=QUIET)) == 2



def test_interval_coverage_counts_only_the_replicas_a_mould_holds():
    """NaN-padded replicas (a mould with fewer): coverage and spread equal those of the
    mould's own replicas, never counting padding as outside."""
    rng = np.random.default_rng(3)
    mean, std = rng.normal(size=(3, 1, 6, 6)), rng.uniform(0.5, 1.5, size=(3, 1, 6, 6))
    replicas = mean[:, None] + std[:, None] * rng.normal(size=(3, 30, 1, 6, 6))
    replicas[0, 10:] = np.nan
    mask = np.ones((3, 6, 6), bool)
    padded = interval_coverage(mean, std, replicas, mask)[0.9]
    own = interval_coverage(mean[:1], std[:1], replicas[:1, :10], mask[:1])[0.9]
    assert padded[0] == pytest.approx(own[0]) and padded[0] > 0.8
    agree = spread_agreement(std, replicas, mask)
    assert agree["replica"][0] == pytest.approx(
        spread_agreement(std[:2], replicas[:2, :10], mask[:2])["replica"][0])
