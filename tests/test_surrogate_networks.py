"""Networks of the surrogate: the paper's tables, shapes, BatchNorm, prediction modes, losses,
resampling."""

import math

import numpy as np
import pytest
import torch
from torch import nn

from condor.surrogate.samples import resample_fields, resample_masks
from condor.surrogate.networks import (PatchConfig, PatchDiscriminator, TFBatchNorm2d, UNetConfig,
                                     UNetGenerator, count_parameters_like_paper, discriminator_loss,
                                     generator_loss, paper_discriminator, paper_generator,
                                     prediction_mode, sigmoid_cross_entropy)

# Parameter Count column of the Appendix tables, non-zero rows in order (typed from the paper).
PAPER_GENERATOR_ROWS = [2048, 131072, 512, 524288, 1024, 2097152, 2048, 4194304, 2048, 4194304,
                        2048, 4194304, 2048, 4194304, 2048, 4194304, 2048, 8388608, 2048, 8388608,
                        2048, 8388608, 2048, 4194304, 1024, 1048576, 512, 262144, 256, 16392]
PAPER_DISCRIMINATOR_ROWS = [10240, 131072, 512, 524288, 1024, 2097152, 2048, 8193]


def _rows(model: nn.Module) -> list[int]:
    """Per-layer counts like Keras: conv weights + bias; BN gamma, beta, mean, var."""
    rows = []
    for m in model.modules():
        if isinstance(m, (nn.Conv2d, nn.ConvTranspose2d)):
            rows.append(sum(p.numel() for p in m.parameters()))
        elif isinstance(m, nn.BatchNorm2d):
            rows.append(4 * m.num_features)
    return rows


@pytest.fixture(scope="module")
def paper_nets():
    torch.manual_seed(0)
    return paper_generator(), paper_discriminator()


def test_parameter_counts_equal_paper_tables(paper_nets):
    g, d = paper_nets
    assert sum(PAPER_GENERATOR_ROWS) == 54_435_080  # the paper's total
    assert sum(PAPER_DISCRIMINATOR_ROWS) == 2_774_529
    assert count_parameters_like_paper(g) == 54_435_080
    assert count_parameters_like_paper(d) == 2_774_529
    assert _rows(g) == PAPER_GENERATOR_ROWS
    assert _rows(d) == PAPER_DISCRIMINATOR_ROWS


def test_paper_shapes_256_to_30x30_patch(paper_nets):
    g, d = paper_nets
    x = torch.rand(1, 2, 256, 256).round()
    shapes = []
    hooks = [blk.register_forward_hook(lambda m, i, o: shapes.append(tuple(o.shape[1:])))
             for blk in list(g.down) + list(g.up)]
    with prediction_mode(g, "eval"), torch.no_grad():
        y = g(x)
        logits = d(x, y)
    for h in hooks:
        h.remove()
    # Encoder rows 2..24 and decoder rows 25..54 of the generator table (channels, H, W).
    enc = [(64, 128), (128, 64), (256, 32), (512, 16), (512, 8), (512, 4), (512, 2), (512, 1)]
    dec = [(512, 2), (512, 4), (512, 8), (512, 16), (256, 32), (128, 64), (64, 128)]
    assert shapes == [(c, s, s) for c, s in enc + dec]
    assert y.shape == (1, 8, 256, 256) and float(y.abs().max()) <= 1.0
    assert logits.shape == (1, 1, 30, 30)
    assert PatchConfig().output_side(256) == 30


def test_unet_family_shapes_and_sizes():
    small = UNetConfig.for_size(64, base=16)
    assert small.depth == 4
    g = UNetGenerator(small)
    with torch.no_grad():
        y = g.eval()(torch.zeros(3, 2, 64, 64))
    assert y.shape == (3, 8, 64, 64)
    assert count_parameters_like_paper(g) < 54_435_080 / 50
    d = PatchDiscriminator(PatchConfig(base=16, n_down=2))
    assert d(torch.zeros(2, 2, 64, 64), y[:2]).shape == (2, 1, 14, 14)
    with pytest.raises(ValueError, match="size=48"):
        UNetConfig(size=48, depth=5)


