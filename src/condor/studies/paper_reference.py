"""The paper's CONDOR as a reference ensemble: long anneals of test moulds, run resumably.

A reference run is `recipes.anneal_then_relax` (the paper's anneal of `budget` moves per
cell, then L-BFGS to a tight force) of one mould with one seed. Its seed is the study stream
`study_seed(dataset_seed, mould, REFERENCE_RUN + k)` for run k, shared by every budget (run k of
each rung starts from the same orientations) and used by no replica of the dataset.

`run_reference` keeps each finished run as a SimResult file under the cache folder, and the
anneal's checkpoint beside it while it runs: a killed ladder loses at most
`condor.model.anneal.CHECKPOINT_SECONDS` of work and resumes bit-identically.
"""

from __future__ import annotations

import fcntl
import json
from collections import Counter
from dataclasses import dataclass
from pathlib import Path

import numpy as np

from condor.data.fields import cell_fields, normalise
from condor.moulds.paper import generate_mould
from condor.model.scenes import Scene
from condor.data.seeds import study_seed
from condor.model.simulate import SimResult
from condor.studies.recipes import anneal_then_relax

REFERENCE_RUN = 5000  # study-stream offset of the reference runs (`condor.data.seeds.study_seed`)


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
    """The dataset's mould `mould_id` in `scene` (as condor.stages.build.make_mould)."""
    return generate_mould(dataset_seed, mould_id, scene)


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


def scene_fields(state, scene: Scene) -> np.ndarray:
    """Normalised fields (8, H, W) at the scene's grid of any state with positions,
    orientations and tension (a SimResult or a ReferenceRun)."""
    return normalise(cell_fields(state.positions, state.orientations, state.tension, scene.box,
                                 scene.pixels, scene.sigma), len(state.positions))


# --- the shipped data product ---------------------------------------------------------------
# One .npz per (scene, dataset seed, mould) under REFERENCE_DIR, holding every finished run of
# every rung packed: positions and orientations quantised to int16 (POS_QUANTUM l0, 1/32767),
# tensions as float16, energies per cell and CPU seconds as float64, and the provenance (the
# anneal kernel, the code commit, the seeds) as JSON. Fields are recomputed from the states
# at any grid, so the product scores a solver at whatever resolution its store holds.

REFERENCE_DIR = Path(__file__).resolve().parent.parent / "paper_reference"
POS_QUANTUM = 2.0e-3  # l0: positions up to 65 l0 fit an int16; 1e-3 l0 RMS is far below sigma
_ORI_SCALE = 32767.0


def reference_file(scene_name: str, dataset_seed: int, mould_id: int, folder=None) -> Path:
    return Path(folder or REFERENCE_DIR) / f"{scene_name}_s{dataset_seed}_m{mould_id}.npz"


def run_provenance(made_by: str) -> dict:
    """What a packed run records of the code that made it: the anneal kernel, the git commit
    of this checkout ('' outside one) and the script."""
    import subprocess

    from condor.model.anneal import KERNEL
    commit = subprocess.run(["git", "rev-parse", "HEAD"], capture_output=True, text=True,
                            cwd=Path(__file__).resolve().parent).stdout.strip()
    return {"kernel": KERNEL, "commit": commit, "made_by": made_by}


def shipped_runs(scene_name: str, dataset_seed: int, mould_id: int, folder=None) -> set[str]:
    """The keys (e.g. "anneal1e6_k0") of the runs the reference file holds with status ok:
    runs that need no rerun when the cache that made them is gone."""
    path = reference_file(scene_name, dataset_seed, mould_id, folder)
    if not path.exists():
        return set()
    with np.load(path, allow_pickle=False) as data:
        return {r["key"] for r in json.loads(str(data["meta"]))["runs"] if r["status"] == "ok"}


