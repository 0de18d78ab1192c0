"""Configuration: the shipped configs validate; bad keys and values are named."""

from pathlib import Path

import pytest
import yaml

from condor.config import ConfigError, batches, load_config, scene_of, store_spec, validate_config

CONFIG_DIR = Path(__file__).resolve().parents[1] / "config"


def default_config():
    return yaml.safe_load((CONFIG_DIR / "config.yaml").read_text())


@pytest.mark.parametrize("name", ["config.yaml", "tiny.yaml", "paper.yaml"])
def test_shipped_configs_validate(name):
    config = load_config(CONFIG_DIR / name)
    scene = scene_of(config)
    assert scene.pixels >= 8
    ids = [i for batch in batches(config) for i in batch]
    assert ids == list(range(config["n_moulds"]))  # every mould in exactly one batch


def test_defaults_are_filled():
    config = validate_config({"scene": "tiny", "seed": 1, "n_moulds": 10, "split": {"test": 2}})
    assert config["batch_size"] == 8
    assert config["simulation"] == {"solver": "hybrid", "budget": None}
    assert config["split"]["val_fraction"] == 0.1


@pytest.mark.parametrize(
    "change, named",
    [
        ({"n_mould": 5}, "n_mould"),  # misspelt key
        ({"scene": "huge"}, "scene"),
        ({"seed": -1}, "seed"),
        ({"seed": "seven"}, "seed"),
        ({"batch_size": 0}, "batch_size"),
        ({"simulation": {"solver": "newton"}}, "simulation/solver"),
        ({"moulds": {"no_tether_fraction": 1.5}}, "moulds/no_tether_fraction"),
        ({"scene_overrides": {"pixels": 3}}, "scene_overrides/pixels"),
        ({"scene_overrides": {"colour": 3}}, "colour"),
        ({"split": {"test": 500}}, "split/test"),
    ],
)
def test_bad_values_are_named(change, named):
    config = default_config()
    config.update(change)
    with pytest.raises(ConfigError, match=named):
        validate_config(config)


def test_store_spec_records_scene_and_split():
    config = validate_config(default_config())
    spec = store_spec(config)
    assert spec.n_samples == config["n_moulds"]
    assert spec.attrs["scene"]["name"] == "default"
    assert spec.split.count("test") == config["split"]["test"]
    assert spec == store_spec(validate_config(default_config()))  # deterministic
