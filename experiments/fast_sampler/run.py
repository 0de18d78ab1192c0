"""Candidate fast samplers of the paper's ensemble, scored against the reference anneals.

  python experiments/fast_sampler/run.py --moulds 468 302 143 557 27 128 553 392 \
      --methods quench window:1000:0.02:1e-4 --reference 1e5 --out fidelity.csv

Methods (each from the lattice with the orientations of `simulate`, seeds = the dataset's
replica seeds of the mould, then L-BFGS to the dataset's tolerance):
  quench                   L-BFGS alone (the dataset's solver until now)
  anneal:B                 the paper's schedule (T_INIT to T_INIT / 1e7) over B moves a cell
  window:B:Thi:Tlo         an exponential anneal over B moves a cell from Thi to Tlo
  relax:Thi:Tlo:S:W:R      condor.model.anneal.relaxed_anneal: S segments of W sweeps from Thi to
                           Tlo, each followed by R evaluations of L-BFGS on the positions
  relax:Thi:Tlo:S:W:R:F    the same, the final L-BFGS to a largest residual force F (kappa0 l0)
                           instead of the dataset's tolerance
  relax:Thi:Tlo:S:W:R0-R1  R ramped linearly from R0 (the first segment) to R1 (the last)
  relax:Thi:Tlo:S:W:F+R    F evaluations after the first segment, R after each other one
  relax:Thi:Tlo:S:W:F+R,Q  the same, Q after each other one in a mould without posts
Runs are cached (fields, energy, evaluations) under --cache; the reference runs are read from
the paper-reference cache (experiments/paper_reference/run.py).
"""

from __future__ import annotations

import argparse
import os
import sys
import time
from pathlib import Path

os.environ.setdefault("OPENBLAS_NUM_THREADS", "1")
os.environ.setdefault("NUMBA_NUM_THREADS", "1")

import numpy as np  # noqa: E402
import pandas as pd  # noqa: E402

from condor.files import write_text  # noqa: E402
from condor.model import anneal as anneal_mod  # noqa: E402
from condor.model.energy import random_orientations  # noqa: E402
from condor.model.lattice import build_lattice  # noqa: E402
from condor.measures.estimators import pad_replicas  # noqa: E402
from condor.model.scenes import get_scene  # noqa: E402
from condor.data.seeds import replica_seed  # noqa: E402
from condor.model.simulate import SimResult, simulate_lattice, warm_up  # noqa: E402
from condor.studies.fidelity import fidelity_row  # noqa: E402
from condor.studies.paper_reference import (budget_tag, mould_of, reference_rung_from,  # noqa: E402
                                           rung_by_run, scene_fields)

CACHE = Path.home() / ".cache" / "condor" / "fast_sampler"
# the paper scene's 1e5 runs of moulds whose 1e6 rung is complete, out of the product files
RUNGS_MOVED = Path(__file__).resolve().parents[1] / "paper_reference" / "rung_1e5"



def run_method(spec: str, scene, mould, seed: int) -> SimResult:
    lattice = build_lattice(mould.polygon, mould.tethers, scene.depth)
    ori = random_orientations(lattice.n_cells, np.random.default_rng([seed, 1]))
    pos = lattice.positions
    kind, *args = spec.split(":")
    ftol = None  # the dataset's tolerance
    anneal_info, t0 = {}, time.process_time()
    if kind in ("anneal", "window"):
        budget = float(args[0])
        t_hi, t_lo = ((anneal_mod.T_INIT, anneal_mod.T_INIT / anneal_mod.T_RATIO)
                      if kind == "anneal" else (float(args[1]), float(args[2])))
        pos, ori, anneal_info = anneal_mod.anneal(lattice, pos, ori, budget, [seed, 2],
                                                  t_init=t_hi, t_ratio=t_hi / t_lo)
    elif kind == "relax":
        t_hi, t_lo, segments, sweeps = float(args[0]), float(args[1]), int(args[2]), int(args[3])
        if "+" in args[4]:  # F+R: F evaluations after the first segment, R after the others
            first, rest = args[4].split("+")  # F+R,Q: Q after the others without posts
            rest, _, free = rest.partition(",")
            later = int(free) if free and not lattice.fixed.any() else int(rest)
            relax = np.array([int(first)] + [later] * (segments - 1))
        else:  # R, or R0-R1: a linear ramp over the segments
            first, _, last = args[4].partition("-")
            relax = np.rint(np.linspace(int(first), int(last or first), segments)).astype(int)
        ftol = float(args[5]) if len(args) > 5 else None
        pos, ori, anneal_info = anneal_mod.relaxed_anneal(lattice, pos, ori, [seed, 2], t_hi,
                                                          t_lo, segments, sweeps, relax)
    elif kind != "quench":
        raise ValueError(f"unknown method {spec!r}")
    anneal_seconds = time.process_time() - t0
    result = simulate_lattice(lattice, pos, ori, "lbfgs", seed=seed, ftol=ftol)
    result.seconds += anneal_seconds
    result.info["evaluations"] += anneal_info.get("anneal_evaluations", 0.0)
    result.info.update(anneal_info)
    return result


