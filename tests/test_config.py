"""Configuration: the shipped configs validate; defaults come from the packaged schema only;
bad keys and values, and combinations that would fail late, are named before anything runs."""

import dataclasses
from pathlib import Path

import pytest
import yaml

from condor.config import SCHEMA_PATH, Config, ConfigError, load_schema
from condor.moulds.paper import MouldParams
from condor.model.simulate import DEFAULT_BUDGET, DEFAULT_SOLVER

CONFIG_DIR = Path(__file__).resolve().parents[1] / "config"


def default_config():
    return yaml.safe_load((CONFIG_DIR / "config.yaml").read_text())


@pytest.mark.parametrize("name", ["config.yaml", "tiny.yaml", "paper.yaml"])
def test_shipped_configs_validate(name):
    config = Config.load(CONFIG_DIR / name)
    assert config.scene.pixels >= 8
    ids = [i for batch in config.batches() for i in batch]
    assert ids == list(range(config.n_moulds))  # every mould in exactly one batch
    assert len(config.replicas()) == config.n_moulds
    assert config.store_spec().n_samples == sum(config.replicas())


OVERLAYS = ["tiny.yaml", "paper.yaml"]


def test_the_default_run_is_the_schemas_defaults():
    """config.yaml shows keys to change, each at the schema's default: the default run (650
    moulds, 100 test moulds with 4 replicas, 60% of the training moulds lab moulds, a third of
    those composite, the faithful solver, the `unet` preset) is the schema's."""
    config = Config.load(CONFIG_DIR / "config.yaml")
    assert config == Config.default()
    assert (config.n_moulds, config.split["test"], config.simulation["replicas"]["test"],
            config.moulds["lab_fraction"], config.moulds["composite_fraction"]) == (
                650, 100, 4, 0.6, 0.33)
    assert config.solver()[0] == "relaxed_anneal"
    assert config.surrogate["variants"] == ("unet",) and dict(config.surrogate["models"]) == {}


@pytest.mark.parametrize("name", OVERLAYS)
def test_the_config_snakemake_sees(name):
    """`snakemake --configfile config/<name>` layers it over the Snakefile's config.yaml:
    `layered` merges as Snakemake does, and since config.yaml holds defaults only, the
    overlay alone is the config the workflow runs."""
    from snakemake.utils import update_config

    from condor.config import layered

    base, over = (yaml.safe_load((CONFIG_DIR / n).read_text()) for n in ("config.yaml", name))
    seen = yaml.safe_load((CONFIG_DIR / "config.yaml").read_text())
    update_config(seen, over)
    assert layered(base, over) == seen
    workflow = Config.load(CONFIG_DIR / "config.yaml", CONFIG_DIR / name)
    assert workflow == Config.from_dict(seen) == Config.load(CONFIG_DIR / name)
    # nested keys are layered, not replaced
    assert layered({"a": {"b": 1, "c": 2}}, {"a": {"b": 3}}) == {"a": {"b": 3, "c": 2}}


def test_schema_ships_in_the_package():
    assert SCHEMA_PATH.parent == Path(__file__).resolve().parents[1] / "src" / "condor"
    assert SCHEMA_PATH.is_file() and not (CONFIG_DIR / "config.schema.yaml").exists()


def test_defaults_come_from_the_schema_and_the_library_only():
    config = Config.from_dict({"scene": "tiny", "seed": 1, "n_moulds": 10, "split": {"test": 2}})
    schema = load_schema()["properties"]
    assert config.batch_size == schema["batch_size"]["default"]
    assert config.split["val_fraction"] == schema["split"]["properties"]["val_fraction"]["default"]
    assert config.simulation["replicas"]["test"] == \
        schema["simulation"]["properties"]["replicas"]["properties"]["test"]["default"]
    # solver, budget and the tether-free share are the library's own defaults, resolved once
    assert config.solver() == (DEFAULT_SOLVER, DEFAULT_BUDGET[DEFAULT_SOLVER])
    assert config.mould_params().no_tether_fraction == MouldParams().no_tether_fraction
    assert config.data_config()["no_tether_fraction"] == MouldParams().no_tether_fraction


