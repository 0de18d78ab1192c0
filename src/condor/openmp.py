"""How OpenMP's threads (torch's and numba's) wait for work, chosen once per process before the
runtime loads (`import condor` calls `choose_wait`).

A waiting thread either spins or sleeps. Spinning is fast when the process has its cores: the
default run's training epoch took 2.8 s with 2 threads that spin briefly, against 4.7 s with
threads that sleep between torch's many small parallel regions. It is slow when another process
wants a core: a spinning thread that loses its core stalls the others (10 s against 5.2 s for
the sleeping threads, beside one process that spins a core). benchmarks/bench_busy.py measures
both; docs/scale.md gives the figures.

So condor looks before it chooses: where the other processes keep less than `IDLE_CORES` of a
core busy over a short look at /proc/stat, the threads spin for `SPIN_COUNT` turns before they
sleep (GOMP_SPINCOUNT); elsewhere, or where the machine cannot be read, they sleep at once
(OMP_WAIT_POLICY=PASSIVE). A value the user set in the environment is kept. The choice is
marked (`MARK`) so that a child process (a Snakemake job of a workflow that imported condor)
looks again for itself instead of inheriting its parent's look.
"""

from __future__ import annotations

import os
import sys
import time

SPIN_COUNT = 10_000   # GOMP_SPINCOUNT where the machine is idle: 2.8 s an epoch, as spinning on
IDLE_CORES = 0.5      # other processes' busy cores below which the machine counts as idle
LOOK_SECONDS = 0.05   # how long the look at /proc/stat lasts (5 clock ticks)
MARK = "CONDOR_OPENMP_WAIT"  # set beside condor's own choice: "spin" or "sleep"
KEYS = ("OMP_WAIT_POLICY", "GOMP_SPINCOUNT")


def cpu_times(text: str) -> tuple[int, int]:
    """(busy, total) clock ticks of /proc/stat's aggregate `cpu` line: idle and iowait are not
    busy; user, nice, system, irq, softirq and steal are (a stolen tick is a core lost)."""
    for line in text.splitlines():
        fields = line.split()
        if fields and fields[0] == "cpu":
            ticks = [int(v) for v in fields[1:9]]
            idle = ticks[3] + (ticks[4] if len(ticks) > 4 else 0)
            return sum(ticks) - idle, sum(ticks)
    raise ValueError("no aggregate 'cpu' line in /proc/stat")


def busy_cores(seconds: float = LOOK_SECONDS, stat: str = "/proc/stat") -> float | None:
    """Cores kept busy by other processes over `seconds` (this one sleeps meanwhile); None where
    `stat` cannot be read or parsed."""
    try:
        with open(stat) as f:
            busy0, total0 = cpu_times(f.read())
        time.sleep(seconds)
        with open(stat) as f:
            busy1, total1 = cpu_times(f.read())
    except (OSError, ValueError):
        return None
    if total1 <= total0:
        return None
    return (busy1 - busy0) / (total1 - total0) * (os.cpu_count() or 1)


def wait_settings(busy: float | None) -> dict[str, str | None]:
    """The environment for a machine with `busy` other cores busy (None: unknown): spin briefly
    where it is idle, else sleep. None removes a key."""
    if busy is not None and busy < IDLE_CORES:
        return {"OMP_WAIT_POLICY": None, "GOMP_SPINCOUNT": str(SPIN_COUNT), MARK: "spin"}
    return {"OMP_WAIT_POLICY": "PASSIVE", "GOMP_SPINCOUNT": None, MARK: "sleep"}


def choose_wait(environ=None, look=busy_cores) -> str:
    """Set how OpenMP's threads wait in `environ` (os.environ), unless the user set it or the
    runtime has loaded already (torch imported). Returns "user", "loaded", "spin" or "sleep"."""
    environ = os.environ if environ is None else environ
    if MARK not in environ and any(k in environ for k in KEYS):
        return "user"
    if "torch" in sys.modules:  # the runtime read its environment when torch loaded
        return "loaded"
    for key, value in wait_settings(look()).items():
        if value is None:
            environ.pop(key, None)
        else:
            environ[key] = value
    return environ[MARK]
