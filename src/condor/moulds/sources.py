"""Which source makes each mould of a dataset, and the mould of an id.

A dataset mixes three sources: the paper's generator (`condor.moulds.paper`, family PAPER), the
lab families (`condor.moulds.lab`) and, for training only, composite moulds
(`condor.moulds.composite`). `assign_sources` gives every mould id its source from the split
and the config's mixture (`moulds.lab_fraction`, `moulds.composite_fraction`, `split.lab_test`,
`moulds.lab_families`): a pure function of the seed, with each family's share of a split
equal to within one mould. `make_mould` draws the mould of an id from its source.
"""

from __future__ import annotations

import numpy as np

from condor.model.scenes import Scene
from condor.moulds.composite import COMPOSITE, composite_mould
from condor.moulds.lab import AREA_RANGE, FAMILY_NAMES, lab_mould
from condor.moulds.mould import PAPER, Mould, check_mould
from condor.moulds.paper import MouldParams, generate_mould, is_tether_free

SOURCE_STREAM = 0x1AB  # default_rng([seed, SOURCE_STREAM]): which moulds are lab moulds


def lab_test_share(lab_fraction: float, composite_fraction: float) -> float:
    """The share of lab moulds in a test set of no set size (`split.lab_test` null): the lab
    families' share of the training moulds that are not composite, lab_fraction (1 - c) /
    (1 - lab_fraction c), so that the test sets mirror the two sources the training set draws
    its moulds from (composite moulds train only). lab_fraction itself without composite
    moulds, and when every training mould is composite."""
    rest = 1.0 - lab_fraction * composite_fraction
    return lab_fraction if rest <= 0 else lab_fraction * (1.0 - composite_fraction) / rest


def assign_sources(splits, lab_fraction: float, lab_test: int | None, families, seed: int,
                   pinned=(), composite_fraction: float = 0.0) -> tuple[str, ...]:
    """The source of every mould (PAPER, a lab family or COMPOSITE), from its split (`splits`,
    one label a mould): `lab_test` of the test moulds (None: round(lab_test_share x n) of the n
    test moulds that are not pinned) and round(lab_fraction x n) of the n moulds of each other
    split are lab moulds, chosen by a seeded permutation; the `pinned` moulds (those with a
    paper reference) are always the generator's. Of a training or validation split's lab
    moulds, round(composite_fraction x their number) are composite moulds; the rest, and every
    lab test mould, take the families in turn, from a seeded start, so each family has the
    same share of a split to within one mould. ValueError when the test split has too few free
    moulds for `lab_test`."""
    families = tuple(families)
    unknown = [f for f in families if f not in FAMILY_NAMES]
    if unknown:
        raise ValueError(f"unknown lab families {unknown}; choose among {FAMILY_NAMES}")
    if not 0.0 <= lab_fraction <= 1.0:
        raise ValueError(f"lab_fraction must be in [0, 1], got {lab_fraction}")
    if not 0.0 <= composite_fraction <= 1.0:
        raise ValueError(f"composite_fraction must be in [0, 1], got {composite_fraction}")
    if ((lab_fraction > 0 and composite_fraction < 1) or (lab_test or 0) > 0) and not families:
        raise ValueError("lab moulds were asked for, but no lab family is chosen")
    n = len(splits)
    rng = np.random.default_rng([int(seed), SOURCE_STREAM])
    order = rng.permutation(n)
    pinned = {int(p) for p in pinned}
    sources = np.full(n, PAPER, dtype=object)
    for split in ("test", "val", "train"):
        members = [int(i) for i in order if splits[i] == split]
        free = [i for i in members if i not in pinned]
        if split != "test":
            count = int(round(lab_fraction * len(members)))
        elif lab_test is None:
            count = int(round(lab_test_share(lab_fraction, composite_fraction) * len(free)))
        else:
            count = int(lab_test)
        if count > len(free):
            raise ValueError(f"{count} lab moulds asked of the {len(members)} {split} moulds, "
                             f"of which {len(free)} are free (the others hold a paper "
                             "reference)")
        start = int(rng.integers(len(families))) if families else 0
        n_composite = 0 if split == "test" else int(round(composite_fraction * count))
        for i in free[:n_composite]:
            sources[i] = COMPOSITE
        for k, i in enumerate(free[n_composite:count]):
            sources[i] = families[(start + k) % len(families)]
    return tuple(sources)


def make_mould(scene: Scene, seed: int, mould_id: int, source: str = PAPER,
               params: MouldParams | None = None, lab_area=AREA_RANGE) -> Mould:
    """Mould `mould_id` of dataset `seed` in `scene` from its source (PAPER: the generator with
    `params`; a lab family: `lab_mould` with areas in `lab_area`; COMPOSITE: `composite_mould`,
    the same areas), checked (never write invalid geometry)."""
    if not isinstance(source, str):
        raise TypeError(f"make_mould's source is PAPER or a lab family's name, not {source!r} "
                        "(pass the generator's parameters as params=)")
    if source == PAPER:
        mould = generate_mould(seed, mould_id, scene, **({} if params is None else
                                                       {"params": params}))
        check_mould(mould)
        return mould
    if source == COMPOSITE:
        return composite_mould(seed, mould_id, scene, tuple(lab_area))
    return lab_mould(seed, mould_id, source, scene, tuple(lab_area))


def tether_free(seed: int, mould_id: int, source: str, params: MouldParams) -> bool:
    """Whether mould `mould_id` has no posts, without drawing its geometry: the generator's
    first draw for its moulds; a lab or composite mould always has posts."""
    return source == PAPER and is_tether_free(seed, mould_id, params)
