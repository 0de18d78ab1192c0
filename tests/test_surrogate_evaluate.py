"""Evaluation metrics, baselines, normalisation and the evaluation/prediction entry points."""

import numpy as np
import pandas as pd
import pytest
import torch

from condor import plots
from condor.measures.metrics import normalise_predicted

from condor.surrogate.baselines import MaskedMeanBaseline, MouldBlurBaseline, gaussian_blur
from condor.surrogate.checkpoint import save_checkpoint
from condor.surrogate.samples import FIELD_NAMES, FieldScaling
from condor.surrogate.evaluate import (best_worst, correlation_table, evaluate, mae_frame,
                                       pearson_r, statistics_frame)
from condor.surrogate.networks import UNetConfig, paper_generator
from condor.surrogate.predict import predict
from condor.surrogate.synthetic import synthetic_dataset
from condor.surrogate.train import TrainConfig, train


def stand_in_statistics(fields, pixel_size, n_cells=None):
    """A local stand-in with mould_statistics' signature."""
    n_cells = fields[0].sum() if n_cells is None else n_cells
    return {"mean_P": fields[0].mean() / pixel_size ** 2, "mean_T_norm": fields[1].sum() / n_cells}


def test_pearson_r_matches_numpy():
    rng = np.random.default_rng(0)
    x = rng.normal(size=50)
    y = 0.7 * x + rng.normal(scale=0.5, size=50)
    assert pearson_r(x, y) == pytest.approx(np.corrcoef(x, y)[0, 1], rel=1e-12)
    assert pearson_r(x, -x) == pytest.approx(-1)
    assert np.isnan(pearson_r(x, np.ones(50)))


def test_mae_frame_and_best_worst_brute_force():
    rng = np.random.default_rng(1)
    pred, true = rng.random((5, 8, 4, 4)), rng.random((5, 8, 4, 4))
    ids = [10, 11, 12, 13, 14]
    mae = mae_frame(pred, true, ids)
    for s in range(5):
        for f, name in enumerate(FIELD_NAMES):
            expect = sum(abs(pred[s, f, i, j] - true[s, f, i, j]) for i in range(4) for j in range(4)) / 16
            assert mae.loc[ids[s], name] == pytest.approx(expect)
    best, worst = best_worst(mae, "Sx2", n=2)
    order = np.argsort(mae["Sx2"].to_numpy())
    assert best == [ids[order[0]], ids[order[1]]] and worst == [ids[order[-1]], ids[order[-2]]]
    with pytest.raises(ValueError, match="shape"):
        mae_frame(pred, true[:, :, :2], ids)


def test_statistics_and_correlations_against_corrcoef():
    rng = np.random.default_rng(2)
    true = rng.random((12, 8, 6, 6)) + 0.1
    pred = true * rng.uniform(0.8, 1.2, (12, 1, 1, 1)) + rng.normal(0, 0.05, true.shape)
    sim = statistics_frame(true, 0.5, statistics_fn=stand_in_statistics)
    prd = statistics_frame(pred, 0.5, statistics_fn=stand_in_statistics)
    np.testing.assert_allclose(sim["mean_P"], true[:, 0].mean(axis=(1, 2)) / 0.25)
    table = correlation_table(sim, prd)
    for name in ("mean_P", "mean_T_norm"):
        assert table.loc[name, "r"] == pytest.approx(np.corrcoef(sim[name], prd[name])[0, 1], rel=1e-10)
    assert table.loc["mean_P", "paper_r"] == 0.881 and table.loc["mean_T_norm", "paper_relation"] == ">"
    # The project's real statistics, when present, go through the same path.
    statistics = pytest.importorskip("condor.data.statistics")
    real = statistics_frame(true.astype(np.float32), 0.5)
    assert list(real.columns) == list(statistics.STATISTICS)
    np.testing.assert_allclose(real["mean_T_norm"], true[:, 1].sum(axis=(1, 2)) / true[:, 0].sum(axis=(1, 2)), rtol=1e-5)


def test_normalise_uses_predicted_density_sum():
    rng = np.random.default_rng(3)
    raw = rng.random((3, 8, 5, 5)).astype(np.float32)
    normalised = normalise_predicted(raw)
    n_cells = raw[:, 0].sum(axis=(1, 2), dtype=np.float64)
    raw[2, 0] = 0.0  # no predicted density: undefined normalisation
    assert np.isnan(normalise_predicted(raw)[2]).all() and np.isfinite(normalise_predicted(raw)[:2]).all()
    np.testing.assert_allclose(normalised[:, 0].sum(axis=(1, 2)), 25, rtol=1e-5)  # = N_p
    np.testing.assert_allclose(normalised[1, 3], raw[1, 3] * 25 / n_cells[1], rtol=1e-5)


