"""Run the paper-reference ladder: long anneals of chosen test moulds, resumable, any number
of workers at once (each claims a run with a lock file), one thread each, niced.

  python experiments/paper_reference/run.py --scene default --moulds 468 302 27 128 553 143 \
      392 557 --rungs 1e5 1e6 --runs 3

Each finished run is added to the shipped product (src/condor/paper_reference/, tables.pack) at
once, and kept as a SimResult file in the cache; a running one keeps its anneal checkpoint
beside it, every 5 minutes (`condor.studies.paper_reference`). Kill a worker at any time;
start it again to resume; a run the product already holds is not run again. The cache defaults to experiments/paper_reference/cache/, whose
checkpoints are committed when a session ends, so that a ladder spans sessions and machines. The order is rung by rung; within a rung, run k of every mould before run k + 1
(--order run) or every run of a mould before the next mould (--order mould).
"""

from __future__ import annotations

import argparse
import os
import sys
import time
from pathlib import Path

os.environ.setdefault("OPENBLAS_NUM_THREADS", "1")
os.environ.setdefault("NUMBA_NUM_THREADS", "1")

from condor.model.scenes import get_scene  # noqa: E402
from condor.model.simulate import warm_up  # noqa: E402
from condor.studies.paper_reference import (  # noqa: E402
    budget_tag, pack_mould, run_path, run_provenance, run_reference, shipped_runs,
)

CACHE = Path(__file__).resolve().parent / "cache"


def claim(path: Path) -> bool:
    """Take run `path` (a lock file holding this pid); False when a live worker holds it."""
    lock = path.with_name(path.name + ".lock")
    for _ in range(2):
        try:
            fd = os.open(lock, os.O_CREAT | os.O_EXCL | os.O_WRONLY)
        except FileExistsError:
            try:
                os.kill(int(lock.read_text() or 0), 0)
                return False  # its worker lives
            except (ProcessLookupError, ValueError):
                lock.unlink(missing_ok=True)  # a dead worker's: take it over
                continue
        os.write(fd, str(os.getpid()).encode())
        os.close(fd)
        return True
    return False


def main(argv=None) -> int:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--scene", default="default")
    ap.add_argument("--seed", type=int, default=2026, help="the dataset's global seed")
    ap.add_argument("--moulds", type=int, nargs="+", required=True)
    ap.add_argument("--rungs", type=float, nargs="+", required=True, help="moves per cell")
    ap.add_argument("--runs", type=int, default=3, help="seeds per rung")
    ap.add_argument("--from-run", type=int, default=0,
                    help="run only runs K.. of each rung (their first runs done elsewhere, "
                         "such as a rung moved out of the product into rung_1e5/)")
    ap.add_argument("--order", choices=("run", "mould"), default="run",
                    help="within a rung: run k of every mould first, or every run of a mould")
    ap.add_argument("--cache", type=Path, default=CACHE)
    ap.add_argument("--product", type=Path, default=None,
                    help="pack finished runs into this folder instead of the shipped product "
                         "(src/condor/paper_reference): a study's own reference")
    a = ap.parse_args(argv)
    os.nice(10)
    scene = get_scene(a.scene)
    warm_up()
    provenance = run_provenance("experiments/paper_reference/run.py")  # the code it runs

    def log(line):
        print(f"{time.strftime('%H:%M:%S')} [{os.getpid()}] {line}", flush=True)

    for budget in a.rungs:
        runs = range(a.from_run, a.runs)
        pairs = ([(k, m) for k in runs for m in a.moulds] if a.order == "run"
                 else [(k, m) for m in a.moulds for k in runs])
        for k, mould in pairs:
            path = run_path(a.cache, scene, a.seed, mould, budget, k)
            path.parent.mkdir(parents=True, exist_ok=True)
            shipped = shipped_runs(scene.name, a.seed, mould, a.product)
            if path.exists() or f"anneal{budget_tag(budget)}_k{k}" in shipped or not claim(path):
                continue  # done here, shipped from another machine, or a live worker's
            try:
                log(f"start {path.name}")
                r = run_reference(a.cache, scene, a.seed, mould, budget, k, log=log)
                log(f"done {path.name}: {r.status}, E/cell {r.energy_per_cell:.6f}, "
                    f"{r.seconds:.0f} CPU s")
                out = pack_mould(a.cache, scene, a.seed, mould, [budget], a.runs, provenance,
                                 folder=a.product)
                log(f"packed into {out}")
            finally:
                path.with_name(path.name + ".lock").unlink(missing_ok=True)
    return 0


if __name__ == "__main__":
    sys.exit(main())
