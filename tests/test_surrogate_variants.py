"""Variant settings -> TrainConfig, the config's `surrogate:` section, and the workflow's
train/evaluate entry points on a real-format store."""

import numpy as np
import pandas as pd
import pytest
import torch

from condor.config import Config, ConfigError
from condor.stages.surrogate import (evaluate_store_baselines, evaluate_variant, summarise,
                                     train_variant, working_checkpoint)
from condor.surrogate.checkpoint import load_checkpoint
from condor.surrogate.networks import UNetConfig
from condor.surrogate.synthetic import synthetic_dataset
from condor.surrogate.train import TrainConfig
from condor.surrogate.variants import PRESETS, UNET_KEYS, resolve, train_config, workflow_variants
from condor.data.store import write_sample
from test_cli_surrogate import write_store

REPO_CONFIGS = ("config/config.yaml", "config/tiny.yaml", "config/paper.yaml")


def test_train_config_maps_flat_settings():
    cfg = train_config({"model": "unet_gan", "base": 16, "depth": 3, "epochs": 7, "lr": 1e-3,
                        "lam": 50, "batch_size": None}, 64)
    assert cfg.unet == UNetConfig(size=64, base=16, depth=3, max_width=256)
    assert (cfg.network, cfg.epochs, cfg.lr, cfg.lam, cfg.batch_size) == ("unet_gan", 7, 1e-3, 50, 1)
    assert train_config({"model": "unet_l1"}, 32).unet == UNetConfig.for_size(32)
    assert train_config({"model": "pix2pix"}, 64).networks(64)[0] == UNetConfig.paper()


@pytest.mark.parametrize("settings, message", [
    ({"model": "unet_x"}, "'unet_x'"),
    ({"model": "unet", "loss": "gaussian"}, "physics"),
    ({"model": "unet", "upsample": "cubic"}, "cubic"),
    ({"model": "unet_l1", "bse": 3}, "bse"),
    ({"model": "pix2pix", "base": 16}, "base"),
    ({"model": "unet_l1", "epochs": -1}, "epochs"),
    ({"model": "unet_l1", "depth": 7}, "divisible"),
    ({"model": "unet_l1", "betas": [0.9]}, r"betas = \[0.9\]"),
    ({"model": "unet_l1", "betas": [0.9, 1.0]}, r"betas = \[0.9, 1.0\]"),
    ({"model": "unet_l1", "betas": [-0.1, 0.99]}, "betas"),
])
def test_train_config_rejects_bad_settings(settings, message):
    with pytest.raises(ValueError, match=message):
        train_config(settings, 64)


def test_presets_name_only_what_they_change():
    """Each preset of the registry differs from TrainConfig's and UNetConfig.for_size's
    defaults in every key it names (a key at its default would be a second home of it)."""
    trainer, unet = TrainConfig(), UNetConfig.for_size(32)
    for name, settings in PRESETS.items():
        for key, value in settings.items():
            if key == "model":
                continue
            default = getattr(unet if key in UNET_KEYS else trainer, key)
            assert (tuple(value) if isinstance(value, (list, tuple)) else value) != default, \
                (name, key)
        train_config(settings, 32)


def test_resolve_layers_a_variant_over_its_preset():
    assert resolve("unet") == dict(PRESETS["unet"])
    assert resolve("unet", {"unet": {"epochs": 3}}) == {**PRESETS["unet"], "epochs": 3}
    small = resolve("small", {"small": {"preset": "unet_l1", "base": 8}})
    assert small == {**PRESETS["unet_l1"], "base": 8}
    assert resolve("mine", {"mine": {"model": "unet_l1"}}) == {"model": "unet_l1"}
    with pytest.raises(ValueError, match="neither a preset nor a model"):
        resolve("mine", {"mine": {"base": 8}})
    with pytest.raises(ValueError, match="'nope'"):
        resolve("mine", {"mine": {"preset": "nope"}})


def test_the_tiny_run_trains_the_default_preset_smaller():
    """What the tiny workflow trains (tiny.yaml layered over config.yaml, as Snakemake reads
    them) is the `unet` preset with only its size and length changed."""
    config = Config.load("config/config.yaml", "config/tiny.yaml")
    assert workflow_variants(config) == {"unet": {**PRESETS["unet"], "base": 8, "epochs": 30,
                                                  "batch_size": 4}}
    assert workflow_variants(Config.load("config/config.yaml")) == {"unet": dict(PRESETS["unet"])}