def test_baselines_against_direct_computation():
    rng = np.random.default_rng(4)
    inputs = (rng.random((6, 2, 16, 16)) > 0.6).astype(np.float32)
    inputs[:, 1] *= 1 - inputs[:, 0]
    fields = rng.random((6, 8, 16, 16))
    occ = np.clip(inputs[:, 0] + inputs[:, 1], 0, 1)
    mm = MaskedMeanBaseline().fit(inputs, fields)
    i, j = 3, 7
    inside = occ[:, i, j] > 0
    assert mm.mean_in[2, i, j] == pytest.approx(fields[inside, 2, i, j].mean())
    assert mm.mean_out[2, i, j] == pytest.approx(fields[~inside, 2, i, j].mean())
    # The blur of a lone pixel is the sampled Gaussian.
    delta = np.zeros((1, 21, 21))
    delta[0, 10, 10] = 1
    g = gaussian_blur(delta, 2.0)[0]
    k = np.exp(-0.5 * (np.arange(-8, 9) / 2.0) ** 2)
    np.testing.assert_allclose(g[2:19, 2:19], np.outer(k, k) / k.sum() ** 2, rtol=1e-12)
    # Fields built as a_f * blur + b_f are recovered by the least-squares fit.
    blur = MouldBlurBaseline(pixel_size=0.5, sigma_multiples=(1.0,))
    sigma_px = 0.732421875 / 0.5
    exact = np.arange(8)[None, :, None, None] * 0.3 * gaussian_blur(occ, sigma_px)[:, None] + 0.1
    fitted = blur.fit(inputs, exact).predict(inputs)
    np.testing.assert_allclose(fitted, exact, atol=1e-5)


def test_paper_generator_on_small_scene_resamples(tmp_path):
    """A pix2pix (256 px) checkpoint serves 32 px moulds: inputs up, fields down, sums kept."""
    torch.manual_seed(0)
    g = paper_generator()
    scaling = FieldScaling(np.zeros(8), np.full(8, 2.0))
    save_checkpoint({"config": TrainConfig().to_dict(), "generator_config": g.cfg.to_dict(),
                     "generator": g.state_dict(), "scaling": scaling.to_dict(),
                     "data": {"native_size": 32}}, tmp_path / "paper.pt")
    inputs = np.zeros((2, 32, 32), dtype=np.uint8)
    inputs[0, 8:24, 8:24] = 1
    out = predict(tmp_path / "paper.pt", inputs, mode="eval")
    assert out.raw.shape == (8, 32, 32) and out.normalised.shape == (8, 32, 32)
    # Independently: replicate pixels 8x, run the network, unscale, sum 8x8 blocks.
    big = torch.from_numpy(np.kron(inputs, np.ones((8, 8))).astype(np.float32))[None]
    with torch.no_grad():
        y = g.eval()(big)[0].double().numpy() + 1.0  # (y + 1) * span / 2 + lo with span 2, lo 0
    expect = y.reshape(8, 32, 8, 32, 8).sum(axis=(2, 4))
    np.testing.assert_allclose(out.raw, expect, rtol=1e-4)
    assert out.n_cells == pytest.approx(out.raw[0].sum(), rel=1e-5)


def test_evaluate_end_to_end(tmp_path):
    ds = synthetic_dataset(12, 32, splits=("train",) * 4 + ("val", "test"))
    cfg = TrainConfig(network="unet_l1", unet=UNetConfig.for_size(32, base=8), epochs=2, seed=0)
    train(ds, cfg, tmp_path / "m.pt", log=lambda s: None)
    result = evaluate(tmp_path / "m.pt", ds, out_dir=tmp_path / "eval", pixel_size=0.5,
                      statistics_fn=stand_in_statistics)
    summary = result["summary"]
    assert list(summary.index) == ["unet_l1_eval", "unet_l1_train", "masked_mean", "mould_blur"]
    ev = result["evaluations"]["mould_blur"]
    assert len(ev.mae) == 2 and set(ev.correlations.index) == {"mean_P", "mean_T_norm"}
    assert summary.loc["mould_blur", "mae_mean"] == pytest.approx(ev.mae["mean"].mean())
    written = {p.name for p in (tmp_path / "eval").iterdir()}
    assert {"summary.csv", "unet_l1_eval_mae.csv", "mould_blur_correlations.csv"} <= written
    assert not any(name.endswith(".png") for name in written)  # computing draws nothing
    paths = plots.evaluation_figures(ev, result["truth"], result["predictions"]["mould_blur"],
                                     tmp_path / "figures")
    assert {p.name for p in paths} >= {"mould_blur_T_worst.png", "mould_blur_statistics.png"}
    assert pd.read_csv(tmp_path / "eval" / "summary.csv").shape[0] == 4
    with pytest.raises(ValueError, match="'val'"):
        evaluate(tmp_path / "m.pt", ds.assign(status=ds["status"].where(ds["split"] != "val", "x")),
                 split="val", pixel_size=0.5, statistics_fn=stand_in_statistics)
