"""Data handling and training: scaling, sample selection, loss decrease, baseline, resume,
checkpoint errors."""

import numpy as np
import pytest
import torch

from condor.surrogate.baselines import MaskedMeanBaseline
from condor.surrogate.checkpoint import (CheckpointError, CheckpointMismatchError,
                                         CheckpointNotFoundError, load_checkpoint, save_checkpoint)
from condor.surrogate.samples import FieldScaling, SampleSource, compute_scaling, usable_samples
from condor.surrogate.networks import UNetConfig
from condor.surrogate.predict import predict
from condor.surrogate.synthetic import synthetic_dataset
from condor.surrogate.train import TrainConfig, train

TINY_UNET = UNetConfig.for_size(32, base=8)
QUIET = lambda message: None


@pytest.fixture(scope="module")
def ds():
    data = synthetic_dataset(16, 32, splits=("train",) * 6 + ("val", "test"))
    # One failed and one unwritten sample with extreme values: must be ignored everywhere.
    status = data["status"].values.astype(object)
    status[[0, 1]] = ["anneal diverged", ""]
    data["status"] = ("sample", status.astype(str))
    data["fields"][0] = 1e6
    data["fields"][1] = -1e6
    return data


def test_usable_samples_select_ok_by_split(ds):
    train_idx = usable_samples(ds, "train")
    split = ds["split"].values
    assert 0 not in train_idx and 1 not in train_idx
    assert list(train_idx) == [i for i in range(16) if split[i] == "train" and i > 1]
    assert len(usable_samples(ds)) == 14
    with pytest.raises(ValueError, match="'bogus'"):
        usable_samples(ds, "bogus")


def test_scaling_from_train_split_and_round_trip(ds):
    train_idx = usable_samples(ds, "train")
    scaling = compute_scaling(ds, train_idx, chunk=3)
    f = ds["fields"].values[train_idx].astype(np.float64)
    np.testing.assert_allclose(scaling.lo, f.min(axis=(0, 2, 3)), rtol=1e-6)
    np.testing.assert_allclose(scaling.hi, f.max(axis=(0, 2, 3)), rtol=1e-6)
    scaled = scaling.scale(f)
    assert scaled.min() == pytest.approx(-1) and scaled.max() == pytest.approx(1)
    np.testing.assert_allclose(scaling.unscale(scaled), f, atol=1e-12)
    t = torch.from_numpy(f.astype(np.float32))
    np.testing.assert_allclose(scaling.unscale(scaling.scale(t)).numpy(), f, atol=1e-5)
    again = FieldScaling.from_dict(scaling.to_dict())
    np.testing.assert_array_equal(again.lo, scaling.lo)
    # At 4x the resolution the conserved-sum resampling divides values by 16.
    up = compute_scaling(ds, train_idx, size=128)
    np.testing.assert_allclose(up.hi, scaling.hi / 16, rtol=1e-6)
    flat = FieldScaling(np.zeros(8), np.zeros(8))  # constant fields survive the round trip
    np.testing.assert_allclose(flat.unscale(flat.scale(np.zeros((8, 2, 2)))), 0)


def test_sample_source_lazy_equals_preloaded(ds):
    idx = usable_samples(ds, "train")
    scaling = compute_scaling(ds, idx)
    lazy = SampleSource(ds, idx, scaling, size=64, preload=False)
    eager = SampleSource(ds, idx, scaling, size=64, preload=True)
    for a, b in zip(lazy.batch([3, 0, 5]), eager.batch([3, 0, 5])):
        assert a.shape[-1] == 64 and torch.equal(a, b)


def test_training_reduces_loss_and_beats_masked_mean(ds, tmp_path):
    cfg = TrainConfig(network="unet_l1", unet=UNetConfig.for_size(32, base=16), epochs=30,
                      batch_size=2, lr=2e-3, betas=(0.9, 0.999), seed=1)
    history = train(ds, cfg, tmp_path / "l1.pt", log=QUIET)
    assert history[-1]["l1"] < 0.25 * history[0]["l1"]
    assert history[-1]["val_mae"] < history[0]["val_mae"]
    inputs = ds["inputs"].values.astype(np.float32)
    fields = ds["fields"].values
    tr, te = usable_samples(ds, "train"), usable_samples(ds, "test")
    baseline = MaskedMeanBaseline().fit(inputs[tr], fields[tr]).predict(inputs[te])
    predicted = predict(tmp_path / "l1.pt", inputs[te]).raw
    assert np.abs(predicted - fields[te]).mean() < 0.7 * np.abs(baseline - fields[te]).mean()


def _weights(path):
    state = load_checkpoint(path)
    return {**{f"g.{k}": v for k, v in state["generator"].items()},
            **{f"d.{k}": v for k, v in state["discriminator"].items()}}, state


