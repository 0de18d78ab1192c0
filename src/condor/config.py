"""The workflow configuration: one frozen `Config`, built once from the validated YAML.

The JSON schema (`config.schema.yaml`, shipped inside the package) is the only place where
defaults live: `Config.from_dict` fills them, validates, checks what a schema cannot express
(a split that leaves no training mould, a U-Net that does not fit the grid, a CUDA device on a
machine without one, fewer test replicas than the studies need, a scene or store beyond the
size limits below: every combination that would fail in a late job) and freezes the result. The workflow (`workflow/rules/common.smk`) and
the CLI build it the same way, so both stop on the same bad key with a one-line message.

`data_config()` is the part of a config that defines the data in a results folder (scene,
seed, moulds, split, solver, replicas, batching): a results folder is never reused for
another one (condor.folder).
"""

from __future__ import annotations

import json
import logging
import math
from dataclasses import dataclass
from pathlib import Path
from types import MappingProxyType
from typing import Mapping

import jsonschema
import yaml

from condor.model.anneal import T_INIT, T_RATIO
from condor.model.energy import DELTA
from condor.data.fields import FIELD_NAMES, window_width
from condor.model.lattice import SHELL_KBAR, fcc_layers
from condor.moulds.lab import FAMILY_NAMES, check_area_range
from condor.moulds.mould import PAPER
from condor.moulds.paper import MouldParams
from condor.moulds.sources import assign_sources, make_mould, tether_free
from condor.model.scenes import Scene, get_scene
from condor.model.simulate import DEFAULT_SOLVER, default_budget, solver_recipe
from condor.model.minimise import FTOL
from condor.data.store import SPLITS, StoreSpec, assign_splits
from condor.studies.recipes import MIN_REPLICAS

log = logging.getLogger("condor")
TEST_SETS = ("paper", "lab")  # the test moulds of the generator, and of the lab families

SCHEMA_PATH = Path(__file__).with_name("config.schema.yaml")

# What a config may ask of the machines, checked before any job runs (a typo such as
# `box: 100000` is refused, not met as a MemoryError a minute in). Each limit is far above
# every shipped config (the paper scene: ~9,400 cells a mould, 14 GiB of fields) and far below
# what fails:
# - cells of one mould (its area x one cell per l0^2 of an FCC (001) layer x the layers of its
#   depth): a simulation holds up to ~8 KB a cell (measured at 37,400 cells, box 125 l0: 305
#   MB with relaxed_anneal, 233 MB with lbfgs), so 200,000 fill the simulate rule's 2 GB
#   (mem_mb 2000); 21x the paper scene, whose simulations already take 15 s or more;
MAX_CELLS = 200_000
# - the store's fields (samples x 8 float32 maps of pixels^2): the baselines read the training
#   split's fields whole into memory (the evaluate_baselines and accuracy jobs), so a store
#   beyond this fits no common machine; 18x the paper's 14 GiB;
MAX_FIELD_BYTES = 256 * 2**30
# - the rasteriser's kernel weights of one sample (2 axes x cells x window x 8 bytes; the
#   window is 11 sigma in px, condor.data.fields): within the fields rule's 2 GB (mem_mb 2000);
#   the paper scene's are 5 MB;
MAX_KERNEL_BYTES = 2**30
# - the smallest mould (area_fraction x box^2, l0^2) the generator and the lattice build:
#   measured over 300 moulds, 10 l0^2 left 2 without a mobile cell, 14 and 20 none (area
#   fraction 0.4 and 0.1); the tiny scene's are 98 l0^2;
MIN_MOULD_AREA = 20.0
# - how full the generator may pack a mould's extent (area_fraction / max_extent^2): fuller,
#   some moulds are never accepted (measured, 40-300 moulds a setting: 0.82 (area fraction
#   0.4, extent 0.7) failed 15 of 40, 0.81 (0.81, 1.0) 16 of 40, 0.74 (0.6, 0.9) 5 of 40,
#   0.70 (0.45, 0.8) 1 of 40; 0.625 (0.4, 0.8) and 0.68 (0.55, 0.9) none of 300); the
#   paper's 0.4 / 0.9^2 = 0.49.
MAX_FILL = 0.62

