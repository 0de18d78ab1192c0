"""The paper's CONDOR as a reference ensemble: long anneals of test moulds, run resumably.

A reference run is `reference.anneal_then_relax` (the paper's anneal of `budget` moves per
cell, then L-BFGS to a tight force) of one mould with one seed. Its seed is the study stream
`study_seed(dataset_seed, mould, REFERENCE_RUN + k)` for run k, shared by every budget (run k of
each rung starts from the same orientations) and used by no replica of the dataset.

`run_reference` keeps each finished run as a SimResult file under the cache folder, and the
anneal's checkpoint beside it while it runs: a killed ladder loses at most
`condor.anneal.CHECKPOINT_SECONDS` of work and resumes bit-identically.
"""

from __future__ import annotations

from pathlib import Path

from condor.moulds import generate_mould
from condor.scenes import Scene
from condor.seeds import study_seed
from condor.simulate import SimResult
from condor.studies.reference import anneal_then_relax

REFERENCE_RUN = 5000  # study-stream offset of the reference runs (`condor.seeds.study_seed`)


def reference_seed(dataset_seed: int, mould_id: int, k: int) -> int:
    return study_seed(dataset_seed, mould_id, REFERENCE_RUN + k)


def budget_tag(budget: float) -> str:
    """'1e5' for 100000.0, '3e3' for 3000.0, '1.5e4' for 15000.0."""
    mantissa, exponent = f"{float(budget):e}".split("e")
    return f"{float(mantissa):g}e{int(exponent)}"


def run_path(cache, scene: Scene, dataset_seed: int, mould_id: int, budget: float, k: int) -> Path:
    return (Path(cache) / f"{scene.name}_s{dataset_seed}"
            / f"m{mould_id}_anneal{budget_tag(budget)}_k{k}.npz")


def mould_of(scene: Scene, dataset_seed: int, mould_id: int):
    """The dataset's mould `mould_id` in `scene` (as condor.stages.dataset.make_mould)."""
    return generate_mould(dataset_seed, mould_id, box=scene.box,
                          area_fraction=scene.area_fraction, max_extent=scene.max_extent)


def run_reference(cache, scene: Scene, dataset_seed: int, mould_id: int, budget: float, k: int,
                  log=None) -> SimResult:
    """Reference run k of `mould_id` at `budget` moves per cell: read from the cache when it has
    finished, else run (resuming its checkpoint) and cached. A failed run is cached too: its
    status says why."""
    path = run_path(cache, scene, dataset_seed, mould_id, budget, k)
    if path.exists():
        return SimResult.load(path)
    checkpoint = path.with_name(path.stem + ".checkpoint.npz")
    mould = mould_of(scene, dataset_seed, mould_id)
    result = anneal_then_relax(mould, scene.depth, budget,
                               reference_seed(dataset_seed, mould_id, k),
                               checkpoint=checkpoint, log=log)
    result.info.update(scene=scene.name, dataset_seed=int(dataset_seed), mould=int(mould_id),
                       run=int(k))
    tmp = path.with_name(path.name + ".tmp")
    result.save(tmp)
    tmp.replace(path)
    checkpoint.unlink(missing_ok=True)
    return result
