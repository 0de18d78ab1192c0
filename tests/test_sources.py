"""Which source makes each mould (condor.moulds.sources) and the config's mixture keys."""

from collections import Counter

import numpy as np
import pytest

from condor.config import Config, ConfigError
from condor.model.scenes import get_scene
from condor.moulds.lab import FAMILY_NAMES
from condor.moulds.mould import PAPER
from condor.moulds.sources import assign_sources, make_mould
from condor.studies.paper_reference import reference_moulds


def _splits(n_train, n_val, n_test, seed=0):
    labels = ["train"] * n_train + ["val"] * n_val + ["test"] * n_test
    return tuple(np.random.default_rng(seed).permutation(labels))


def test_sources_meet_the_counts_per_split_with_families_in_equal_shares():
    splits = _splits(300, 30, 100)
    sources = assign_sources(splits, 0.5, 40, FAMILY_NAMES, seed=3, pinned=[0, 1, 2])
    by_split = Counter((s, src != PAPER) for s, src in zip(splits, sources))
    assert by_split[("test", True)] == 40 and by_split[("test", False)] == 60
    assert by_split[("train", True)] == 150 and by_split[("val", True)] == 15
    for split in ("train", "val", "test"):
        shares = Counter(src for s, src in zip(splits, sources) if s == split and src != PAPER)
        assert set(shares) <= set(FAMILY_NAMES)
        assert max(shares.values()) - min(shares.values()) <= 1
    assert all(sources[i] == PAPER for i in (0, 1, 2))  # the pinned moulds
    assert sources == assign_sources(splits, 0.5, 40, FAMILY_NAMES, seed=3, pinned=[0, 1, 2])
    assert sources != assign_sources(splits, 0.5, 40, FAMILY_NAMES, seed=4, pinned=[0, 1, 2])
    only = assign_sources(splits, 1.0, 0, ("ring",), seed=3)
    assert {src for s, src in zip(splits, only) if s != "test"} == {"ring"}


def test_impossible_mixtures_are_refused():
    splits = _splits(20, 2, 5)
    with pytest.raises(ValueError, match="6 lab moulds asked of the 5 test moulds, of which 3"):
        assign_sources(splits, 0.5, 6, FAMILY_NAMES, seed=0, pinned=[i for i, s in
                                                                      enumerate(splits)
                                                                      if s == "test"][:2])
    with pytest.raises(ValueError, match="unknown lab families"):
        assign_sources(splits, 0.5, 1, ("star",), seed=0)
    with pytest.raises(ValueError, match="no lab family"):
        assign_sources(splits, 0.5, 1, (), seed=0)


def test_a_mould_comes_from_its_source():
    scene = get_scene("default")
    paper = make_mould(scene, 2026, 3, PAPER)
    assert paper.family == PAPER and paper.is_generated
    lab = make_mould(scene, 2026, 3, "ring")
    assert lab.family == "ring" and not lab.is_generated and lab.n_tethers == 1


def test_the_config_refuses_mixtures_it_cannot_make_naming_the_key():
    for changes, key in [({"split": {"test": 10, "lab_test": 9}}, "split/lab_test"),
                         ({"moulds": {"lab_area": [0.5, 0.6]}}, "moulds/lab_area"),
                         ({"moulds": {"lab_area": [0.4, 0.3]}}, "moulds/lab_area"),
                         ({"moulds": {"lab_families": ["star"]}}, "moulds/lab_families"),
                         ({"moulds": {"lab_fraction": 1.5}}, "moulds/lab_fraction")]:
        with pytest.raises(ConfigError, match=f"config key {key}"):
            Config.default(**changes)