# The CONDOR model parameters every dataset records, from the physics modules themselves.
MODEL_PARAMETERS = MappingProxyType({
    "delta": DELTA, "kbar": list(SHELL_KBAR), "t_init": T_INIT, "t_ratio": T_RATIO,
    "lattice": "fcc",
})


class ConfigError(ValueError):
    """A configuration key or value is invalid; the message names it."""


def _frozen(value):
    """Read-only view of nested dicts and lists (a frozen config stays frozen)."""
    if isinstance(value, Mapping):
        return MappingProxyType({k: _frozen(v) for k, v in value.items()})
    if isinstance(value, list):
        return tuple(_frozen(v) for v in value)
    return value


def _plain(value):
    """The inverse of _frozen: JSON-safe dicts and lists."""
    if isinstance(value, Mapping):
        return {k: _plain(v) for k, v in value.items()}
    if isinstance(value, tuple):
        return [_plain(v) for v in value]
    return value


@dataclass(frozen=True)
class Config:
    """A validated workflow configuration (every default filled from the schema).

    Sections are read-only mappings: `config.simulation["solver"]`, `config.report["moulds"]`.
    """

    scene: Scene
    seed: int
    n_moulds: int
    batch_size: int
    results: Path
    moulds: Mapping
    split: Mapping
    simulation: Mapping
    surrogate: Mapping
    report: Mapping
    design: Mapping
    raw: Mapping  # the validated dict, defaults filled (what a checkpoint or report records)

    # --- building ------------------------------------------------------------------------

    @classmethod
    def from_dict(cls, config: Mapping, check_surrogate: bool = True) -> "Config":
        """Validate a config dict (defaults filled) and freeze it; ConfigError names the key.
        `check_surrogate=False` skips building the surrogate variants and parsing the design
        objective, for the jobs of a workflow whose config was checked in full when it started."""
        filled = json.loads(json.dumps(_plain(config)))  # a copy: the caller's dict is kept
        schema = load_schema()
        _fill_defaults(filled, schema)
        errors = sorted(jsonschema.Draft202012Validator(schema).iter_errors(filled), key=str)
        if errors:
            err = errors[0]
            where = "/".join(str(p) for p in err.absolute_path) or "(top level)"
            raise ConfigError(f"config key {where}: {err.message}")
        try:
            scene = get_scene(filled["scene"], **filled["scene_overrides"])
        except ValueError as err:
            raise ConfigError(f"config key scene: {err}") from err
        made = cls(scene=scene, seed=filled["seed"], n_moulds=filled["n_moulds"],
                   batch_size=filled["batch_size"], results=Path(filled["results"]),
                   moulds=_frozen(filled["moulds"]), split=_frozen(filled["split"]),
                   simulation=_frozen(filled["simulation"]),
                   surrogate=_frozen(filled["surrogate"]), report=_frozen(filled["report"]),
                   design=_frozen(filled["design"]),
                   raw=_frozen(filled))
        made._check_consistency(check_surrogate)
        return made

    @classmethod
    def load(cls, *paths: str | Path) -> "Config":
        """Read YAML config files and build the Config of them layered as Snakemake layers
        them (`layered`): `Config.load("config/config.yaml", "config/tiny.yaml")` is the
        config of `snakemake --configfile config/tiny.yaml`."""
        return cls.from_dict(layered(*map(read_config_file, paths)))

    @classmethod
    def default(cls, **changes) -> "Config":
        """The schema's defaults (the embedded default scene), with top-level `changes`."""
        return cls.from_dict(changes)

    def to_dict(self) -> dict:
        return _plain(self.raw)

    # --- derived -------------------------------------------------------------------------

    def mould_params(self) -> MouldParams:
        """Generator parameters: MouldParams' own defaults, with the keys the config sets."""
        given = {k: v for k, v in self.moulds.items() if k in MouldParams.__dataclass_fields__}
        params = MouldParams(**given)
        params.validate()
        return params

    def splits(self) -> tuple[str, ...]:
        """The split of every mould (deterministic for the seed); the moulds the package
        holds a paper reference of (scene and seed) are always test moulds, so that the
        surrogate is scored against the paper's ensemble on moulds it did not train on."""
        return mould_splits(self.n_moulds, self.split, self.seed, self.scene.name)

    def lab_families(self) -> tuple[str, ...]:
        """The lab families the config draws from (`moulds.lab_families`; null: all)."""
        chosen = self.moulds["lab_families"]
        return tuple(FAMILY_NAMES if chosen is None else chosen)

    def sources(self) -> tuple[str, ...]:
        """The source of every mould: PAPER (the generator) or a lab family
        (`condor.moulds.sources.assign_sources`); the moulds with a paper reference are the
        generator's."""
        from condor.studies.paper_reference import reference_moulds
        return assign_sources(self.splits(), self.moulds["lab_fraction"],
                              self.split["lab_test"], self.lab_families(), self.seed,
                              pinned=reference_moulds(self.scene.name, self.seed),
                              composite_fraction=self.moulds["composite_fraction"])

    def make_mould(self, mould_id: int):
        """Mould `mould_id` of this dataset, from its source."""
        return make_mould(self.scene, self.seed, mould_id, self.sources()[mould_id],
                          self.mould_params(), self.moulds["lab_area"])

    def replicas(self) -> tuple[int, ...]:
        """Simulations per mould, from its split; a tether-free test mould takes
        `test_tether_free` when set (its orientation scatters far more: docs/surrogate.md,
        "Tether-free test moulds")."""
        counts = self.simulation["replicas"]
        free = counts.get("test_tether_free")
        params = self.mould_params()
        return tuple(int(free) if s == "test" and free is not None
                     and tether_free(self.seed, i, source, params) else int(counts[s])
                     for i, (s, source) in enumerate(zip(self.splits(), self.sources())))

    def batches(self) -> list[range]:
        """Mould ids per job: consecutive runs of `batch_size`."""
        n, size = self.n_moulds, self.batch_size
        return [range(start, min(start + size, n)) for start in range(0, n, size)]

    def test_moulds(self, source: str | None = None) -> list[int]:
        """Mould ids of the test split, in id order; `source` "paper": the generator's only
        (the paper test set), "lab": the lab families' only (the lab test set)."""
        test = [i for i, s in enumerate(self.splits()) if s == "test"]
        if source is None:
            return test
        if source not in TEST_SETS:
            raise ValueError(f"unknown test set {source!r}; choose one of {TEST_SETS}")
        sources = self.sources()
        return [i for i in test if (sources[i] == PAPER) == (source == "paper")]

    def study_moulds(self) -> list[int]:
        """The test moulds the accuracy study and the sweeps use: the first `report.moulds` by id
        of the paper test set (the generator's moulds, as the paper reference's), then of the lab
        test set when the paper test set holds fewer (said in the log). ConfigError, naming the
        key, when the whole test set holds fewer, or `report.ladder_moulds` (the ladder's, the
        first of them) asks for more: a report never measures fewer moulds than its config says."""
        paper, lab = self.test_moulds("paper"), self.test_moulds("lab")
        report = self.report
        wanted = report["moulds"]
        if wanted > len(paper) + len(lab):
            raise ConfigError(
                f"config key report/moulds: {wanted}, but the test set holds {len(paper) + len(lab)} "
                f"moulds (split/test {self.split['test']}); lower report/moulds to "
                f"{len(paper) + len(lab)} or less, or raise split/test")
        if report["ladder_moulds"] > wanted:
            raise ConfigError(
                f"config key report/ladder_moulds: {report['ladder_moulds']}, but the ladder runs on "
                f"the accuracy study's moulds, report/moulds = {wanted}: lower it")
        chosen = (paper + lab)[:wanted]
        if wanted > len(paper):
            log.warning(
                "report.moulds is %d, but the paper test set holds %d moulds: the accuracy study "
                "sweeps %d paper and %d lab test moulds (raise split.test, or lower "
                "split.lab_test)", wanted, len(paper), len(paper), wanted - len(paper))
        return chosen

    def solver(self) -> tuple[str, float]:
        """The simulation's solver and budget, None resolved to the simulator's defaults at
        this scene's box (condor.model.simulate.default_budget)."""
        solver = self.simulation["solver"] or DEFAULT_SOLVER
        budget = self.simulation["budget"]
        return solver, (default_budget(solver, self.scene.box) if budget is None else float(budget))

    def data_config(self) -> dict:
        """What defines the data in a results folder: a folder built for one of these never
        takes samples made with another (condor.folder checks it before any job runs)."""
        return {"scene": self.scene.to_dict(), "seed": self.seed, "n_moulds": self.n_moulds,
                "batch_size": self.batch_size,
                "no_tether_fraction": self.mould_params().no_tether_fraction,
                "split": _plain(self.split), "lab_fraction": self.moulds["lab_fraction"],
                "lab_families": list(self.lab_families()),
                "lab_area": list(self.moulds["lab_area"]),
                # recorded when it draws a mould (lab moulds asked for): a store built before
                # the key had none, and a store of the generator's moulds alone holds none
                **({"composite_fraction": self.moulds["composite_fraction"]}
                   if self.moulds["composite_fraction"] and self.moulds["lab_fraction"] else {}),
                "solver": self.solver()[0],
                "budget": self.solver()[1], "ftol": FTOL,
                "replicas": _plain(self.simulation["replicas"])}

    def store_spec(self) -> StoreSpec:
        scene = self.scene
        return StoreSpec(
            n_moulds=self.n_moulds, pixels=scene.pixels, seed=self.seed, split=self.splits(),
            replicas=self.replicas(),
            attrs={"scene": scene.to_dict(), "pixel_size": scene.pixel_size,
                   "sigma": scene.sigma, "model": dict(MODEL_PARAMETERS),
                   "mould_params": {"no_tether_fraction": self.mould_params().no_tether_fraction},
                   "solver": self.solver()[0], "solver_budget": self.solver()[1],
                   "solver_recipe": solver_recipe(self.solver()[0]),
                   "data_config": self.data_config()},
        )

    # --- checks a schema cannot express ---------------------------------------------------

    def _check_consistency(self, check_surrogate: bool = True) -> None:
        self._check_sizes()
        try:
            labels = self.splits()
        except ValueError as err:
            raise ConfigError(f"config key split: {err}") from err
        if "train" not in labels:
            raise ConfigError(
                f"config key split/val_fraction: {self.split['val_fraction']} of the "
                f"{self.n_moulds - self.split['test']} non-test moulds leaves none for training")
        try:
            self.mould_params()
        except ValueError as err:
            raise ConfigError(f"config key moulds: {err}") from err
        try:
            self.sources()
        except ValueError as err:
            raise ConfigError(f"config key split/lab_test: {err}") from err
        try:
            check_area_range(self.moulds["lab_area"], self.lab_families(), self.scene.max_extent)
        except ValueError as err:
            raise ConfigError(f"config key moulds/lab_area: {err}") from err
        counts = self.simulation["replicas"]
        for name in ("test", "test_tether_free"):
            if counts[name] is not None and counts[name] < MIN_REPLICAS:
                raise ConfigError(
                    f"config key simulation/replicas/{name}: {counts[name]} is too few; the "
                    "accuracy study and the anneal ladder measure against the mean of "
                    f"{MIN_REPLICAS} or more replicas a test mould "
                    "(condor.studies.recipes.MIN_REPLICAS)")
        if check_surrogate:
            self._check_surrogate()
        scene = self.scene
        if not (math.isfinite(scene.pixel_size) and scene.pixels >= 8):
            raise ConfigError(f"config key scene_overrides: {scene.pixels} px is too coarse")

    def _scene_key(self, *names: str) -> str:
        """'scene_overrides/<name> = <value>' for the first of `names` the config overrides
        (the key to blame for a scene size), else the preset's 'scene = <name>'."""
        given = self.raw["scene_overrides"]
        name = next((n for n in names if n in given), None)
        return f"scene = {self.raw['scene']}" if name is None else \
            f"scene_overrides/{name} = {given[name]:g}"

    def _check_sizes(self) -> None:
        """Refuse a scene or dataset beyond the limits at the top of this module, naming the
        key. Arithmetic only: it runs before the splits are drawn."""
        scene, report = self.scene, self.report
        if scene.area_fraction > MAX_FILL * scene.max_extent ** 2:
            raise ConfigError(
                f"config key {self._scene_key('area_fraction', 'max_extent')}: an area fraction "
                f"of {scene.area_fraction:g} within a max_extent of {scene.max_extent:g} is "
                f"{scene.area_fraction / scene.max_extent ** 2:.2f} of the extent's square; the "
                f"mould generator accepts at most {MAX_FILL:g} (condor.config.MAX_FILL)")
        # every lattice the workflow builds: the dataset's, and the convergence study's
        # deepest, smallest and largest (condor.studies.convergence)
        depths, scales = report["convergence_depths"], report["convergence_box_scales"]
        lattices = [(self._scene_key("box", "depth", "area_fraction"), scene.box, scene.depth),
                    (f"report/convergence_depths = {list(depths)}", scene.box, max(depths))]
        lattices += [(f"report/convergence_box_scales = {list(scales)}", scene.box * scale,
                      scene.depth) for scale in ((min(scales), max(scales)) if scales else ())]
        for key, box, depth in lattices:
            area = scene.area_fraction * box ** 2
            cells = area * fcc_layers(depth)  # one cell per l0^2 of an FCC (001) layer
            mould = (f"a mould of {area:.4g} l0^2 (box {box:g} l0, area fraction "
                     f"{scene.area_fraction:g})")
            if area < MIN_MOULD_AREA:
                raise ConfigError(f"config key {key}: {mould} is smaller than the "
                                  f"{MIN_MOULD_AREA:g} l0^2 the generator and the lattice "
                                  "need (condor.config.MIN_MOULD_AREA)")
            if cells > MAX_CELLS:
                raise ConfigError(
                    f"config key {key}: {mould} and depth {depth:g} l0 ({fcc_layers(depth)} "
                    f"layers) holds ~{cells:,.0f} cells; the limit is {MAX_CELLS:,} a mould "
                    "(memory and time of a simulation: condor.config.MAX_CELLS)")
            kernel = 2 * cells * window_width(scene.sigma_px) * 8
            if kernel > MAX_KERNEL_BYTES:
                raise ConfigError(
                    f"config key {self._scene_key('sigma', 'pixels', 'box')}: a kernel of "
                    f"{scene.sigma_px:.4g} px over ~{cells:,.0f} cells needs "
                    f"{kernel / 2**30:.3g} GiB to rasterise a sample; the limit is "
                    f"{MAX_KERNEL_BYTES / 2**30:g} GiB (condor.config.MAX_KERNEL_BYTES)")
        # samples: each mould's replicas by split, the test moulds' largest count (no draw)
        counts, n_test = self.simulation["replicas"], min(self.split["test"], self.n_moulds)
        n_val = round(self.split["val_fraction"] * (self.n_moulds - n_test))
        samples = (n_test * max(counts["test"], counts["test_tether_free"] or 0)
                   + n_val * counts["val"] + (self.n_moulds - n_test - n_val) * counts["train"])
        size = samples * len(FIELD_NAMES) * scene.pixels ** 2 * 4
        if size > MAX_FIELD_BYTES:
            key = self._scene_key("pixels") if "pixels" in self.raw["scene_overrides"] else \
                f"n_moulds = {self.n_moulds}"
            raise ConfigError(
                f"config key {key}: up to {samples:,} samples of 8 fields at {scene.pixels} px "
                f"make {size / 2**30:,.0f} GiB of fields; the limit is "
                f"{MAX_FIELD_BYTES / 2**30:g} GiB (condor.config.MAX_FIELD_BYTES)")

    def _check_surrogate(self) -> None:
        # Imported here: a workflow job skips this (neither imports torch: a test says so).
        from condor.surrogate.variants import train_config, workflow_variants

        try:
            variants = workflow_variants(self)
        except ValueError as err:
            raise ConfigError(str(err)) from err
        for name, settings in variants.items():
            try:
                train_config(settings, self.scene.pixels)
            except ValueError as err:
                raise ConfigError(f"config key surrogate/models/{name}: {err}") from err
        device = self.surrogate["device"]
        if device is not None and variants:
            check_device(device, "config key surrogate/device")
        from condor.design.objectives import ObjectiveError, parse_objective

        try:
            parse_objective(self.design["objective"], pixels=self.scene.pixels,
                            max_extent=self.scene.max_extent)
        except ObjectiveError as err:
            raise ConfigError(f"config key design/objective: {err}") from err


