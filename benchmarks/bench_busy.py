"""Training beside other work: a training step's time alone and beside CPU-bound competitors.

Each setting (torch threads, OpenMP wait policy) trains the default run's network (`unet`
preset's U-Net at the default scene's 64 px, batch 8, Adam) in a fresh process, so that the
wait policy is read when the OpenMP runtime loads. Alone, then beside --competitors processes
that each spin one core, then alone again; the settings interleaved round by round. Prints the
median seconds a step of each setting alone and beside them, and their ratio, with the range
over rounds.

    python benchmarks/bench_busy.py [--rounds 3] [--steps 20] [--competitors 1]

On a machine with other work running the "alone" figures are not alone: run it idle.
"""

from __future__ import annotations

import argparse
import json
import os
import statistics
import subprocess
import sys
import textwrap

STEP = textwrap.dedent("""
    import json, sys, time
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

SETTINGS = {  # name: (torch threads, OMP_WAIT_POLICY or None for the runtime's default)
    "2-default": (2, None),   # 2 torch threads, the OpenMP runtime's default wait (spinning)
    "2-passive": (2, "PASSIVE"),  # 2 threads that sleep while they wait (condor's default)
    "1-default": (1, None),   # 1 thread
}


def step_seconds(threads: int, policy: str | None, steps: int) -> float:
    env = {k: v for k, v in os.environ.items() if k != "OMP_WAIT_POLICY"}
    if policy:
        env["OMP_WAIT_POLICY"] = policy
    out = subprocess.run([sys.executable, "-c", STEP, str(threads), str(steps)], env=env,
                         check=True, capture_output=True, text=True).stdout
    return float(json.loads(out.strip().splitlines()[-1]))


def main() -> int:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--rounds", type=int, default=3)
    ap.add_argument("--steps", type=int, default=20)
    ap.add_argument("--competitors", type=int, default=1)
    ap.add_argument("--settings", nargs="+", choices=list(SETTINGS), default=list(SETTINGS))
    a = ap.parse_args()
    settings = {k: SETTINGS[k] for k in a.settings}
    alone = {k: [] for k in settings}
    busy = {k: [] for k in settings}
    for r in range(a.rounds):
        for name, (threads, policy) in settings.items():
            alone[name].append(step_seconds(threads, policy, a.steps))
        spinners = [subprocess.Popen([sys.executable, "-c", "while True: pass"])
                    for _ in range(a.competitors)]
        try:
            for name, (threads, policy) in settings.items():
                busy[name].append(step_seconds(threads, policy, a.steps))
        finally:
            for p in spinners:
                p.kill()
                p.wait()
        print(f"round {r + 1}/{a.rounds} done", file=sys.stderr, flush=True)
    print(f"seconds a training step (median of {a.steps} steps, then median [range] over "
          f"{a.rounds} rounds), beside {a.competitors} spinning process(es):")
    print(f"{'setting':10s} {'alone':>18s} {'beside':>18s} {'ratio':>18s}")
    for name in settings:
        ratios = [b / s for b, s in zip(busy[name], alone[name])]

        def fmt(v, unit=""):
            return f"{statistics.median(v):.3f} [{min(v):.3f}, {max(v):.3f}]{unit}"
        print(f"{name:10s} {fmt(alone[name]):>18s} {fmt(busy[name]):>18s} {fmt(ratios):>18s}")
    return 0


if __name__ == "__main__":
    sys.exit(main())
