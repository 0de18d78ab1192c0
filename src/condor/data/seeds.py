"""Seed conventions: every random stream of a dataset is a pure function of the global seed.

Streams in other modules: a mould's geometry uses default_rng([seed, mould]) (condor.moulds.paper),
the split permutation default_rng([seed, 0x5B117]) (condor.data.store.assign_splits). Here: the
simulation seed of each replica of a mould, and the seeds of study runs, which must be
independent of every replica (a study compares methods against the replicas).
"""

from __future__ import annotations

import numpy as np

_SEED_RANGE = 2**62


def replica_seed(seed: int, mould: int, replica: int) -> int:
    """Simulation seed of `replica` of `mould` in the dataset of global `seed`. Replica 0 keeps
    the stream of datasets built before replicas existed, so their samples are unchanged."""
    key = [int(seed), int(mould), 1] if replica == 0 else [int(seed), int(mould), 1, int(replica)]
    return int(np.random.default_rng(key).integers(_SEED_RANGE))


def study_seed(seed: int, mould: int, run: int) -> int:
    """Seed of the `run`-th study simulation of `mould`: a stream no replica uses."""
    return int(np.random.default_rng([int(seed), int(mould), 2, int(run)]).integers(_SEED_RANGE))
