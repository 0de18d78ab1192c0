"""The dataset's solver on the moulds labs cast: each lab family's mould against its own
reference anneals (experiments/held_out_fidelity/README.md, "Lab moulds").

One mould of each family named (FAMILY:ID, drawn by condor.moulds.sources.make_mould at
--seed, an unused dataset seed), each run --runs times by the long anneal the paper reference
uses (condor.studies.recipes.anneal_then_relax at --budget moves a cell, study seeds), and
--seeds times by each solver of --solvers at its default budget (the dataset's replica seeds);
every run cached under --cache, in --workers processes, and scored as docs/data/fidelity.csv
is (condor.studies.fidelity.fidelity_row): pooled, and mould by mould.

    python experiments/held_out_fidelity/lab.py --scene default --moulds strip:0 dogbone:1 \\
        ring:2 annulus:3 polygon:4 cross:5 spline:6 frame:7 side_anchored:8 oval:9 --out CSV
"""

from __future__ import annotations

import argparse
import sys
import time
from concurrent.futures import ProcessPoolExecutor
from pathlib import Path

import numpy as np
import pandas as pd

from condor.data.seeds import replica_seed, study_seed
from condor.files import write_text
from condor.measures.estimators import pad_replicas
from condor.model.scenes import get_scene
from condor.model.simulate import default_budget, simulate, warm_up
from condor.moulds.sources import make_mould
from condor.studies.fidelity import fidelity_row
from condor.studies.paper_reference import budget_tag, scene_fields
from condor.studies.recipes import anneal_then_relax

CACHE = Path.home() / ".cache" / "condor" / "lab_fidelity"


def parse_mould(token: str) -> tuple[str, int]:
    family, _, mould_id = token.partition(":")
    if not mould_id.isdigit():
        raise SystemExit(f"--moulds {token!r}: write FAMILY:ID, e.g. strip:0")
    return family, int(mould_id)


def one_run(job) -> tuple[str, str]:
    """Run (or find) one job: (kind, scene name, seed, family, id, k, solver or budget, cache
    folder) -> (its file, its status)."""
    kind, scene_name, seed, family, mould_id, k, what, cache = job
    path = Path(cache) / f"{scene_name}_s{seed}" / f"{family}_m{mould_id}" / f"{kind}_{what}_r{k}.npz"
    if path.exists():
        return str(path), "cached"
    scene = get_scene(scene_name)
    mould = make_mould(scene, seed, mould_id, family)
    t0 = time.process_time()
    if kind == "reference":
        result = anneal_then_relax(mould, scene.depth, float(what),
                                   study_seed(seed, mould_id, k))
    else:
        result = simulate(mould.polygon, mould.tethers, scene.depth, what,
                          default_budget(what, scene.box), replica_seed(seed, mould_id, k))
    path.parent.mkdir(parents=True, exist_ok=True)
    tmp = path.with_name(path.stem + ".tmp.npz")
    np.savez(tmp, fields=scene_fields(result, scene).astype(np.float32),
             energy=result.energy_per_cell, evaluations=result.info["evaluations"],
             status=result.status, seconds=time.process_time() - t0)
    tmp.replace(path)
    return str(path), result.status


def load(path: str):
    with np.load(path) as d:
        return d["fields"], float(d["energy"]), float(d["evaluations"]), str(d["status"])


def main(argv=None) -> int:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--scene", default="default")
    ap.add_argument("--seed", type=int, default=2031, help="the moulds' dataset seed")
    ap.add_argument("--moulds", nargs="+", required=True, help="FAMILY:ID of each mould")
    ap.add_argument("--budget", type=float, default=1e5,
                    help="the reference anneal's moves a cell")
    ap.add_argument("--runs", type=int, default=3, help="reference runs a mould")
    ap.add_argument("--solvers", nargs="+", default=["relaxed_anneal", "lbfgs"])
    ap.add_argument("--seeds", type=int, default=4, help="runs of each solver a mould")
    ap.add_argument("--workers", type=int, default=2)
    ap.add_argument("--cache", type=Path, default=CACHE)
    ap.add_argument("--out", type=Path, default=None, help="CSV: pooled rows, then mould rows")
    a = ap.parse_args(argv)
    moulds = [parse_mould(t) for t in a.moulds]
    warm_up()
    jobs = [("reference", a.scene, a.seed, f, m, k, f"{a.budget:g}", str(a.cache))
            for k in range(a.runs) for f, m in moulds]
    jobs += [("solver", a.scene, a.seed, f, m, k, s, str(a.cache))
             for s in a.solvers for f, m in moulds for k in range(a.seeds)]
    paths, t0 = {}, time.time()
    with ProcessPoolExecutor(a.workers) as pool:
        for n, (job, (path, status)) in enumerate(zip(jobs, pool.map(one_run, jobs)), 1):
            paths[job[:7]] = path
            print(f"{time.time() - t0:7.0f} s  {n}/{len(jobs)}  {job[0]} {job[3]}:{job[4]} "
                  f"{job[6]} run {job[5]}: {status}", flush=True)
    ref = {(f, m): [load(paths[("reference", a.scene, a.seed, f, m, k, f"{a.budget:g}")])
                    for k in range(a.runs)] for f, m in moulds}
    label = f"anneal {budget_tag(a.budget)}"
    rows = []
    for solver in a.solvers:
        got = {(f, m): [load(paths[("solver", a.scene, a.seed, f, m, k, solver)])
                        for k in range(a.seeds)] for f, m in moulds}

        def row(keys, mould="all"):
            mine = [[r for r in got[key] if r[3] == "ok"] for key in keys]
            theirs = [[r for r in ref[key] if r[3] == "ok"] for key in keys]
            out = fidelity_row(solver, a.scene, label,
                               pad_replicas([[r[0] for r in runs] for runs in mine]),
                               pad_replicas([[r[0] for r in runs] for runs in theirs]),
                               evaluations=pad_replicas([[r[2] for r in runs] for runs in mine]),
                               energy=pad_replicas([[r[1] for r in runs] for runs in mine]),
                               ref_energy=pad_replicas([[r[1] for r in runs] for runs in theirs]))
            return {"mould": mould, **out}

        rows.append(row(list(got)))
        rows += [row([key], f"{key[0]}:{key[1]}") for key in got]
    table = pd.DataFrame(rows)
    cols = ["mould", "method", "distance", "distance_lo", "distance_hi", "replica_noise",
            "evaluations_per_mould", "sz2_difference", "energy_difference_pct"]
    print(table[cols].round(4).to_string(index=False))
    if a.out:
        write_text(a.out, table.to_csv(index=False, float_format="%.5g"))
    return 0


if __name__ == "__main__":
    sys.exit(main())
