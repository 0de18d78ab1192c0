"""The product's answer on the held-out families: the leave-one-kind-out models' predictions
checked by simulation as `condor predict` checks a mould at the default scene, and combined
with the simulations into its best estimate (condor.stages.check: the same seeds, solver and
weights), scored as generalisation.csv scores the surrogate alone (issue 41).

    python experiments/generalisation/checked.py --pool POOL --cache CACHE \\
        --models 'without_*_n500_extra0.2_noise_weight1_e120_*' --out DIR

For every test mould of the pool (its paper and lab test sets) the check's N simulations
(`--checks`, default condor.stages.check.AUTO_CHECK) are run once and cached in --sims; the
truth is the pool's own replicas (other seeds). For each model of run.py's cache matching
--models (its cached predictions of the test sets), three answers are scored family by family
(condor.studies.families): the surrogate alone, the mean of the N simulations alone, and the
best estimate of the two. Writes checked.csv (`answer` and generalisation.csv's columns; the
held-out families' rows and the paper test moulds') and checked_moulds.csv (per model, answer
and mould: squared error, noise, mean tension ratio).
"""

from __future__ import annotations

import argparse
import os
import runpy
import sys
import time
from pathlib import Path

os.environ.setdefault("OPENBLAS_NUM_THREADS", "1")

import numpy as np  # noqa: E402
import pandas as pd  # noqa: E402

from condor.data.dataset import mould_geometry  # noqa: E402
from condor.data.fields import cell_fields, normalise  # noqa: E402
from condor.data.seeds import replica_seed  # noqa: E402
from condor.data.store import open_store  # noqa: E402
from condor.files import atomic_path, write_text  # noqa: E402
from condor.measures.metrics import normalise_predicted  # noqa: E402
from condor.model.scenes import Scene  # noqa: E402
from condor.model.simulate import DEFAULT_SOLVER  # noqa: E402
from condor.moulds.mould import PAPER, Mould  # noqa: E402
from condor.stages.build import default_budget, simulate_mould  # noqa: E402
from condor.stages.check import AUTO_CHECK, CHECK_SEED, best_estimate  # noqa: E402
from condor.studies.families import family_rows  # noqa: E402
from condor.studies.recipes import reference_ensemble  # noqa: E402

HERE = Path(__file__).resolve().parent
RUN = runpy.run_path(str(HERE / "run.py"))  # the study's pool, kinds and per-mould scoring
ANSWERS = ("surrogate", "simulations", "best estimate")


def log(line: str) -> None:
    print(f"{time.strftime('%H:%M:%S')} {line}", flush=True)


def check_simulations(ds, scene: Scene, mould_id: int, n: int, cache: Path) -> np.ndarray:
    """(n, 8, H, W) normalised fields of `n` simulations of the pool's mould `mould_id`, with
    the seeds and solver of `condor predict`'s check (cached in `cache`)."""
    path = cache / f"m{mould_id}_check{n}.npy"
    if path.exists():
        return np.load(path)
    polygon, tethers = mould_geometry(ds, int(mould_id))
    mould = Mould(box=scene.box, polygon=polygon, tethers=tethers)
    fields = []
    for k in range(n):
        result = simulate_mould(mould, scene, None, None, replica_seed(CHECK_SEED, 0, k))
        if result.status != "ok":
            raise RuntimeError(f"mould {mould_id}, check simulation {k}: {result.status}")
        raw = cell_fields(result.positions, result.orientations, result.tension, scene.box,
                          scene.pixels, scene.sigma)
        fields.append(normalise(raw, len(result.positions)))
    out = np.stack(fields).astype(np.float32)
    with atomic_path(path) as tmp, open(tmp, "wb") as handle:  # whole or not at all
        np.save(handle, out)
    return out


def answers(predicted_raw: np.ndarray, checks: np.ndarray) -> dict[str, np.ndarray]:
    """Each answer's normalised fields (M, 8, H, W): the surrogate's, the check simulations'
    mean, and the best estimate of the two (condor.stages.check.best_estimate)."""
    predicted = normalise_predicted(np.asarray(predicted_raw)).astype(np.float64)
    best = np.stack([best_estimate(p, c)[0] for p, c in zip(predicted, checks)])
    return {"surrogate": predicted, "simulations": checks.astype(np.float64).mean(axis=1),
            "best estimate": best}


