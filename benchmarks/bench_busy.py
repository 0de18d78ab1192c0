"""Training beside other work: a training step's time alone and beside CPU-bound competitors.

Each setting (torch threads, how OpenMP's threads wait) trains in a fresh process, so that the
wait is read when the OpenMP runtime loads: the default run's network alone (`unet` preset's
U-Net at the default scene's 64 px, batch 8, Adam, a squared error), or with --store the whole
training loop (`condor train` of the default variant on that store: the physics head, the
symmetries, the inputs; the seconds of its first epoch). Alone, then beside
--competitors processes that each spin one core; the settings interleaved round by round.
Prints the median seconds a step of each setting alone and beside them, and their ratio, with
the range over rounds.

    python benchmarks/bench_busy.py [--rounds 3] [--steps 20] [--competitors 1] [--store S]

"auto" is condor's own choice (condor.openmp): it looks at the machine when `import condor`
runs, so alone it spins and beside a competitor it sleeps.

On a machine with other work running the "alone" figures are not alone: run it idle.
"""

from __future__ import annotations

import argparse
import json
import os
import re
import statistics
import subprocess
import sys
import tempfile
import textwrap

from condor import openmp

STEP = textwrap.dedent("""
    import json, sys, time
    import condor  # chooses the wait (condor.openmp) unless the environment holds one
    import torch
    from condor.surrogate.networks import UNetConfig, UNetGenerator
    threads, steps = int(sys.argv[1]), int(sys.argv[2])
    if threads:
        torch.set_num_threads(threads)
    torch.manual_seed(0)
    net = UNetGenerator(UNetConfig.for_size(64, base=32, upsample="bilinear", n_dropout=0,
                                            in_channels=2, out_channels=8))
    opt = torch.optim.Adam(net.parameters(), 2e-3)
    x, y = torch.rand(8, 2, 64, 64), torch.rand(8, 8, 64, 64)
    times = []
    for i in range(steps + 2):
        t0 = time.perf_counter()
        opt.zero_grad()
        loss = ((net(x) - y) ** 2).mean()
        loss.backward()
        opt.step()
        if i >= 2:  # the first two warm the allocator
            times.append(time.perf_counter() - t0)
    times.sort()
    print(json.dumps(times[len(times) // 2]))
""")

SPIN = {"GOMP_SPINCOUNT": str(openmp.SPIN_COUNT)}  # condor's idle choice, forced
SETTINGS = {  # name: (torch threads, the OpenMP environment; {} leaves the choice to condor)
    "2-auto": (2, {}),                               # condor's choice (condor.openmp)
    "2-spin": (2, SPIN),                             # spin 10,000 turns, then sleep
    "2-passive": (2, {"OMP_WAIT_POLICY": "PASSIVE"}),  # sleep at once
    "2-default": (2, {"OMP_WAIT_POLICY": "ACTIVE"}),  # spin while waiting
    "1-passive": (1, {"OMP_WAIT_POLICY": "PASSIVE"}),  # 1 thread
}
OPENMP_KEYS = (*openmp.KEYS, openmp.MARK)  # a child gets only its setting's


def step_seconds(threads: int, openmp: dict, steps: int, store: str | None = None) -> float:
    env = {k: v for k, v in os.environ.items() if k not in OPENMP_KEYS}
    env.update(openmp)
    if store is None:
        out = subprocess.run([sys.executable, "-c", STEP, str(threads), str(steps)], env=env,
                             check=True, capture_output=True, text=True).stdout
        return float(json.loads(out.strip().splitlines()[-1]))
    with tempfile.TemporaryDirectory() as tmp:  # condor train: its first epoch (no validation)
        out = subprocess.run([sys.executable, "-m", "condor.cli", "train", "--store", store,
                              "--checkpoint", os.path.join(tmp, "m.pt"), "--epochs", "2",
                              "--threads", str(threads)], env=env, check=True,
                             capture_output=True, text=True).stdout
    return float(re.search(r"^epoch 1/2 .* ([0-9.]+) s$", out, re.M).group(1))


def main() -> int:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--rounds", type=int, default=3)
    ap.add_argument("--steps", type=int, default=20)
    ap.add_argument("--competitors", type=int, default=1)
    ap.add_argument("--settings", nargs="+", choices=list(SETTINGS), default=list(SETTINGS))
    ap.add_argument("--store", default=None,
                    help="time condor train's first epoch on this store instead of the bare step")
    a = ap.parse_args()
    settings = {k: SETTINGS[k] for k in a.settings}
    alone = {k: [] for k in settings}
    busy = {k: [] for k in settings}
    for r in range(a.rounds):
        for name, (threads, environ) in settings.items():
            alone[name].append(step_seconds(threads, environ, a.steps, a.store))
        spinners = [subprocess.Popen([sys.executable, "-c", "while True: pass"])
                    for _ in range(a.competitors)]
        try:
            for name, (threads, environ) in settings.items():
                busy[name].append(step_seconds(threads, environ, a.steps, a.store))
        finally:
            for p in spinners:
                p.kill()
                p.wait()
        print(f"round {r + 1}/{a.rounds} done", file=sys.stderr, flush=True)
    what = (f"seconds of condor train's first epoch on {a.store}" if a.store else
            f"seconds a training step (median of {a.steps} steps")
    print(f"{what}, then median [range] over {a.rounds} rounds), beside {a.competitors} "
          "spinning process(es):")
    print(f"{'setting':10s} {'alone':>18s} {'beside':>18s} {'ratio':>18s}")
    for name in settings:
        ratios = [b / s for b, s in zip(busy[name], alone[name])]

        def fmt(v, unit=""):
            return f"{statistics.median(v):.3f} [{min(v):.3f}, {max(v):.3f}]{unit}"
        print(f"{name:10s} {fmt(alone[name]):>18s} {fmt(busy[name]):>18s} {fmt(ratios):>18s}")
    return 0


if __name__ == "__main__":
    sys.exit(main())
