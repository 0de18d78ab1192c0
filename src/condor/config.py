"""The workflow configuration as library objects (pure: no Snakemake).

The workflow validates `config/config.yaml` against `config/config.schema.yaml` with
Snakemake's `validate`; the CLI uses `load_config`, which applies the same schema with
jsonschema, so both stop on the same bad key or value with a message naming it.
"""

from __future__ import annotations

import json
from pathlib import Path

from condor.scenes import Scene, get_scene

SCHEMA_PATH = Path(__file__).resolve().parents[2] / "config" / "config.schema.yaml"

# The CONDOR model parameters every dataset records (DESIGN.md, "The physical model").
MODEL_PARAMETERS = {
    "delta": 0.3,
    "kbar": [1.0, 0.4, 0.2, 0.2],
    "t_init": 0.0625,
    "t_ratio": 1e7,
    "lattice": "fcc",
}


class ConfigError(ValueError):
    """A configuration key or value is invalid; the message names it."""


def load_config(path: str | Path, schema_path: str | Path = SCHEMA_PATH) -> dict:
    """Read a YAML config, fill defaults and validate it against the schema."""
    import yaml

    path = Path(path)
    try:
        config = yaml.safe_load(path.read_text()) or {}
    except (OSError, yaml.YAMLError) as err:
        raise ConfigError(f"cannot read config {path}: {err}") from err
    return validate_config(config, schema_path)


def validate_config(config: dict, schema_path: str | Path = SCHEMA_PATH) -> dict:
    """Validate `config` (filling schema defaults in place); ConfigError names the bad key."""
    import jsonschema
    import yaml

    schema = yaml.safe_load(Path(schema_path).read_text())
    _fill_defaults(config, schema)
    errors = sorted(jsonschema.Draft202012Validator(schema).iter_errors(config), key=str)
    if errors:
        err = errors[0]
        where = "/".join(str(p) for p in err.absolute_path) or "(top level)"
        raise ConfigError(f"config key {where}: {err.message}")
    check_consistency(config)
    return config


def _fill_defaults(config: dict, schema: dict) -> None:
    for key, sub in schema.get("properties", {}).items():
        if key not in config and "default" in sub:
            config[key] = json.loads(json.dumps(sub["default"]))
        if isinstance(config.get(key), dict) and sub.get("type") == "object":
            _fill_defaults(config[key], sub)


def check_consistency(config: dict) -> None:
    """Constraints a JSON schema cannot express."""
    n_test = config.get("split", {}).get("test", 0)
    if n_test >= config["n_moulds"]:
        raise ConfigError(
            f"config key split/test: {n_test} test moulds leaves none for training "
            f"out of n_moulds = {config['n_moulds']}"
        )
    scene_of(config)  # raises for a bad override combination


def scene_of(config: dict) -> Scene:
    try:
        return get_scene(config["scene"], **config.get("scene_overrides", {}))
    except ValueError as err:
        raise ConfigError(f"config key scene: {err}") from err


def mould_params_of(config: dict):
    from condor.moulds import MouldParams

    params = MouldParams(no_tether_fraction=config.get("moulds", {}).get("no_tether_fraction", 100 / 6500))
    params.validate()
    return params


def batches(config: dict) -> list[range]:
    """Mould ids per job: consecutive runs of `batch_size`."""
    n, size = config["n_moulds"], config.get("batch_size", 8)
    return [range(start, min(start + size, n)) for start in range(0, n, size)]


def store_spec(config: dict):
    from condor.store import StoreSpec, assign_splits

    scene = scene_of(config)
    split = config.get("split", {})
    return StoreSpec(
        n_samples=config["n_moulds"],
        pixels=scene.pixels,
        seed=config["seed"],
        split=assign_splits(config["n_moulds"], split.get("test", 24), split.get("val_fraction", 0.1), config["seed"]),
        attrs={
            "scene": scene.to_dict(),
            "pixel_size": scene.pixel_size,
            "sigma": scene.sigma,
            "model": MODEL_PARAMETERS,
            "mould_params": {"no_tether_fraction": config.get("moulds", {}).get("no_tether_fraction", 100 / 6500)},
            "solver": config.get("simulation", {}).get("solver", "hybrid"),
            "solver_budget": config.get("simulation", {}).get("budget"),
        },
    )
