"""The dataset's sampler on the moulds labs cast, against long anneals of the same moulds.

Issue 45 asks for the sampler to be checked on lab-style moulds too (holes, 1-3 posts, thin
arms), not only the paper generator's. This study anneals chosen moulds of `condor.moulds.lab`
with the paper's schedule at each rung (`condor.studies.recipes.anneal_then_relax`, as the
paper reference does), runs the product's solver at its default budget (`simulate`) and the
quench, and scores each against each rung (`condor.studies.fidelity.fidelity_row`: the
noise-corrected distance, over the moulds with a bootstrap interval, and mould by mould).

    python experiments/sampler_lab_moulds/run.py --rungs 1e4 1e5 --runs 3 --seeds 16 \
        --out experiments/sampler_lab_moulds/default_1e5.csv

Every run is cached under --cache (one .npz of normalised fields, energy and evaluations); a
long anneal keeps a checkpoint there and resumes it, so the study can be stopped and started
again (`--only-references` runs the anneals alone, for a background job). Seeds: the
reference runs' are `study_seed(seed, key, REFERENCE_RUN + k)` at every rung (so two rungs
are scored run k against run k: `estimators.paired_distance`), the solvers' the dataset's
`replica_seed(seed, key, k)`, key = LAB_KEY x (family's index + 1) + mould id.
"""

from __future__ import annotations

import argparse
import os
import sys
from pathlib import Path

os.environ.setdefault("OPENBLAS_NUM_THREADS", "1")
os.environ.setdefault("NUMBA_NUM_THREADS", "1")

import numpy as np  # noqa: E402
import pandas as pd  # noqa: E402

from condor.data.seeds import replica_seed, study_seed  # noqa: E402
from condor.files import write_text  # noqa: E402
from condor.measures.estimators import pad_replicas  # noqa: E402
from condor.model.scenes import get_scene  # noqa: E402
from condor.model.simulate import simulate, warm_up  # noqa: E402
from condor.moulds.lab import FAMILY_NAMES, lab_mould  # noqa: E402
from condor.studies.fidelity import fidelity_row  # noqa: E402
from condor.studies.paper_reference import REFERENCE_RUN, budget_tag, scene_fields  # noqa: E402
from condor.studies.recipes import anneal_then_relax  # noqa: E402

HERE = Path(__file__).resolve().parent
CACHE = HERE / "cache"
LAB_KEY = 100_000
# one mould of each kind the issue names: two posts (strip, dog-bone), one post (a ring round
# its centre post), holes (an annulus on 3 posts, a frame with a hole), thin arms (a cross)
MOULDS = ("strip:0", "dogbone:0", "ring:2", "annulus:0", "cross:0", "frame:2")
METHODS = {"product": None, "quench": "lbfgs"}  # name -> simulate's solver (None: the default)


def parse_mould(text: str) -> tuple[str, int]:
    family, _, mould_id = text.partition(":")
    if family not in FAMILY_NAMES or not mould_id.isdigit():
        raise SystemExit(f"--moulds: {text!r} is not FAMILY:ID with FAMILY one of {FAMILY_NAMES}")
    return family, int(mould_id)


def key_of(family: str, mould_id: int) -> int:
    return LAB_KEY * (FAMILY_NAMES.index(family) + 1) + mould_id


def cached_run(path: Path, run):
    """(normalised fields, energy per cell, evaluations) of a run: from `path`, else run() and
    saved there whole (a failed run raises: the study has no use for it)."""
    if path.exists():
        with np.load(path) as d:
            return d["fields"], float(d["energy"]), float(d["evaluations"])
    fields, result = run()
    if result.status != "ok":
        raise RuntimeError(f"{path.name}: the run failed ({result.status})")
    path.parent.mkdir(parents=True, exist_ok=True)
    tmp = path.with_name(path.name + ".tmp.npz")
    np.savez(tmp, fields=fields.astype(np.float32), energy=result.energy_per_cell,
             evaluations=result.info["evaluations"], seconds=result.seconds)
    tmp.replace(path)
    return fields, result.energy_per_cell, result.info["evaluations"]