def pack_mould(cache, scene: Scene, dataset_seed: int, mould_id: int, budgets, runs: int,
               provenance: dict, folder=None) -> Path | None:
    """Add the finished runs 0..runs-1 of `mould_id` at `budgets` in the run cache (each with
    its seed, and `provenance`) to its reference file, keeping every run it already holds that
    the cache lacks: the product, not the cache, is the ladder's record, so a lost cache loses
    no shipped run. None when neither holds a run. Writers of one file take turns (a lock
    file), and the file is replaced atomically."""
    out = reference_file(scene.name, dataset_seed, mould_id, folder)
    out.parent.mkdir(parents=True, exist_ok=True)
    with open(out.with_name(out.name + ".lock"), "w") as lock:
        fcntl.flock(lock, fcntl.LOCK_EX)
        runs_meta, arrays = {}, {}
        if out.exists():
            with np.load(out, allow_pickle=False) as data:
                old = json.loads(str(data["meta"]))
                shared = {k: v for k, v in old.items()  # provenance a file once kept file-wide
                          if k not in ("scene", "dataset_seed", "mould", "runs")}
                for r in old["runs"]:
                    runs_meta[r["key"]] = {**shared, **r}
                arrays = {name: data[name] for name in data.files if name != "meta"}
        for budget in budgets:
            for k in range(runs):
                path = run_path(cache, scene, dataset_seed, mould_id, budget, k)
                if not path.exists():
                    continue
                r = SimResult.load(path)
                key = f"anneal{budget_tag(budget)}_k{k}"
                runs_meta[key] = {"key": key, "budget": float(budget), "run": k,
                                  "seed": int(r.seed), "status": r.status,
                                  "energy_per_cell": r.energy_per_cell, "cpu_seconds": r.seconds,
                                  "evaluations": r.info.get("evaluations"),
                                  "max_force": r.info.get("max_force"), **provenance}
                if r.status != "ok":  # a rerun that failed: no stale state of an earlier one
                    for part in ("pos", "ori", "tension"):
                        arrays.pop(f"{key}_{part}", None)
                    continue
                arrays[f"{key}_pos"] = np.round(r.positions / POS_QUANTUM).astype(np.int16)
                arrays[f"{key}_ori"] = np.round(r.orientations * _ORI_SCALE).astype(np.int16)
                arrays[f"{key}_tension"] = r.tension.astype(np.float16)
                arrays["fixed"] = r.fixed
        if not runs_meta:
            return None
        meta = {"scene": scene.to_dict(), "dataset_seed": int(dataset_seed),
                "mould": int(mould_id),
                "runs": sorted(runs_meta.values(), key=lambda r: (r["budget"], r["run"]))}
        tmp = out.with_name(out.name + ".tmp")  # not *.npz: reference_moulds globs those
        with open(tmp, "wb") as fh:
            np.savez_compressed(fh, meta=np.array(json.dumps(meta)), **arrays)
        tmp.replace(out)
    return out


@dataclass(frozen=True)
class ReferenceRun:
    budget: float
    run: int
    seed: int
    energy_per_cell: float
    positions: np.ndarray
    orientations: np.ndarray
    tension: np.ndarray
    fixed: np.ndarray

    def fields(self, scene: Scene) -> np.ndarray:
        """Normalised fields (8, H, W) at the scene's grid."""
        return scene_fields(self, scene)