def test_kill_and_resume_give_identical_weights(ds, tmp_path):
    cfg = TrainConfig(network="unet_gan", unet=TINY_UNET, epochs=2, batch_size=2, lr=1e-3,
                      lam=100.0, seed=3)
    full = train(ds, cfg, tmp_path / "full.pt", log=QUIET)

    def killed(message):
        raise KeyboardInterrupt(message)  # dies right after the first checkpoint

    with pytest.raises(KeyboardInterrupt):
        train(ds, cfg, tmp_path / "resumed.pt", log=killed)
    assert load_checkpoint(tmp_path / "resumed.pt")["epoch"] == 1
    resumed = train(ds, cfg, tmp_path / "resumed.pt", log=QUIET)
    # stop_after: a snapshot of the run, as if interrupted, that the next call resumes
    assert len(train(ds, cfg, tmp_path / "snapshot.pt", log=QUIET, stop_after=1)) == 1
    train(ds, cfg, tmp_path / "snapshot.pt", log=QUIET)
    a, _ = _weights(tmp_path / "full.pt")
    for other in ("resumed.pt", "snapshot.pt"):
        b, state_b = _weights(tmp_path / other)
        assert a.keys() == b.keys() and all(torch.equal(a[k], b[k]) for k in a)
        assert state_b["epoch"] == 2 and len(state_b["history"]) == 2
    assert [h["l1"] for h in resumed] == [h["l1"] for h in full]
    # A finished run of 1 epoch is another run, not the first half of this one: `epochs` is
    # part of what a checkpoint claims (under a cosine schedule, another schedule).
    train(ds, TrainConfig(**{**cfg.__dict__, "epochs": 1}), tmp_path / "shorter.pt", log=QUIET)
    with pytest.raises(CheckpointMismatchError, match="epochs: checkpoint 1 vs now 2"):
        train(ds, cfg, tmp_path / "shorter.pt", log=QUIET)
    assert "d_loss" in full[0] and np.isfinite(full[-1]["d_loss"])
    assert not [p for p in tmp_path.iterdir() if ".tmp" in p.name]  # atomic writes cleaned up


def test_checkpoint_errors_name_file_and_mismatch(ds, tmp_path):
    path = tmp_path / "model.pt"
    missing = tmp_path / "nothing.pt"
    with pytest.raises(CheckpointNotFoundError, match="nothing.pt"):
        predict(missing, np.zeros((2, 32, 32)))
    assert issubclass(CheckpointNotFoundError, FileNotFoundError)
    cfg = TrainConfig(network="unet_l1", unet=TINY_UNET, epochs=1, seed=0)
    train(ds, cfg, path, log=QUIET)
    with pytest.raises(CheckpointMismatchError, match=r"model\.pt.*lr: checkpoint 0.0002 vs now 0.001"):
        train(ds, TrainConfig(**{**cfg.__dict__, "lr": 1e-3}), path, log=QUIET)
    smaller = synthetic_dataset(8, 32, seed=5)
    with pytest.raises(CheckpointMismatchError, match="n_train"):
        train(smaller, cfg, path, log=QUIET)
    with pytest.raises(ValueError, match="16x16 px.*32x32"):
        predict(path, np.zeros((2, 16, 16)))
    state = load_checkpoint(path)
    state["generator_config"]["base"] = 16  # weights no longer fit the config
    del state["format"]
    save_checkpoint(state, tmp_path / "bad.pt")
    with pytest.raises(CheckpointMismatchError, match="bad.pt.*generator"):
        predict(tmp_path / "bad.pt", np.zeros((2, 32, 32)))
    (tmp_path / "junk.pt").write_bytes(b"not a checkpoint")
    with pytest.raises(CheckpointError, match="junk.pt"):
        predict(tmp_path / "junk.pt", np.zeros((2, 32, 32)))


def test_changed_data_is_never_resumed(ds, tmp_path):
    """Another value of any training or validation sample, with the same sample ids, is
    other data: the checkpoint's fingerprint no longer matches (a stale model would be
    published otherwise)."""
    path = tmp_path / "m.pt"
    cfg = TrainConfig(network="unet_l1", unet=TINY_UNET, epochs=1, seed=0)
    train(ds, cfg, path, log=QUIET)
    fingerprint = load_checkpoint(path)["data"]["fingerprint"]
    assert len(fingerprint) == 64
    train(ds.copy(deep=True), cfg, path, log=QUIET)  # the same data: resumes, nothing to do
    train_idx, val_idx = usable_samples(ds, "train"), usable_samples(ds, "val")
    for position, variable in ((train_idx[2], "fields"), (val_idx[0], "fields"),
                               (train_idx[0], "inputs"), (train_idx[1], "n_cells")):
        changed = ds.copy(deep=True)
        changed[variable].values[position] = changed[variable].values[position] + 1
        with pytest.raises(CheckpointMismatchError, match="m.pt.*training data changed"):
            train(changed, cfg, path, log=QUIET)
    history = train(changed, cfg, path, log=QUIET, resume=False)
    assert len(history) == 1 and load_checkpoint(path)["data"]["fingerprint"] != fingerprint