def test_workflow_variants_and_repository_configs():
    for path in REPO_CONFIGS:
        config = Config.load("config/config.yaml", path)
        variants = workflow_variants(config)
        assert variants, path
        for name, settings in variants.items():
            train_config(settings, config.scene.pixels)
    base = {"scene": "tiny", "seed": 1, "n_moulds": 8, "split": {"test": 2}}
    with pytest.raises(ConfigError, match="'b'"):
        Config.from_dict({**base, "surrogate": {"variants": ["a", "b"],
                                                "models": {"a": {"model": "unet_l1"}}}})
    with pytest.raises(ConfigError, match="baselines"):
        Config.from_dict({**base, "surrogate": {"variants": ["baselines"], "models": {}}})


def test_schema_rejects_unknown_variant_key(tmp_path):
    text = ("scene: tiny\nseed: 1\nn_moulds: 4\nsurrogate:\n  models:\n"
            "    u: {model: unet_l1, epoch: 3}\n")
    (tmp_path / "c.yaml").write_text(text)
    with pytest.raises(ValueError, match="epoch"):
        Config.load(tmp_path / "c.yaml")


@pytest.fixture(scope="module")
def store(tmp_path_factory):
    path = tmp_path_factory.mktemp("wf") / "data.zarr"
    write_store(path, synthetic_dataset(16, 32, splits=("train",) * 6 + ("val", "test")))
    return path


SETTINGS = {"model": "unet_l1", "base": 8, "epochs": 2, "batch_size": 4, "lr": 2e-3}


def test_betas_reach_the_optimiser(store, tmp_path):
    """A variant's `betas` are Adam's in training (the default is the paper's 0.5/0.999)."""
    assert train_config({"model": "unet_l1"}, 32).betas == (0.5, 0.999)
    assert train_config({"model": "unet_l1", "betas": [0.9, 0.99]}, 32).betas == (0.9, 0.99)
    checkpoint = tmp_path / "b.pt"
    train_variant(store, {**SETTINGS, "epochs": 1, "betas": [0.9, 0.99]}, checkpoint, threads=1,
          log_line=lambda s: None)
    state = load_checkpoint(checkpoint)
    assert [tuple(g["betas"]) for g in state["opt_g"]["param_groups"]] == [(0.9, 0.99)]
    assert state["config"]["betas"] == [0.9, 0.99]


def _generator(path):
    return load_checkpoint(path)["generator"]


def _same_weights(a, b) -> bool:
    a, b = _generator(a), _generator(b)
    return a.keys() == b.keys() and all(torch.equal(a[k], b[k]) for k in a)


def test_train_variant_publishes_and_resumes(store, tmp_path):
    final = tmp_path / "models" / "v.pt"
    final.parent.mkdir()
    lines = []
    history = train_variant(store, SETTINGS, final, tmp_path / "h.csv", threads=1, log_line=lines.append)
    assert len(history) == 2 and final.is_file() and working_checkpoint(final).is_file()
    assert pd.read_csv(tmp_path / "h.csv")["epoch"].tolist() == [1, 2]
    # A job killed after epoch 1 of 3 resumes: only epochs 2 and 3 run.
    cosine = {**SETTINGS, "epochs": 3, "lr_schedule": "cosine"}
    with pytest.raises(KeyboardInterrupt):
        train_variant(store, cosine, final, threads=1, log_line=_killed_after_epoch_1)
    lines.clear()
    train_variant(store, cosine, final, threads=1, log_line=lines.append)
    assert lines[0].startswith("resuming") and [line.split()[1] for line in lines[1:]] == ["2/3", "3/3"]
    assert load_checkpoint(final)["epoch"] == 3
    train_variant(store, cosine, tmp_path / "straight.pt", threads=1, log_line=lambda s: None)
    assert _same_weights(final, tmp_path / "straight.pt")
    # Other settings discard the working checkpoint and start over.
    lines.clear()
    train_variant(store, {**SETTINGS, "base": 4}, final, threads=1, log_line=lines.append)
    assert lines[0].startswith("training from scratch") and len(lines) == 3
    assert load_checkpoint(final)["generator_config"]["base"] == 4


