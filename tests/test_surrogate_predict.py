"""Prediction's fast path ("eval" mode: the BatchNorm-folded, channels_last inference copy; the
8 planar transforms as one batch, moved back before one decode) gives what the model gives:
one mould at a time or many, as the plain per-transform symmetrisation of the model itself,
and it follows the model's weights when they change."""

import numpy as np
import pytest
import torch

from condor.moulds.paper import MouldParams
from condor.moulds.mould import input_channels
from condor.model.scenes import get_scene
from condor.stages.build import make_mould
from condor.surrogate.checkpoint import save_checkpoint
from condor.surrogate.networks import TFBatchNorm2d, UNetGenerator, prediction_mode
from condor.surrogate.physics import PhysicsHead
from condor.surrogate.predict import Predictor, run_model
from condor.surrogate import inference
from condor.surrogate.symmetrise import symmetrised_reference
from condor.surrogate.variants import preset, train_config

SCENE = get_scene("tiny")


def _randomise_batchnorm(model, seed):
    generator = torch.Generator().manual_seed(seed)
    with torch.no_grad():
        for m in model.modules():
            if isinstance(m, TFBatchNorm2d):
                n = m.num_features
                m.running_mean.copy_(0.3 * torch.randn(n, generator=generator))
                m.running_var.copy_(0.5 + torch.rand(n, generator=generator))
                m.weight.copy_(1.0 + 0.2 * torch.randn(n, generator=generator))
                m.bias.copy_(0.2 * torch.randn(n, generator=generator))


@pytest.fixture(scope="module")
def checkpoint(tmp_path_factory):
    """The default recipe (preset unet: physics head, mechanics inputs, symmetrised) at the
    tiny scene's 32 px and base 8, random weights and BatchNorm statistics."""
    cfg = train_config({**preset("unet"), "base": 8}, SCENE.pixels)
    unet, _ = cfg.networks(SCENE.pixels)
    torch.manual_seed(11)
    model = UNetGenerator(unet)
    _randomise_batchnorm(model, 12)
    head = PhysicsHead(np.linspace(0.5, 2.0, 8), 0.7)
    path = tmp_path_factory.mktemp("predict") / "unet.pt"
    save_checkpoint({"generator": model.state_dict(), "generator_config": unet.to_dict(),
                     "scaling": head.to_dict(), "config": cfg.to_dict(),
                     "data": {"native_size": SCENE.pixels, "pixel_size": SCENE.pixel_size,
                              "depth": SCENE.depth, "sigma": SCENE.sigma}}, path)
    return path


@pytest.fixture(scope="module")
def moulds():
    return [make_mould(SCENE, 5, i, params=MouldParams()) for i in range(5)]


def test_batched_prediction_equals_one_mould_at_a_time(checkpoint, moulds):
    predictor = Predictor(checkpoint, device="cpu", precision="float32")
    assert predictor.symmetrise and predictor.mode == "eval"
    masks = np.stack([input_channels(m, predictor.native) for m in moulds])
    extra = predictor.mould_arguments(moulds)
    together = predictor(masks, batch_size=16, **extra)
    for k in range(len(moulds)):
        alone = predictor(masks[k], batch_size=1, n_cells=extra["n_cells"][k],
                          lattice=extra["lattice"][k])
        for a, b in ((together.raw[k], alone.raw), (together.spread[k], alone.spread)):
            np.testing.assert_allclose(a, b, rtol=1e-5, atol=1e-6 * np.abs(a).max())
    # batches of 2 (the last one short) too
    pairs = predictor(masks, batch_size=2, **extra)
    np.testing.assert_allclose(pairs.raw, together.raw, rtol=1e-5,
                               atol=1e-6 * np.abs(together.raw).max())


def test_the_fast_path_equals_the_model_s_own_symmetrisation(checkpoint, moulds):
    """run_model in "eval" mode (the inference copy, one batch of 8 transforms, one decode)
    against the reference: the model itself in eval mode, each transform run and decoded on
    its own and moved back field by field (apply_symmetry), in float64 until the end."""
    predictor = Predictor(checkpoint, device="cpu")
    masks = np.stack([input_channels(m, predictor.native) for m in moulds])
    extra = predictor.mould_arguments(moulds)
    from condor.data.inputs import stress_channels

    x = np.concatenate([masks.astype(np.float32), extra["lattice"], stress_channels(masks)],
                       axis=1)
    fields, spread = run_model(predictor.model, predictor.scaling, x, "eval", 16, "cpu", True,
                               extra["n_cells"], predictor.inputs_kind)
    with prediction_mode(predictor.model, "eval"), torch.no_grad():
        expected = symmetrised_reference(predictor.model, predictor.scaling, torch.from_numpy(x),
                                         extra["n_cells"], predictor.inputs_kind)
    for got, want in zip((fields, spread), expected):
        np.testing.assert_allclose(got, want, rtol=1e-5, atol=1e-6 * np.abs(want).max())
    assert np.all(fields[:, 6:] == 0)  # SxSz, SySz: exactly zero, as before
    np.testing.assert_allclose(fields[:, 0].sum(axis=(1, 2)), extra["n_cells"], rtol=1e-5)