def held_out_of(name: str) -> str | None:
    """The kind a leave-one-kind-out model's name says it held out (run.py's KINDS)."""
    for kind in RUN["KINDS"]:
        if name.startswith(f"without_{'_'.join(kind)}_"):
            return "+".join(kind)
    return None


def main(argv=None) -> int:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--pool", type=Path, required=True, help="the pool's dataset.zarr")
    ap.add_argument("--cache", type=Path, required=True, help="run.py's --cache")
    ap.add_argument("--models", required=True,
                    help="a glob of the models' checkpoint names in --cache (without .pt)")
    ap.add_argument("--checks", type=int, default=AUTO_CHECK)
    ap.add_argument("--sims", type=Path, default=Path.home() / ".cache/condor/checked",
                    help="where the check simulations are cached")
    ap.add_argument("--out", type=Path, default=HERE)
    ap.add_argument("--seed", type=int, default=2026, help="the bootstrap's seed")
    a = ap.parse_args(argv)
    ds = open_store(a.pool)
    if ds.attrs.get("solver") != DEFAULT_SOLVER:
        ap.error(f"{a.pool}: its solver is {ds.attrs.get('solver')!r}, the check's "
                 f"{DEFAULT_SOLVER!r}: the truth and the check would differ in kind")
    scene = Scene(**ds.attrs["scene"])
    budget = default_budget(DEFAULT_SOLVER, scene.box)
    if ds.attrs.get("solver_budget") not in (None, budget):
        ap.error(f"{a.pool}: its solver budget {ds.attrs['solver_budget']!r} is not the "
                 f"check's {budget!r}")
    fam = RUN["families_of"](ds)
    test = RUN["first_replicas"](ds, "test")
    groups = {"paper": [int(i) for i in test if fam[i] == PAPER],
              "lab": [int(i) for i in test if fam[i] != PAPER]}
    ensembles = {g: reference_ensemble(ds, ids) for g, ids in groups.items()}
    labels = {"paper": [PAPER] * len(ensembles["paper"].moulds),
              "lab": [str(fam[int(m)]) for m in ensembles["lab"].moulds]}
    a.sims.mkdir(parents=True, exist_ok=True)
    checks = {}
    for g, ensemble in ensembles.items():
        start = time.process_time()
        checks[g] = np.stack([check_simulations(ds, scene, m, a.checks, a.sims)
                              for m in ensemble.moulds])
        log(f"{g}: {len(ensemble.moulds)} moulds x {a.checks} check simulations "
            f"({time.process_time() - start:.0f} CPU s)")
    checkpoints = sorted(a.cache.glob(a.models + ".pt"))
    if not checkpoints:
        ap.error(f"no checkpoint {a.models}.pt in {a.cache}")
    rows, moulds = [], []
    for checkpoint in checkpoints:
        kind = held_out_of(checkpoint.stem)
        if kind is None:
            continue
        for g, ensemble in ensembles.items():
            raw = np.load(a.cache / f"{checkpoint.stem}_{g}.npy")
            for answer, fields in answers(raw, checks[g]).items():
                table = family_rows(ensemble, fields, labels[g], seed=a.seed)
                keep = table["family"].isin(kind.split("+") + [PAPER])
                rows.append(table[keep].assign(answer=answer, held_out=kind))
                moulds.append(RUN["per_mould"](ensemble, fields, labels[g]).assign(
                    answer=answer, held_out=kind))
        log(f"scored {checkpoint.stem}")
    columns = ["answer", "family", "held_out", "n_moulds", "replicas", "error", "error_lo",
               "error_hi", "noise_ceiling", "tension_bias", "tension_bias_lo",
               "tension_bias_hi"]
    a.out.mkdir(parents=True, exist_ok=True)
    write_text(a.out / "checked.csv", pd.concat(rows, ignore_index=True)[columns].to_csv(index=False))
    write_text(a.out / "checked_moulds.csv", pd.concat(moulds, ignore_index=True).to_csv(index=False))
    return 0


if __name__ == "__main__":
    sys.exit(main())