def test_the_relaxed_anneals_default_budget_grows_with_the_box_area_and_a_set_one_is_kept():
    """The validated budgets: 200 moves a cell in the default scene's box, 800 in the paper
    scene's (twice the side); a box between gets the same budget per unit area, a smaller one
    the default's; another solver's default and a budget set in the config are left alone.
    The resolved budget defines the data (data_config), so a store of one is never filled
    with the other."""
    def resolved(**data):
        return Config.from_dict({"seed": 1, "n_moulds": 10, "split": {"test": 2}, **data})

    default, paper = resolved(scene="default"), resolved(scene="paper")
    assert default.solver() == ("relaxed_anneal", DEFAULT_BUDGET["relaxed_anneal"])
    assert paper.solver() == ("relaxed_anneal", 4 * DEFAULT_BUDGET["relaxed_anneal"])
    assert resolved(scene="tiny").solver() == default.solver()
    side = 1.5 * default.scene.box
    between = resolved(scene="default", scene_overrides={"box": side})
    per_area = [c.solver()[1] / c.scene.box ** 2 for c in (default, between, paper)]
    assert per_area == pytest.approx([per_area[0]] * 3)
    assert resolved(scene="paper", simulation={"solver": "lbfgs"}).solver() == \
        ("lbfgs", DEFAULT_BUDGET["lbfgs"])
    assert resolved(scene="paper", simulation={"budget": 200}).solver()[1] == 200
    assert paper.data_config()["budget"] != resolved(scene="paper", simulation={"budget": 200}) \
        .data_config()["budget"]


def test_config_is_frozen_and_the_callers_dict_is_untouched():
    raw = {"scene": "tiny", "seed": 1, "n_moulds": 10, "split": {"test": 2}}
    config = Config.from_dict(raw)
    assert raw == {"scene": "tiny", "seed": 1, "n_moulds": 10, "split": {"test": 2}}
    with pytest.raises(dataclasses.FrozenInstanceError):
        config.seed = 2
    with pytest.raises(TypeError):
        config.simulation["solver"] = "anneal"
    assert Config.from_dict(config.to_dict()) == config


@pytest.mark.parametrize(
    "change, named",
    [
        ({"n_mould": 5}, "n_mould"),  # misspelt key
        ({"scene": "huge"}, "scene"),
        ({"seed": -1}, "seed"),
        ({"seed": "seven"}, "seed"),
        ({"batch_size": 0}, "batch_size"),
        ({"simulation": {"solver": "newton"}}, "simulation/solver"),
        ({"simulation": {"replicas": {"test": 0}}}, "simulation/replicas/test"),
        ({"moulds": {"no_tether_fraction": 1.5}}, "moulds/no_tether_fraction"),
        ({"scene_overrides": {"pixels": 3}}, "scene_overrides/pixels"),
        ({"scene_overrides": {"colour": 3}}, "colour"),
        ({"split": {"test": 10 ** 6}}, "split"),  # more test moulds than moulds
        ({"split": {"test": 24, "val_fraction": 0.99999}}, "val_fraction"),  # no training mould
        ({"scene_overrides": {"pixels": 36}}, "surrogate/models/unet"),  # 36 px, 3 levels
        ({"surrogate": {"variants": ["unet_l1"], "models": {"unet_l1": {"model": "unet_l1",
                                                                       "epochs": 0}}}}, "epochs"),
        ({"surrogate": {"variants": ["nope"]}}, "nope"),
        ({"surrogate": {"device": "cuda:0"}}, "device"),  # no CUDA on the test machines
        ({"design": {"objective": "alignmnt:x"}}, "design/objective"),
        ({"design": {"objective": "alignment:x@rect(0.99,0.99,1,1)"}}, "design/objective"),
    ],
)
def test_bad_values_are_named_before_anything_runs(change, named):
    config = default_config()
    config.update(change)
    with pytest.raises(ConfigError, match=named):
        Config.from_dict(config)


def test_message_is_one_line_without_a_schema_dump():
    with pytest.raises(ConfigError) as info:
        Config.from_dict({**default_config(), "n_mould": 5})
    assert "\n" not in str(info.value) and len(str(info.value)) < 300