def mould_splits(n_moulds: int, split: Mapping, seed: int, scene: str) -> tuple[str, ...]:
    """The split of every mould of a dataset (Config.splits): `split` the config's section,
    `scene` the scene's name (the moulds with a paper reference are test moulds)."""
    from condor.studies.paper_reference import reference_moulds
    return assign_splits(n_moulds, split["test"], split["val_fraction"], seed,
                         pinned=reference_moulds(scene, seed))


def recorded_splits(data_config: Mapping) -> tuple[str, ...] | None:
    """The split of every mould of a store built for `data_config` (Config.data_config(), as
    a store and its folder record it), None when it does not say."""
    try:
        return mould_splits(int(data_config["n_moulds"]), data_config["split"],
                            int(data_config["seed"]), data_config["scene"]["name"])
    except (KeyError, TypeError, ValueError):
        return None


def read_config_file(path) -> dict:
    """The mapping a YAML config file holds; ConfigError, one line, naming the file when it is
    missing, unreadable, not YAML (with the line and column of the mistake) or not a mapping."""
    path = Path(path)
    try:
        text = path.read_text()
    except FileNotFoundError:
        raise ConfigError(f"config file {path} does not exist") from None
    except (OSError, UnicodeDecodeError) as err:
        raise ConfigError(f"config file {path} cannot be read ({err})") from None
    try:
        config = yaml.safe_load(text)
    except yaml.YAMLError as err:
        mark = getattr(err, "problem_mark", None)
        where = f" at line {mark.line + 1}, column {mark.column + 1}" if mark is not None else ""
        problem = getattr(err, "problem", None) or str(err).splitlines()[0]
        context = getattr(err, "context", None)
        raise ConfigError(f"config file {path} is not valid YAML{where}: {problem}"
                          + (f" ({context})" if context else "")) from None
    if config is None:
        return {}
    if not isinstance(config, dict):
        raise ConfigError(f"config file {path} must be a mapping of keys, got "
                          f"{type(config).__name__}")
    return config