def load_reference(scene_name: str, dataset_seed: int, mould_id: int, budget: float | None = None,
                   folder=None, min_runs: int = 1) -> list[ReferenceRun]:
    """The shipped ok runs of a mould at `budget` (None: its highest rung with at least
    `min_runs` runs; [] when no rung has so many); FileNotFoundError naming the file when the
    product holds no reference of that mould."""
    path = reference_file(scene_name, dataset_seed, mould_id, folder)
    if not path.exists():
        raise FileNotFoundError(f"no paper reference of {scene_name} mould {mould_id} (seed "
                                f"{dataset_seed}): {path} does not exist")
    with np.load(path, allow_pickle=False) as data:
        meta = json.loads(str(data["meta"]))
        ok = [r for r in meta["runs"] if r["status"] == "ok"]
        if budget is None:
            counts = Counter(r["budget"] for r in ok)
            rungs = [b for b, n in counts.items() if n >= min_runs]
            if not rungs:
                return []
            budget = max(rungs)
        out = []
        for r in ok:
            if r["budget"] != float(budget):
                continue
            key = r["key"]
            ori = data[f"{key}_ori"].astype(np.float64) / _ORI_SCALE
            out.append(ReferenceRun(
                budget=float(budget), run=int(r["run"]), seed=int(r["seed"]),
                energy_per_cell=float(r["energy_per_cell"]),
                positions=data[f"{key}_pos"].astype(np.float64) * POS_QUANTUM,
                orientations=ori / np.linalg.norm(ori, axis=1, keepdims=True),
                tension=data[f"{key}_tension"].astype(np.float64), fixed=data["fixed"]))
    return sorted(out, key=lambda run: run.run)


def reference_rung(scene: Scene, dataset_seed: int, mould_id: int, budget: float, folder=None):
    """The shipped ok runs of a mould's rung: (normalised fields at the scene's grid, energies
    per cell), lists of equal length; empty when the product holds none of that rung."""
    try:
        runs = load_reference(scene.name, dataset_seed, mould_id, budget, folder)
    except FileNotFoundError:
        return [], []
    return [r.fields(scene) for r in runs], [r.energy_per_cell for r in runs]


def reference_rung_from(scene: Scene, dataset_seed: int, mould_id: int, budget: float,
                        folders) -> tuple[list, list]:
    """reference_rung from the first of `folders` (None: the product) that holds at least 2
    runs of it (a rung moved out of the product lies in a study's folder), else the first's."""
    found = [reference_rung(scene, dataset_seed, mould_id, budget, f) for f in folders]
    return next((r for r in found if len(r[0]) >= 2), found[0])


def rung_by_run(scene: Scene, dataset_seed: int, mould_id: int, budget: float,
                folders) -> dict:
    """Every shipped ok run of a mould's rung across `folders` (None: the product), by run
    number: {run: (normalised fields, energy per cell)}, in run order. A run number held by
    two folders is read from the first (runs beyond the shipped three are packed in a study's
    folders: experiments/paper_reference/more_runs_*)."""
    runs = {}
    for folder in folders:
        try:
            shipped = load_reference(scene.name, dataset_seed, mould_id, budget, folder)
        except FileNotFoundError:
            continue
        for r in shipped:
            if r.run not in runs:
                runs[r.run] = (r.fields(scene), r.energy_per_cell)
    return dict(sorted(runs.items()))


def paired_rungs(scene: Scene, dataset_seed: int, mould_id: int, lower: float, upper: float,
                 folders):
    """Two rungs of a mould, each from the first of `folders` (None: the product) holding at
    least 2 runs of it, kept to the runs both hold, in run order: (lower's fields, upper's
    fields, lower's energies, upper's energies), lists of equal length whose k-th entries share
    their seed (`reference_seed` does not depend on the budget; estimators.paired_distance)."""
    def runs(budget):
        found = []
        for folder in folders:
            try:
                found.append(load_reference(scene.name, dataset_seed, mould_id, budget, folder))
            except FileNotFoundError:
                found.append([])
        return {r.run: r for r in next((f for f in found if len(f) >= 2), found[0])}

    low, high = runs(lower), runs(upper)
    common = sorted(set(low) & set(high))
    return ([low[k].fields(scene) for k in common], [high[k].fields(scene) for k in common],
            [low[k].energy_per_cell for k in common], [high[k].energy_per_cell for k in common])


def reference_moulds(scene_name: str, dataset_seed: int, folder=None) -> list[int]:
    """The moulds the product holds a reference of, in increasing id."""
    prefix = f"{scene_name}_s{dataset_seed}_m"
    return sorted(int(p.stem[len(prefix):]) for p in Path(folder or REFERENCE_DIR).glob(
        f"{prefix}*.npz"))