def test_store_spec_records_scene_split_and_data_config():
    config = Config.from_dict(default_config())
    spec = config.store_spec()
    assert spec.n_moulds == config.n_moulds
    assert spec.attrs["scene"]["name"] == "default"
    assert spec.split.count("test") == config.split["test"]
    assert spec.attrs["data_config"] == config.data_config()
    assert spec == Config.from_dict(default_config()).store_spec()  # deterministic
    test_replicas = [r for r, s in zip(config.replicas(), config.splits()) if s == "test"]
    counts = config.simulation["replicas"]
    assert set(test_replicas) <= {counts["test"], counts["test_tether_free"]}


def test_moulds_with_a_paper_reference_are_test_moulds_at_any_size():
    """The surrogate is scored against the paper's ensemble on the reference moulds, so they
    are held out however many moulds a config builds (Config.splits pins them)."""
    from condor.studies.paper_reference import reference_moulds

    moulds = reference_moulds("default", 2026)
    assert len(moulds) >= 6
    for n, test in [(960, 100), (600, 60), (max(moulds) + 1, len(moulds))]:
        config = Config.from_dict({**default_config(), "n_moulds": n,
                                   "split": {"test": test, "val_fraction": 0.1}})
        splits = config.splits()
        assert [splits[m] for m in moulds] == ["test"] * len(moulds)
        assert splits.count("test") == test


def test_tether_free_test_moulds_take_their_own_replicas():
    """simulation.replicas.test_tether_free: the tether-free test moulds (as the generator
    draws them) take it, every other mould its split's count; null leaves them alone."""
    from condor.moulds.paper import generate_mould

    config = Config.default(n_moulds=60, split={"test": 30},
                            moulds={"no_tether_fraction": 0.3},
                            simulation={"replicas": {"test": 4, "test_tether_free": 11}})
    params = config.mould_params()
    sources = config.sources()  # a lab mould always has posts
    expected = [11 if split == "test" and sources[i] == "paper" and
                generate_mould(config.seed, i, config.scene, params).n_tethers == 0
                else config.simulation["replicas"][split]
                for i, split in enumerate(config.splits())]
    assert list(config.replicas()) == expected and expected.count(11) >= 3
    assert config.store_spec().replicas == tuple(expected)
    plain = Config.default(n_moulds=60, split={"test": 30}, moulds={"no_tether_fraction": 0.3},
                           simulation={"replicas": {"test": 4, "test_tether_free": None}})
    assert set(r for r, s in zip(plain.replicas(), plain.splits()) if s == "test") == {4}


def test_the_schema_takes_every_variant_setting_the_library_knows():
    """A setting TrainConfig/UNetConfig accepts but the schema lacks could not be set in a
    workflow config; num_threads is the workflow's (surrogate.threads), not a variant's."""
    from condor.surrogate.variants import SETTING_KEYS

    models = load_schema()["properties"]["surrogate"]["properties"]["models"]
    assert set(models["additionalProperties"]["properties"]) == \
        set(SETTING_KEYS) - {"num_threads"} | {"preset"}
    config = Config.default(surrogate={"variants": ["t"], "models": {"t": {
        "model": "unet", "head": "physics", "loss": "gaussian", "sum_weight": 1.0}}})
    assert config.surrogate["models"]["t"]["sum_weight"] == 1.0