def test_tf_batchnorm_matches_numpy_and_accepts_one_value():
    torch.manual_seed(1)
    bn = TFBatchNorm2d(3)
    with torch.no_grad():
        bn.weight.copy_(torch.tensor([1.0, 2.0, 0.5]))
        bn.bias.copy_(torch.tensor([0.0, -1.0, 3.0]))
    x = torch.randn(4, 3, 5, 5)
    y = bn.train()(x).detach().numpy()
    a = x.numpy().astype(np.float64)
    mean, var = a.mean(axis=(0, 2, 3)), a.var(axis=(0, 2, 3))  # biased, as TensorFlow
    expect = (a - mean[:, None, None]) / np.sqrt(var[:, None, None] + 1e-3)
    expect = expect * np.array([1, 2, 0.5])[:, None, None] + np.array([0, -1, 3])[:, None, None]
    np.testing.assert_allclose(y, expect, rtol=1e-4, atol=1e-5)
    np.testing.assert_allclose(bn.running_mean.numpy(), 0.01 * mean, rtol=1e-5, atol=1e-7)
    np.testing.assert_allclose(bn.running_var.numpy(), 0.99 + 0.01 * var, rtol=1e-5)
    # One value per channel (1x1 bottleneck, batch 1): normalises to beta, no exception.
    one = bn(torch.randn(1, 3, 1, 1))
    np.testing.assert_allclose(one.detach().numpy().ravel(), [0, -1, 3], atol=1e-6)


def test_prediction_modes_and_restoration():
    torch.manual_seed(2)
    g = UNetGenerator(UNetConfig.for_size(32, base=8))
    g.train()
    g(torch.rand(4, 2, 32, 32))  # move running statistics away from their initial values
    before = {k: v.clone() for k, v in g.state_dict().items()}
    x = torch.rand(2, 2, 32, 32).round()
    outs = {}
    with torch.no_grad():
        for mode in ("eval", "batch_stats", "train"):
            with prediction_mode(g, mode):
                outs[mode] = (g(x), g(x))
    assert torch.equal(*outs["eval"]) and torch.equal(*outs["batch_stats"])
    assert not torch.equal(*outs["train"])  # dropout active
    assert not torch.allclose(outs["eval"][0], outs["batch_stats"][0])
    assert g.training  # restored
    after = g.state_dict()
    assert all(torch.equal(before[k], after[k]) for k in before)
    with pytest.raises(ValueError, match="'bogus'"):
        with prediction_mode(g, "bogus"):
            pass


@pytest.mark.parametrize("upsample", ["transpose", "resize", "bilinear"])
@pytest.mark.parametrize("blocks", [0, 1])
def test_the_inference_copy_is_the_eval_model_with_batchnorm_folded(upsample, blocks):
    """inference_copy folds every BatchNorm into the convolution before it (also across a
    bilinear resize, which commutes with a per-channel affine map) and drops dropout: in
    channels_last order it gives the eval-mode outputs to float32 round-off, whatever the
    running statistics; the model itself is left as it was."""
    from condor.surrogate.networks import inference_copy

    torch.manual_seed(5)
    g = UNetGenerator(UNetConfig.for_size(32, base=8, upsample=upsample, blocks=blocks,
                                          in_channels=6, out_channels=16, output="linear"))
    with torch.no_grad():
        for m in g.modules():
            if isinstance(m, TFBatchNorm2d):
                m.running_mean.normal_()
                m.running_var.uniform_(0.2, 3.0)
                m.weight.normal_(1.0, 0.3)
                m.bias.normal_()
    g.train()
    before = {k: v.clone() for k, v in g.state_dict().items()}
    fast = inference_copy(g)
    assert g.training and all(torch.equal(before[k], v) for k, v in g.state_dict().items())
    assert not any(isinstance(m, (TFBatchNorm2d, nn.Dropout)) for m in fast.modules())
    x = torch.rand(3, 6, 32, 32)
    with torch.no_grad(), prediction_mode(g, "eval"):
        expected = g(x)
    with torch.inference_mode():
        got = fast(x.contiguous(memory_format=torch.channels_last))
    scale = expected.abs().max()
    assert torch.allclose(got, expected, rtol=0, atol=2e-6 * scale)


