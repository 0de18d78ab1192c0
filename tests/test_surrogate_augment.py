"""Symmetry augmentation: the 16 transforms are exact symmetries of the rasterised fields,
form a group with correct inverses, commute with the symmetrised scaling, keep resumption
bit-identical, and test-time symmetrisation gives an equivariant prediction."""

import numpy as np
import pytest
import torch

from condor.data.fields import cell_fields
from condor.surrogate.samples import (FIELD_NAMES, FLIP_Z, MIRROR_X, MIRROR_Y, N_SYMMETRIES,
                                   TRANSPOSE, FieldScaling, apply_symmetry, compute_scaling,
                                   usable_samples)
from condor.surrogate.networks import UNetConfig, UNetGenerator
from condor.surrogate.predict import run_generator
from condor.surrogate.synthetic import synthetic_dataset
from condor.surrogate.train import TrainConfig, augmentation_choices, train

BOX, PIXELS = 15.625, 32
QUIET = lambda message: None


def random_cells(seed: int, n: int = 60):
    rng = np.random.default_rng([seed, n])
    positions = np.column_stack([rng.uniform(3.0, BOX - 3.0, (n, 2)), rng.uniform(0, 2, n)])
    s = rng.normal(size=(n, 3))
    return positions, s / np.linalg.norm(s, axis=1, keepdims=True), rng.uniform(0, 1, n)


def transform_cells(k: int, positions, orientations):
    """The symmetry k acting on the cells themselves (generators in apply_symmetry's order)."""
    p, s = positions.copy(), orientations.copy()
    if k & TRANSPOSE:
        p[:, [0, 1]], s[:, [0, 1]] = p[:, [1, 0]], s[:, [1, 0]]
    if k & MIRROR_X:
        p[:, 0], s[:, 0] = BOX - p[:, 0], -s[:, 0]
    if k & MIRROR_Y:
        p[:, 1], s[:, 1] = BOX - p[:, 1], -s[:, 1]
    if k & FLIP_Z:
        s[:, 2] = -s[:, 2]
    return p, s


@pytest.mark.parametrize("k", range(N_SYMMETRIES))
def test_each_transform_is_a_symmetry_of_the_rasterisation(k):
    positions, s, tau = random_cells(k)
    fields = cell_fields(positions, s, tau, BOX, PIXELS)
    moved = cell_fields(*transform_cells(k, positions, s), tau, BOX, PIXELS)
    _, predicted = apply_symmetry(k, fields=fields)
    scale = np.abs(fields).max()
    np.testing.assert_allclose(predicted, moved, atol=1e-5 * scale)
    if k:  # the transform does something on a generic configuration
        assert np.abs(fields - moved).max() > 1e-2 * scale


def test_generators_are_involutions_and_inverses_undo():
    rng = np.random.default_rng(3)
    inputs, fields = rng.random((2, 2, 8, 8)), rng.normal(size=(2, 8, 8, 8))
    for g in (TRANSPOSE, MIRROR_X, MIRROR_Y, FLIP_Z):
        twice = apply_symmetry(g, *apply_symmetry(g, inputs, fields))
        np.testing.assert_array_equal(twice[0], inputs)
        np.testing.assert_array_equal(twice[1], fields)
    images = set()
    for k in range(N_SYMMETRIES):
        back = apply_symmetry(k, *apply_symmetry(k, inputs, fields), inverse=True)
        np.testing.assert_array_equal(back[1], fields)
        np.testing.assert_array_equal(back[0], inputs)
        # torch and numpy agree
        t = apply_symmetry(k, torch.from_numpy(inputs), torch.from_numpy(fields))
        np.testing.assert_array_equal(t[1].numpy(), apply_symmetry(k, inputs, fields)[1])
        images.add(apply_symmetry(k, fields=fields)[1].tobytes())
    assert len(images) == N_SYMMETRIES  # 16 distinct transforms
    with pytest.raises(ValueError, match="16"):
        apply_symmetry(16, fields=fields)