def test_the_inference_copy_follows_the_weights(checkpoint, moulds):
    """The copy is remade when the model's weights or statistics change (trained, or loaded):
    a prediction after the change is the new model's, not the old copy's."""
    predictor = Predictor(checkpoint, device="cpu")
    masks = np.stack([input_channels(m, predictor.native) for m in moulds[:2]])
    extra = predictor.mould_arguments(moulds[:2])
    first = predictor(masks, **extra).raw
    assert np.array_equal(predictor(masks, **extra).raw, first)
    _randomise_batchnorm(predictor.model, 99)
    changed = predictor(masks, **extra).raw
    assert not np.allclose(changed, first, rtol=1e-3)
    fresh = UNetGenerator(predictor.model.cfg)
    fresh.load_state_dict(predictor.model.state_dict())
    x = predictor(masks, **extra)  # the same weights in another module: the same numbers
    predictor.model = fresh
    np.testing.assert_allclose(predictor(masks, **extra).raw, x.raw, rtol=1e-6,
                               atol=1e-7 * np.abs(x.raw).max())
    # a model left in training mode still predicts in eval mode
    fresh.train()
    np.testing.assert_allclose(predictor(masks, **extra).raw, x.raw, rtol=1e-6,
                               atol=1e-7 * np.abs(x.raw).max())
    assert fresh.training


def test_bfloat16_prediction_is_close_to_float32_and_precision_is_checked(checkpoint, moulds):
    """precision="bfloat16" runs the inference copy in bfloat16: the same fields to a few 1e-3
    of their largest value (a rounding of the arithmetic, not another model), the physics
    head's relations kept exactly (sum P = N_c, SxSz = SySz = 0); an unknown precision is
    refused by name."""
    exact = Predictor(checkpoint, device="cpu", precision="float32")
    fast = Predictor(checkpoint, device="cpu", precision="bfloat16")
    masks = np.stack([input_channels(m, exact.native) for m in moulds])
    extra = exact.mould_arguments(moulds)
    a, b = exact(masks, **extra), fast(masks, **extra)
    for x, y in ((a.raw, b.raw), (a.spread, b.spread)):
        # each field against its largest value; the orientation tensor's components (in
        # cells, as P) against the largest of them all, as a small one (SxSy) nearly cancels
        scale = np.abs(x).max(axis=(0, 2, 3))
        scale[2:] = scale[2:].max()
        assert np.abs(x - y).max() > 0  # it is another arithmetic
        assert np.all(np.abs(x - y) <= 3e-2 * scale[:, None, None])
    np.testing.assert_allclose(b.raw[:, 0].sum(axis=(1, 2)), extra["n_cells"], rtol=1e-5)
    assert np.all(b.raw[:, 6:] == 0)
    with pytest.raises(ValueError, match="precision 'float16' is not one of"):
        Predictor(checkpoint, device="cpu", precision="float16")


@pytest.mark.parametrize("native", [True, False])
def test_auto_precision_takes_bfloat16_only_where_it_is_native(checkpoint, monkeypatch, native):
    """The default precision, "auto", is resolved when the Predictor is made: bfloat16 where
    this CPU has it natively, float32 elsewhere (where bfloat16 would be emulated, slower)."""
    monkeypatch.setattr(inference, "bfloat16_is_native", lambda: native)
    assert Predictor(checkpoint, device="cpu").precision == ("bfloat16" if native else "float32")
    assert Predictor(checkpoint, device="cpu", precision="float32").precision == "float32"


def test_the_symmetrisation_equals_the_reference_in_every_mode(checkpoint, moulds):
    """The product's symmetrisation (decoded where the network wrote each transform, summed
    in one compiled pass: physics.symmetrised_sum_kernel) against the reference
    (symmetrise.symmetrised_reference), with a spread factor that is not 1, moulds of
    different N_c, and the 8 transforms run as one batch ("eval") or one at a time (the
    modes whose output depends on the batch)."""
    from condor.surrogate.symmetrise import symmetrised

    predictor = Predictor(checkpoint, device="cpu", precision="float32")
    predictor.scaling.spread_factor = np.linspace(0.7, 1.9, 8)
    masks = np.stack([input_channels(m, predictor.native) for m in moulds])
    extra = predictor.mould_arguments(moulds)
    from condor.data.inputs import stress_channels

    x = torch.from_numpy(np.concatenate([masks.astype(np.float32), extra["lattice"],
                                         stress_channels(masks)], axis=1))
    with prediction_mode(predictor.model, "eval"), torch.no_grad():
        want = symmetrised_reference(predictor.model, predictor.scaling, x, extra["n_cells"],
                                     predictor.inputs_kind)
        for batched in (True, False):
            got = symmetrised(predictor.model, predictor.scaling, x, extra["n_cells"],
                              predictor.inputs_kind, batched=batched)
            for a, b in zip(got, want):
                np.testing.assert_allclose(a, b, rtol=1e-5, atol=1e-6 * np.abs(b).max())
    assert len(set(np.round(extra["n_cells"]))) > 1