def test_losses_follow_paper_formulas():
    torch.manual_seed(3)
    real, fake = torch.randn(2, 1, 6, 6), torch.randn(2, 1, 6, 6)
    sig = lambda z: 1 / (1 + np.exp(-z.numpy().astype(np.float64)))
    lsxe = lambda z, y: (y - 1) * np.log(1 - sig(z)) - y * np.log(sig(z))
    np.testing.assert_allclose(sigmoid_cross_entropy(real, 1.0).numpy(), lsxe(real, 1.0), rtol=1e-5)
    expect_d = (lsxe(real, 1.0) + lsxe(fake, 0.0)).reshape(2, -1).sum(1).mean()
    assert float(discriminator_loss(real, fake)) == pytest.approx(expect_d, rel=1e-5)
    gen, lab = torch.rand(2, 8, 4, 4), torch.rand(2, 8, 4, 4)
    total, l1, adv = generator_loss(fake, gen, lab, lam=1000.0)
    l1_np = np.abs(gen.numpy() - lab.numpy()).mean()
    assert float(l1) == pytest.approx(l1_np, rel=1e-5)
    assert float(total) == pytest.approx(1000 * l1_np + lsxe(fake, 1.0).mean(), rel=1e-5)


def test_resampling_conserves_sums_and_round_trips():
    rng = np.random.default_rng(4)
    f = rng.random((3, 8, 16, 16)).astype(np.float32)
    up = resample_fields(f, 64)
    assert up.shape == (3, 8, 64, 64)
    np.testing.assert_allclose(up.sum(axis=(-2, -1)), f.sum(axis=(-2, -1)), rtol=1e-5)
    np.testing.assert_allclose(resample_fields(up, 16), f, rtol=1e-5)
    down = resample_fields(f, 4)
    np.testing.assert_allclose(down[0, 0, 1, 2], f[0, 0, 4:8, 8:12].sum(), rtol=1e-5)
    m = (rng.random((2, 8, 8)) > 0.5).astype(np.uint8)
    big = resample_masks(m, 32)
    assert np.array_equal(big[:, ::4, ::4], m) and np.array_equal(resample_masks(big, 8), m)
    with pytest.raises(ValueError, match="16 px to 24 px"):
        resample_fields(f, 24)
    assert math.isclose(float(resample_masks(np.ones((4, 4)), 2).sum()), 4.0)


def test_residual_blocks_add_depth_and_reduce_to_the_plain_unet():
    """blocks=k adds k residual 3x3 blocks (conv without bias + BatchNorm scale and shift) at
    each encoder and decoder level; with their convolutions zeroed they are the identity, so
    the network computes exactly what the same weights compute without them."""
    plain_cfg = UNetConfig.for_size(32, base=8, upsample="bilinear", output="linear")
    plain = UNetGenerator(plain_cfg, torch.Generator().manual_seed(0)).eval()
    widths = plain_cfg.widths()
    decoder = widths[:-1]  # the decoder's levels, below the bottleneck
    for k in (1, 2):
        deep = UNetGenerator(UNetConfig.for_size(32, base=8, upsample="bilinear",
                                                 output="linear", blocks=k)).eval()
        added = sum(p.numel() for p in deep.parameters()) - \
            sum(p.numel() for p in plain.parameters())
        assert added == k * sum(9 * c * c + 2 * c for c in widths + decoder)
        missing, unexpected = deep.load_state_dict(plain.state_dict(), strict=False)
        assert not unexpected and missing
        with torch.no_grad():
            for name, p in deep.named_parameters():
                if name in missing and p.ndim == 4:
                    p.zero_()
            x = torch.rand(2, 2, 32, 32, generator=torch.Generator().manual_seed(1))
            torch.testing.assert_close(deep(x), plain(x))
    with pytest.raises(ValueError, match="blocks"):
        UNetConfig.for_size(32, blocks=-1)