def test_symmetrised_scaling_commutes_with_every_transform():
    rng = np.random.default_rng(5)
    fields = rng.normal(size=(3, 8, 8, 8)) * np.arange(1, 9)[:, None, None] + 0.3
    lo, hi = fields.min(axis=(0, 2, 3)), fields.max(axis=(0, 2, 3))
    scaling = FieldScaling(lo, hi).symmetrised()
    assert np.all(scaling.lo <= lo) and np.all(scaling.hi >= hi)
    for names in (("SxSy",), ("SxSz", "SySz")):  # odd; the second pair shares one range
        idx = [FIELD_NAMES.index(n) for n in names]
        m = max(np.abs(lo[idx]).max(), np.abs(hi[idx]).max())
        assert all(scaling.lo[i] == -scaling.hi[i] == -m for i in idx)
    i, j = FIELD_NAMES.index("Sx2"), FIELD_NAMES.index("Sy2")
    assert (scaling.lo[i], scaling.hi[i]) == (scaling.lo[j], scaling.hi[j])
    for k in range(N_SYMMETRIES):
        a = scaling.scale(apply_symmetry(k, fields=fields)[1])
        b = apply_symmetry(k, fields=scaling.scale(fields))[1]
        np.testing.assert_allclose(a, b, atol=1e-12)
        assert np.abs(a).max() <= 1 + 1e-12
    # the plain min/max scaling does not commute (what the symmetrisation is for)
    plain = FieldScaling(lo, hi)
    assert not np.allclose(plain.scale(apply_symmetry(MIRROR_X, fields=fields)[1]),
                           apply_symmetry(MIRROR_X, fields=plain.scale(fields))[1])


def test_choices_are_uniform_and_seeded():
    a = augmentation_choices(0, 3, 4000)
    assert np.array_equal(a, augmentation_choices(0, 3, 4000))
    assert not np.array_equal(a, augmentation_choices(0, 4, 4000))
    counts = np.bincount(a, minlength=N_SYMMETRIES)
    assert abs(counts - 250).max() < 5 * np.sqrt(250)  # ~5 sigma of a multinomial count


@pytest.fixture(scope="module")
def ds():
    return synthetic_dataset(12, 32, splits=("train",) * 5 + ("val",))


def test_augmented_resume_is_bit_identical_and_augmentation_acts(ds, tmp_path):
    unet = UNetConfig.for_size(32, base=8)
    cfg = TrainConfig(network="unet_l1", unet=unet, epochs=2, batch_size=4, lr=2e-3, augment=True)
    full = train(ds, cfg, tmp_path / "full.pt", log=QUIET)

    def killed(line):  # dies right after the first epoch's checkpoint
        raise KeyboardInterrupt(line)

    with pytest.raises(KeyboardInterrupt):
        train(ds, cfg, tmp_path / "resumed.pt", log=killed)
    resumed = train(ds, cfg, tmp_path / "resumed.pt", log=QUIET)
    assert [h["l1"] for h in resumed] == [h["l1"] for h in full]
    a = torch.load(tmp_path / "full.pt", weights_only=False)
    b = torch.load(tmp_path / "resumed.pt", weights_only=False)
    for key, value in a["generator"].items():
        assert torch.equal(value, b["generator"][key]), key
    plain = train(ds, TrainConfig(**{**cfg.to_dict(), "augment": False}), tmp_path / "p.pt",
                  log=QUIET)
    assert plain[0]["l1"] != full[0]["l1"]
    # the stored scaling is the symmetrised training min/max
    expected = compute_scaling(ds, usable_samples(ds, "train"), 32).symmetrised()
    np.testing.assert_allclose(a["scaling"]["lo"], expected.lo)
    np.testing.assert_allclose(a["scaling"]["hi"], expected.hi)


def test_symmetrised_prediction_is_equivariant(ds):
    model = UNetGenerator(UNetConfig.for_size(32, base=8), torch.Generator().manual_seed(1))
    inputs = np.asarray(ds["inputs"].values[:3], dtype=np.float32)
    scaling = FieldScaling(-np.ones(8), np.ones(8) * 2)  # not symmetric: unscale is affine
    pred = run_generator(model, scaling, inputs, symmetrise=True)
    for k in (TRANSPOSE, MIRROR_X | MIRROR_Y, TRANSPOSE | MIRROR_Y | FLIP_Z):
        moved_in, expected = apply_symmetry(k, inputs, pred)
        moved = run_generator(model, scaling, np.ascontiguousarray(moved_in), symmetrise=True)
        np.testing.assert_allclose(moved, expected, atol=1e-5)
    # the inputs are z-symmetric, so the z-odd fields average to zero
    odd = [FIELD_NAMES.index(f) for f in ("SxSz", "SySz")]
    assert np.abs(pred[:, odd]).max() < 1e-6
    plain = run_generator(model, scaling, inputs)
    assert np.abs(plain[:, odd]).max() > 1e-3