def test_lab_test_moulds_take_the_test_replicas_and_define_the_data():
    from condor.moulds.composite import COMPOSITE
    config = Config.default()
    sources, splits, replicas = config.sources(), config.splits(), config.replicas()
    lab_tests = [i for i, (s, src) in enumerate(zip(splits, sources))
                 if s == "test" and src != PAPER]
    free = [i for i in config.test_moulds() if i not in reference_moulds("default", config.seed)]
    assert config.split["lab_test"] is None  # the default: the families' share of training
    train = Counter(src for s, src in zip(splits, sources) if s == "train")
    family = sum(v for k, v in train.items() if k not in (PAPER, COMPOSITE))
    assert len(lab_tests) == round(family / (family + train[PAPER]) * len(free))
    assert {replicas[i] for i in lab_tests} == {config.simulation["replicas"]["test"]}
    assert config.test_moulds("lab") == lab_tests
    assert set(config.test_moulds("paper")) | set(lab_tests) == set(config.test_moulds())
    other = Config.default(moulds={"lab_fraction": 0.25})
    assert other.data_config() != config.data_config()
    assert other.data_config()["lab_fraction"] == 0.25


def test_composite_moulds_take_their_share_of_training_lab_moulds_and_never_a_test_mould():
    from condor.moulds.composite import COMPOSITE
    splits = _splits(300, 30, 100)
    plain = assign_sources(splits, 0.5, 40, FAMILY_NAMES, seed=3)
    mixed = assign_sources(splits, 0.5, 40, FAMILY_NAMES, seed=3, composite_fraction=0.4)
    for split, n_lab in (("train", 150), ("val", 15)):
        got = Counter(src for s, src in zip(splits, mixed) if s == split)
        assert got[COMPOSITE] == round(0.4 * n_lab)
        assert sum(v for k, v in got.items() if k != PAPER) == n_lab  # the lab share kept
        others = [v for k, v in got.items() if k not in (PAPER, COMPOSITE)]
        assert max(others) - min(others) <= 1
    test = [i for i, s in enumerate(splits) if s == "test"]
    assert [mixed[i] for i in test] == [plain[i] for i in test]  # the test sets unchanged
    assert plain == assign_sources(splits, 0.5, 40, FAMILY_NAMES, seed=3, composite_fraction=0)
    only = assign_sources(splits, 1.0, 0, (), seed=3, composite_fraction=1.0)
    assert {src for s, src in zip(splits, only) if s != "test"} == {COMPOSITE}
    with pytest.raises(ValueError, match="composite_fraction must be in"):
        assign_sources(splits, 0.5, 40, FAMILY_NAMES, seed=3, composite_fraction=1.5)


def test_a_test_set_of_no_set_size_mirrors_the_training_sources_beside_composite_moulds():
    from condor.moulds.composite import COMPOSITE
    splits = _splits(3000, 30, 1000)
    for lab_fraction, composite in ((0.6, 1 / 3), (0.5, 0.0), (0.8, 0.5), (0.3, 0.9)):
        sources = assign_sources(splits, lab_fraction, None, FAMILY_NAMES, seed=5, pinned=[0],
                                 composite_fraction=composite)
        train = Counter(src for s, src in zip(splits, sources) if s == "train")
        family = sum(v for k, v in train.items() if k not in (PAPER, COMPOSITE))
        share = family / (family + train[PAPER])  # counted, not the formula
        test = [src for s, src in zip(splits, sources) if s == "test"]
        free = len(test) - (splits[0] == "test")
        assert COMPOSITE not in test
        assert abs(sum(src != PAPER for src in test) / free - share) < 2 / 1000


def test_the_composite_share_defines_the_data_only_when_used():
    from condor.moulds.composite import COMPOSITE
    config = Config.default(moulds={"lab_fraction": 0.5, "composite_fraction": 0.0})
    assert "composite_fraction" not in config.data_config()  # stores built before the key
    paper = Config.default(moulds={"lab_fraction": 0.0, "composite_fraction": 0.33})
    assert "composite_fraction" not in paper.data_config()  # no lab mould: none drawn
    # a third of the training moulds composite beside the same families' and paper's shares:
    # the same test moulds, the same lab test set
    other = Config.default(moulds={"lab_fraction": 2 / 3, "composite_fraction": 0.5})
    assert other.data_config() != config.data_config()
    assert COMPOSITE in other.sources() and other.test_moulds() == config.test_moulds()
    assert other.test_moulds("lab") == config.test_moulds("lab")
    i = other.sources().index(COMPOSITE)
    assert other.make_mould(i).family == COMPOSITE
