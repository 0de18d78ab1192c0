"""Snakemake overhead per job, to choose how many moulds a job handles (`batch_size`).

Runs the mould stage (store, moulds of every batch, gallery) of the tiny scene for the same
moulds with several batch sizes, each in a fresh folder with one core, and prints the wall
time, the number of jobs and the cost per job beyond the work itself:

    python benchmarks/bench_workflow_overhead.py [--moulds 24] [--repeats 3]
"""

from __future__ import annotations

import argparse
import statistics
import subprocess
import sys
import tempfile
import time
from pathlib import Path

import yaml

REPO = Path(__file__).resolve().parents[1]


def run_once(n_moulds: int, batch_size: int) -> float:
    with tempfile.TemporaryDirectory() as tmp:
        overlay = Path(tmp) / "overlay.yaml"
        # 2 test moulds, both the generator's: the accuracy study's (report.moulds)
        overlay.write_text(yaml.safe_dump({"n_moulds": n_moulds, "batch_size": batch_size,
                                           "split": {"test": 2, "lab_test": 0},
                                           "report": {"moulds": 2}}))
        cmd = [sys.executable, "-m", "snakemake", "--cores", "1", "--snakefile", str(REPO / "Snakefile"),
               "--workflow-profile", str(REPO / "profiles" / "default"), "--directory", tmp,
               "--configfile", str(REPO / "config" / "tiny.yaml"), str(overlay), "--until", "gallery", "--quiet"]
        start = time.perf_counter()
        done = subprocess.run(cmd, capture_output=True, text=True)
        if done.returncode != 0:
            raise SystemExit(f"snakemake failed ({done.returncode}):\n{done.stderr[-3000:]}")
        return time.perf_counter() - start


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--moulds", type=int, default=24)
    parser.add_argument("--repeats", type=int, default=3)
    parser.add_argument("--sizes", type=int, nargs="+", default=[1, 4, 24])
    args = parser.parse_args()
    times = {size: [] for size in args.sizes}
    for _ in range(args.repeats):  # interleave sizes so machine load affects all alike
        for size in args.sizes:
            times[size].append(run_once(args.moulds, size))
    print(f"mould stage, tiny scene, {args.moulds} moulds, 1 core, median of {args.repeats}")
    print(f"{'batch_size':>10} {'jobs':>5} {'wall s':>8} {'s per mould':>12}")
    medians = {}
    for size in args.sizes:
        jobs = -(-args.moulds // size)
        medians[size] = statistics.median(times[size])
        print(f"{size:>10} {jobs:>5} {medians[size]:>8.2f} {medians[size] / args.moulds:>12.3f}")
    small, large = min(args.sizes), max(args.sizes)
    extra_jobs = -(-args.moulds // small) - -(-args.moulds // large)
    if extra_jobs:
        per_job = (medians[small] - medians[large]) / extra_jobs
        print(f"overhead per extra job: {per_job:.2f} s (batch_size {small} vs {large})")


if __name__ == "__main__":
    main()