def check_device(device: str, what: str) -> None:
    """ConfigError when torch cannot use `device` here (e.g. 'cuda' without a GPU)."""
    import torch

    try:
        kind = torch.device(device).type
    except (RuntimeError, TypeError) as err:
        raise ConfigError(f"{what}: {device!r} is not a torch device ({err})") from err
    if kind == "cuda" and not torch.cuda.is_available():
        raise ConfigError(f"{what}: {device!r} asked for, but this machine has no CUDA device "
                          "(use null for CPU)")
    if kind not in ("cpu", "cuda", "mps"):
        raise ConfigError(f"{what}: device type {kind!r} is not supported (cpu or cuda)")


def layered(*configs: Mapping) -> dict:
    """Config dicts layered as Snakemake layers its config files (the Snakefile's
    `configfile:`, then each --configfile in turn): a mapping updates the mapping beneath it
    key by key, any other value replaces what was there."""
    def update(below, above):
        for key, value in above.items():
            if isinstance(value, Mapping):
                below[key] = update(below.get(key, {}) if isinstance(below.get(key), Mapping)
                                    else {}, value)
            else:
                below[key] = value
        return below

    merged: dict = {}
    for config in configs:
        update(merged, json.loads(json.dumps(_plain(config))))
    return merged


def load_schema() -> dict:
    return yaml.safe_load(SCHEMA_PATH.read_text())


def _fill_defaults(config: dict, schema: dict) -> None:
    for key, sub in schema.get("properties", {}).items():
        if key not in config and "default" in sub:
            config[key] = json.loads(json.dumps(sub["default"]))
        if isinstance(config.get(key), dict) and sub.get("type") == "object":
            _fill_defaults(config[key], sub)


__all__ = ["Config", "ConfigError", "MODEL_PARAMETERS", "SCHEMA_PATH", "SPLITS", "check_device",
           "layered", "load_schema", "mould_splits", "read_config_file", "recorded_splits"]