def _killed_after_epoch_1(line):
    if line.startswith("epoch 1/"):
        raise KeyboardInterrupt(line)


@pytest.mark.parametrize("before, after", [(3, 1), (1, 3)])
def test_changed_epochs_train_from_scratch(store, tmp_path, before, after):
    """Fewer epochs never keep the longer model; more never continue a finished cosine
    schedule: the published model is the one a fresh run of the new settings gives."""
    settings = {**SETTINGS, "lr_schedule": "cosine"}
    final = tmp_path / "v.pt"
    train_variant(store, {**settings, "epochs": before}, final, threads=1, log_line=lambda s: None)
    lines = []
    train_variant(store, {**settings, "epochs": after}, final, threads=1, log_line=lines.append)
    assert lines[0].startswith("training from scratch") and f"epochs: checkpoint {before}" in lines[0]
    assert len(lines) == 1 + after
    state = load_checkpoint(final)
    assert state["epoch"] == after == state["config"]["epochs"] == len(state["history"])
    train_variant(store, {**settings, "epochs": after}, tmp_path / "fresh.pt", threads=1,
          log_line=lambda s: None)
    assert _same_weights(final, tmp_path / "fresh.pt")


def test_changed_data_train_from_scratch(tmp_path):
    """A store whose values changed (the same samples simulated again, another solver) is
    never resumed: the published model is trained on, and records, the data read now."""
    data = synthetic_dataset(16, 32, splits=("train",) * 6 + ("val", "test"))
    path = tmp_path / "data.zarr"
    write_store(path, data)
    final = tmp_path / "models" / "v.pt"
    train_variant(store=path, settings=SETTINGS, checkpoint=final, threads=1, log_line=lambda s: None)
    before = load_checkpoint(final)
    train_sample = int(np.flatnonzero(data["split"].values == "train")[0])
    fields = data["fields"].values[train_sample] * 1.5  # the sample simulated again
    write_sample(path, train_sample, fields, {"sim_seed": 0, "n_cells": int(data["n_cells"].values[train_sample]),
                                              "energy": 0.0, "max_force": 0.0, "solver": "synthetic",
                                              "solver_seconds": 0.0, "hardware": "test"}, "ok")
    lines = []
    train_variant(path, SETTINGS, final, threads=1, log_line=lines.append)
    assert lines[0].startswith("training from scratch") and "training data changed" in lines[0]
    after = load_checkpoint(final)
    assert after["data"]["fingerprint"] != before["data"]["fingerprint"]
    train_variant(path, SETTINGS, tmp_path / "fresh.pt", threads=1, log_line=lambda s: None)
    assert _same_weights(final, tmp_path / "fresh.pt")
    assert not all(torch.equal(after["generator"][k], before["generator"][k])
                   for k in before["generator"])


def test_workflow_evaluation_files_and_summary(store, tmp_path):
    checkpoint = tmp_path / "v.pt"
    train_variant(store, SETTINGS, checkpoint, threads=1, log_line=lambda s: None)
    evaluate_variant(store, checkpoint, tmp_path / "v", "v", modes=["eval", "train"])
    evaluate_store_baselines(store, tmp_path / "baselines")
    assert {p.name for p in (tmp_path / "v").iterdir()} == {
        "summary.csv", "figures", "v_eval_mae.csv", "v_eval_correlations.csv", "v_train_mae.csv",
        "v_train_correlations.csv"}
    assert len(list((tmp_path / "v" / "figures").glob("v_*.png"))) == 12
    assert len(list((tmp_path / "baselines" / "figures").glob("*.png"))) == 12
    paths = [tmp_path / "v" / "summary.csv", tmp_path / "baselines" / "summary.csv"]
    summary = summarise(paths, tmp_path / "summary.csv")
    assert list(summary.index) == ["v_eval", "v_train", "masked_mean", "mould_blur"]
    assert (summary["seconds_per_mould"] > 0).all()
    with pytest.raises(ValueError, match="masked_mean"):
        summarise(paths + paths[1:], tmp_path / "again.csv")