def test_the_schema_s_allowed_values_are_the_code_s():
    """Every list of allowed values in the schema (scenes, solvers, networks, inputs,
    upsampling, heads, losses, scalings, loss regions, replica uses, schedules, prediction
    modes) is the list the code accepts, in the code's order: the code is its home, the schema
    a copy that this test holds to it."""
    from condor.data.inputs import INPUT_KINDS
    from condor.model.scenes import PRESETS
    from condor.model.simulate import SOLVERS
    from condor.moulds.lab import FAMILY_NAMES
    from condor.surrogate.modes import PREDICTION_MODES
    from condor.surrogate.networks import UPSAMPLE_MODES
    from condor.surrogate.train import (HEADS, LOSS_REGIONS, LOSSES, LR_SCHEDULES,
                                        NETWORK_KINDS, REPLICA_USES, SCALINGS)

    schema = load_schema()["properties"]
    surrogate = schema["surrogate"]["properties"]
    setting = surrogate["models"]["additionalProperties"]["properties"]
    expected = {
        "scene": (schema["scene"]["enum"], tuple(PRESETS)),
        "simulation/solver": (schema["simulation"]["properties"]["solver"]["enum"],
                              (*SOLVERS, None)),
        "surrogate/eval_modes": (surrogate["eval_modes"]["items"]["enum"], PREDICTION_MODES),
        "model": (setting["model"]["enum"], NETWORK_KINDS),
        "upsample": (setting["upsample"]["enum"], UPSAMPLE_MODES),
        "lr_schedule": (setting["lr_schedule"]["enum"], LR_SCHEDULES),
        "inputs": (setting["inputs"]["enum"], INPUT_KINDS),
        "prediction_mode": (setting["prediction_mode"]["enum"], PREDICTION_MODES),
        "head": (setting["head"]["enum"], HEADS),
        "loss": (setting["loss"]["enum"], LOSSES),
        "scaling": (setting["scaling"]["enum"], SCALINGS),
        "loss_region": (setting["loss_region"]["enum"], LOSS_REGIONS),
        "replicas": (setting["replicas"]["enum"], REPLICA_USES),
        "moulds/lab_families": (schema["moulds"]["properties"]["lab_families"]["items"]["enum"],
                                FAMILY_NAMES),
    }
    for key, (schema_list, code) in expected.items():
        assert tuple(schema_list) == tuple(code), key
    # the stability study may run any solver (its default lists the faithful one first)
    stability = schema["report"]["properties"]["stability_solvers"]["items"]["enum"]
    assert sorted(stability) == sorted(SOLVERS)
    enums = []

    def walk(node):
        if isinstance(node, dict):
            enums.extend([node["enum"]] if "enum" in node else [])
            for value in node.values():
                walk(value)

    walk(schema)
    assert len(enums) == len(expected) + 1  # a new list of allowed values joins the table


# --- combinations that would fail late (issue 33, items 10 and 11) -----------------------------

@pytest.mark.parametrize("change, named", [
    # sizes that exhaust memory or time (a MemoryError a minute in)
    ({"scene_overrides": {"box": 100000}}, r"scene_overrides/box = 100000: .* cells; the limit "
                                           r"is 200,000 a mould"),
    ({"scene_overrides": {"depth": 1000}}, r"scene_overrides/depth = 1000: .* the limit is "
                                           r"200,000"),
    ({"scene_overrides": {"box": 500, "depth": 2}}, r"scene_overrides/box = 500: "),
    ({"scene_overrides": {"pixels": 1024}, "n_moulds": 20000},
     r"scene_overrides/pixels = 1024: .* GiB of fields; the limit is 256 GiB"),
    ({"n_moulds": 10 ** 9}, r"n_moulds = 1000000000: .* the limit is 256 GiB"),
    ({"scene_overrides": {"sigma": 1000}}, r"scene_overrides/sigma = 1000: .* the limit is 1 GiB"),
    ({"report": {"convergence_depths": [2.0, 500.0]}},
     r"report/convergence_depths = \[2.0, 500.0\]: .* the limit is 200,000"),
    ({"report": {"convergence_box_scales": [1.0, 30.0]}},
     r"report/convergence_box_scales = \[1.0, 30.0\]: .* the limit is 200,000"),
    # moulds the generator or the lattice cannot build (the moulds or simulate jobs fail)
    ({"scene_overrides": {"box": 5}}, r"scene_overrides/box = 5: .* smaller than the 20 l0\^2"),
    ({"scene_overrides": {"area_fraction": 0.01}}, r"scene_overrides/area_fraction = 0.01: "),
    ({"report": {"convergence_box_scales": [0.1, 1.0]}}, r"report/convergence_box_scales"),
    ({"scene_overrides": {"max_extent": 0.6}}, r"scene_overrides/max_extent = 0.6: .* at most 0.62"),
    ({"scene_overrides": {"area_fraction": 0.81}}, r"scene_overrides/area_fraction = 0.81: "),
    # too few replicas for the studies (accuracy and ladder fail after training and design)
    ({"simulation": {"replicas": {"test": 1}}}, r"simulation/replicas/test: 1 is too few.* 4 "),
    ({"simulation": {"replicas": {"test": 4, "test_tether_free": 2}}},
     r"simulation/replicas/test_tether_free: 2 is too few"),
    # no surrogate variant: the design stage takes the first (an IndexError parsing the rules)
    ({"surrogate": {"variants": []}}, r"surrogate/variants: "),
])
def test_combinations_that_would_fail_late_are_refused_in_one_line(change, named):
    config = default_config()
    config.update(change)
    with pytest.raises(ConfigError, match=named) as info:
        Config.from_dict(config)
    assert "\n" not in str(info.value) and str(info.value).startswith("config key ")