def cached(cache: Path, spec: str, scene, mould, k: int, seed: int, fresh: bool = False):
    path = cache / f"{scene.name}_s{mould.seed}" / spec.replace(":", "_") / f"m{mould.mould_id}_r{k}.npz"
    if path.exists():
        with np.load(path) as d:
            return d["fields"], float(d["energy"]), float(d["evaluations"]), str(d["status"])
    r = run_method(spec, scene, mould, seed)
    f = scene_fields(r, scene).astype(np.float32)
    path.parent.mkdir(parents=True, exist_ok=True)
    tmp = path.with_name(path.name + ".tmp.npz")
    np.savez(tmp, fields=f, energy=r.energy_per_cell, evaluations=r.info["evaluations"],
             status=r.status, seconds=r.seconds)
    tmp.replace(path)
    return f, r.energy_per_cell, r.info["evaluations"], r.status


def main(argv=None) -> int:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--scene", default="default")
    ap.add_argument("--seed", type=int, default=2026)
    ap.add_argument("--moulds", type=int, nargs="+", required=True)
    ap.add_argument("--methods", nargs="+", required=True)
    ap.add_argument("--seeds", type=int, default=4, help="replicas of each method")
    ap.add_argument("--reference", type=float, nargs="+", default=[1e5],
                    help="reference rungs (moves per cell)")
    ap.add_argument("--cache", type=Path, default=CACHE)
    ap.add_argument("--reference-folder", type=Path, default=None,
                    help="read the reference runs from this folder (paper_reference/run.py "
                         "--product) instead of the shipped product")
    ap.add_argument("--out", type=Path)
    ap.add_argument("--moved-folder", type=Path, default=RUNGS_MOVED,
                    help="where a rung moved out of the product lies (read for a mould whose "
                         "product file lacks it)")
    ap.add_argument("--more-runs", type=Path, nargs="+", default=[], metavar="FOLDER",
                    help="add a rung's runs packed in these folders to the reference's, by run "
                         "number (experiments/paper_reference/more_runs_*: runs beyond the "
                         "shipped three)")
    ap.add_argument("--z-symmetric", action="store_true",
                    help="score the ensembles symmetrised under z -> depth - z, the tilt "
                         "fields' noise left out (studies.fidelity, docs/model.md)")
    ap.add_argument("--min-moulds", type=int, default=2,
                    help="score against a rung only when this many moulds have 2 runs of it "
                         "(1: a single mould's figures, without an interval over moulds)")
    a = ap.parse_args(argv)
    scene = get_scene(a.scene)
    warm_up()
    moulds = [mould_of(scene, a.seed, m) for m in a.moulds]
    refs = {}
    for budget in a.reference:
        folders = (a.reference_folder, a.moved_folder)
        if a.more_runs:  # every run of the rung, wherever it is packed
            runs = [list(rung_by_run(scene, a.seed, m, budget, (*folders, *a.more_runs)).values())
                    for m in a.moulds]
            f, e = [[x[0] for x in r] for r in runs], [[x[1] for x in r] for r in runs]
        else:
            f, e = map(list, zip(*(reference_rung_from(scene, a.seed, m, budget, folders)
                                   for m in a.moulds)))
        keep = [i for i, x in enumerate(f) if len(x) >= 2]
        refs[budget] = (keep, f, e)
        print(f"reference anneal {budget_tag(budget)}: {len(keep)} moulds with >= 2 runs ("
              + ", ".join(f"{m}: {len(x)}" for m, x in zip(a.moulds, f)) + ")", flush=True)
    rows = []
    for spec in a.methods:
        fields, energy, evals = [], [], []
        for mould in moulds:
            fm, em, vm = [], [], []
            for k in range(a.seeds):
                f, e, v, status = cached(a.cache, spec, scene, mould, k,
                                         replica_seed(a.seed, mould.mould_id, k))
                if status == "ok":
                    fm.append(f)
                    em.append(e)
                    vm.append(v)
            fields.append(fm)
            energy.append(em)
            evals.append(vm)
        for budget, (keep, rf, re) in refs.items():
            if len(keep) < a.min_moulds:
                continue
            row = fidelity_row(spec, scene.name, f"anneal {budget_tag(budget)}",
                               pad_replicas([fields[i] for i in keep]),
                               pad_replicas([rf[i] for i in keep]),
                               evaluations=pad_replicas([evals[i] for i in keep]),
                               energy=pad_replicas([energy[i] for i in keep]),
                               ref_energy=pad_replicas([re[i] for i in keep]),
                               z_symmetric=a.z_symmetric)
            rows.append(row)
            print(" ".join(f"{k}={v:.4g}" if isinstance(v, float) else f"{k}={v}"
                           for k, v in row.items()), flush=True)
    if a.out:
        write_text(a.out, pd.DataFrame(rows).to_csv(index=False, float_format="%.5g"))
    return 0


if __name__ == "__main__":
    sys.exit(main())