def main(argv=None) -> int:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--scene", default="default")
    ap.add_argument("--seed", type=int, default=2026, help="the lab moulds' dataset seed")
    ap.add_argument("--moulds", nargs="+", default=list(MOULDS), help="FAMILY:ID ...")
    ap.add_argument("--rungs", type=float, nargs="+", default=[1e4, 1e5],
                    help="the reference anneals' moves per cell")
    ap.add_argument("--runs", type=int, default=3, help="reference anneals a rung and mould")
    ap.add_argument("--seeds", type=int, default=16, help="runs of each solver a mould")
    ap.add_argument("--cache", type=Path, default=CACHE)
    ap.add_argument("--only-references", action="store_true",
                    help="run (or resume) the reference anneals and stop")
    ap.add_argument("--z-symmetric", action="store_true",
                    help="score over the six fields even under z -> depth - z, the tilt fields' "
                         "noise left out (condor.studies.fidelity)")
    ap.add_argument("--out", type=Path, help="the table (CSV)")
    a = ap.parse_args(argv)
    scene = get_scene(a.scene)
    warm_up()
    moulds = [parse_mould(m) for m in a.moulds]
    folder = a.cache / f"{scene.name}_s{a.seed}"

    def log(line):
        print(line, flush=True)

    refs = {}  # rung -> (fields, energies) per mould
    for budget in a.rungs:
        fields, energy = [], []
        for family, i in moulds:
            mould, key = lab_mould(a.seed, i, family, scene), key_of(family, i)
            fm, em = [], []
            for k in range(a.runs):
                path = folder / f"{family}{i}_anneal{budget_tag(budget)}_k{k}.npz"
                checkpoint = path.with_name(path.stem + ".checkpoint.npz")

                def run(mould=mould, key=key, k=k, checkpoint=checkpoint):
                    r = anneal_then_relax(mould, scene.depth, budget,
                                          study_seed(a.seed, key, REFERENCE_RUN + k),
                                          checkpoint=checkpoint, log=log)
                    checkpoint.unlink(missing_ok=True)
                    return scene_fields(r, scene), r

                f, e, _ = cached_run(path, run)
                log(f"{family}:{i} anneal {budget_tag(budget)} run {k}: E/cell {e:.6f}")
                fm.append(f)
                em.append(e)
            fields.append(fm)
            energy.append(em)
        refs[budget] = (pad_replicas(fields), pad_replicas(energy))
    if a.only_references:
        return 0
    rows = []
    ensembles = {f"anneal {budget_tag(b)}": (f, e, None) for b, (f, e) in refs.items()}
    for name, solver in METHODS.items():
        per_mould = []  # per mould, its runs' (fields, energy, evaluations)
        for family, i in moulds:
            mould, key = lab_mould(a.seed, i, family, scene), key_of(family, i)

            def run(k, mould=mould, key=key):
                r = simulate(mould.polygon, mould.tethers, scene.depth, solver,
                             seed=replica_seed(a.seed, key, k))
                return scene_fields(r, scene), r

            per_mould.append([cached_run(folder / name / f"{family}{i}_r{k}.npz",
                                         lambda k=k, run=run: run(k))
                              for k in range(a.seeds)])
        ensembles[name] = tuple(pad_replicas([[r[j] for r in runs] for runs in per_mould])
                                for j in range(3))
    names = list(ensembles)
    for reference in (n for n in names if n.startswith("anneal")):
        rf, re, _ = ensembles[reference]
        for name in names[names.index(reference) + 1:]:
            f, e, v = ensembles[name]
            for m, (family, i) in [(None, (None, None))] + list(enumerate(moulds)):
                pick = slice(None) if m is None else slice(m, m + 1)
                row = fidelity_row(name, scene.name, reference, f[pick], rf[pick],
                                   evaluations=None if v is None else v[pick],
                                   energy=e[pick], ref_energy=re[pick],
                                   paired=v is None,  # two rungs: run k shares its seed
                                   z_symmetric=a.z_symmetric)
                row["moulds"] = " ".join(a.moulds) if m is None else f"{family}:{i}"
                rows.append(row)
                log(f"{name} against {reference} on {row['moulds']}: distance "
                    f"{row['distance']:.3f} [{row['distance_lo']:.3f}, {row['distance_hi']:.3f}]"
                    f" / scatter {row['replica_noise']:.3f} = "
                    f"{row['distance_hi'] / row['replica_noise']:.2f}x at the upper end; "
                    f"E/cell {row['energy_difference_pct']:+.2f}%")
    if a.out:
        write_text(a.out, pd.DataFrame(rows).to_csv(index=False, float_format="%.5g"))
    return 0


if __name__ == "__main__":
    sys.exit(main())