@pytest.mark.parametrize("name", ["config.yaml", "tiny.yaml", "paper.yaml"])
def test_shipped_configs_pass_the_size_limits_with_a_wide_margin(name, monkeypatch):
    """Every shipped config still passes with the memory limits ten times tighter and the
    smallest mould four times larger (the paper scene: ~9,400 cells, 14 GiB of fields)."""
    import condor.config as C

    monkeypatch.setattr(C, "MAX_CELLS", C.MAX_CELLS / 10)
    monkeypatch.setattr(C, "MAX_FIELD_BYTES", C.MAX_FIELD_BYTES / 10)
    monkeypatch.setattr(C, "MAX_KERNEL_BYTES", C.MAX_KERNEL_BYTES / 10)
    monkeypatch.setattr(C, "MIN_MOULD_AREA", C.MIN_MOULD_AREA * 4)
    Config.load(CONFIG_DIR / name)


def test_the_design_defaults_have_one_home():
    """The CLI's design defaults are the schema's; the design stage and the library's search
    and confirmation take the numbers from their callers (no default of their own)."""
    import inspect

    from condor import cli
    from condor.design import confirm_designs, search_designs, simulate_designs
    from condor.stages.design import design

    args = cli.build_parser().parse_args(["design", "--objective", "uniformity", "--checkpoint",
                                          "m.pt", "--out", "d"])
    schema = load_schema()["properties"]["design"]["properties"]
    assert (args.budget, args.top, args.random, args.replicas, args.seed) == tuple(
        schema[k]["default"] for k in ("budget", "top", "random", "replicas", "seed"))
    for function, names in ((design, ("budget", "seed", "n_top", "n_random", "replicas")),
                            (search_designs, ("budget",)),
                            (confirm_designs, ("n_top", "n_random", "replicas"))):
        parameters = inspect.signature(function).parameters
        assert all(parameters[n].default is inspect.Parameter.empty for n in names), function
    # simulate_designs takes its replicas from its caller, or explicit seeds
    assert inspect.signature(simulate_designs).parameters["replicas"].default is None
    with pytest.raises(ValueError, match="needs replicas"):
        simulate_designs(None, [], None)


@pytest.mark.parametrize("text, said", [
    ("seed: 7\nn_moulds: 40: 50\n", "not valid YAML at line 2, column 13"),
    ("seed: 7\nsplit:\n\ttest: 3\n", "not valid YAML at line 3, column 1"),
    ("- seed\n- 7\n", "must be a mapping of keys, got list"),
])
def test_a_config_file_mistake_is_one_line_naming_the_file_and_line(tmp_path, text, said):
    """Issue 44: a YAML mistake named the file and, on another line, where it was."""
    path = tmp_path / "mine.yaml"
    path.write_text(text)
    with pytest.raises(ConfigError) as info:
        Config.load(CONFIG_DIR / "config.yaml", path)
    assert "\n" not in str(info.value) and str(path) in str(info.value) and said in str(info.value)
    with pytest.raises(ConfigError, match=f"config file {tmp_path / 'gone.yaml'} does not exist"):
        Config.load(tmp_path / "gone.yaml")


def test_a_store_of_another_solver_recipe_is_refused_not_mixed(tmp_path, monkeypatch):
    # the relaxed anneal's recipe (relaxations, tolerance) is not in the config: a store records
    # it, and a build under another recipe is refused before any job writes a sample
    import condor.model.simulate as sim
    from condor.data.store import StoreError, create_store

    config = Config.load(CONFIG_DIR / "tiny.yaml")
    path = tmp_path / "d.zarr"
    create_store(path, config.store_spec())
    assert not create_store(path, config.store_spec())  # the same recipe: kept
    monkeypatch.setattr(sim, "RELAXED_FIRST_RELAX", sim.RELAXED_FIRST_RELAX + 1)
    with pytest.raises(StoreError, match="solver_recipe"):
        create_store(path, config.store_spec())
