"""The paper's single-cell Metropolis simulated annealing: the schedule and a thin driver over
the numba kernel (condor.model.metropolis: the trials, the strips, the step sizes' adaptation).

Schedule: exponential, from T_init = 0.0625 kappa0 l0^2 down to T_init / 1e7 over `budget`
moves per cell (the paper's budget is 1e6), rounded to whole sweeps. A sweep is two half
sweeps, one per strip colour (condor.model.metropolis), and the temperature falls by a constant
factor after each half sweep: T_h = T_init * ratio^(-h / (2 n_sweeps)).

The driver (`AnnealRun`) holds every piece of an anneal's state, advances it in whole sweeps
and checkpoints it between them, so that an anneal resumes bit-identically in another process
and on any number of threads; `anneal` runs one, `relaxed_anneal` relaxes the positions by
L-BFGS between its segments. KERNEL names the kernel's trial order and proposals: a
checkpoint of another kernel is refused.
"""

from __future__ import annotations

import hashlib
import json
import math
import os
import time
from pathlib import Path

import numba
import numpy as np

from condor.model.energy import DELTA
from condor.model.metropolis import (MAX_STEP_ORI, MAX_STEP_POS, N_COUNTS, STRIP_WIDTH, Layout,
                                     pack_state, stream_seeds, sweeps_parallel, sweeps_serial,
                                     total_energy)

T_INIT = 0.0625  # kappa0 l0^2 (paper)
T_RATIO = 1.0e7  # T_init / T_final (paper)
PAPER_BUDGET = 1.0e6  # moves per cell (paper)
INIT_AMP_POS = 0.4  # dr = 0.1 l0 at T_init
INIT_AMP_ORI = 1.2  # ds = 0.3 at T_init
KERNEL = "strips-2026-12"  # the trial order and proposals; a checkpoint of another is refused
MOVES_PER_SWEEP = 2  # a visit tries a position move and an orientation move
CHECKPOINT_SECONDS = 300.0  # wall time between a resumable anneal's checkpoints
CHECKPOINT_CHUNKS = 1000  # a resumable anneal runs in about this many segments


def available_threads() -> int:
    """The CPUs this process may use (its affinity: a SLURM job's own share)."""
    try:
        return len(os.sched_getaffinity(0))
    except AttributeError:  # not Linux
        return os.cpu_count() or 1


class AnnealRun:
    """A resumable anneal: every piece of its state (positions and orientations, the random
    streams, the temperature, the step amplitudes and the counters), so
    that it can be advanced in whole sweeps, saved to a checkpoint file between them and
    resumed in another process, bit-identical to one uninterrupted `anneal`, on any number of
    threads.

    The checkpoint is an .npz written atomically (a temporary file, then a rename). It records
    what the run is (`key`: kernel, cells, sweeps, schedule, seed and a fingerprint of the
    lattice); `load` refuses a checkpoint of another run, naming the value that differs.
    """

    def __init__(self, lattice, positions, orientations, budget: float, seed_seq,
                 t_init: float = T_INIT, t_ratio: float = T_RATIO, delta: float = DELTA,
                 adapt: bool = True, threads: int = 1):
        if not np.isfinite(budget) or budget < 0:
            raise ValueError(f"anneal budget must be a non-negative number of moves per cell, "
                             f"got {budget}")
        self.lattice = lattice
        self.layout = Layout.of(lattice, delta)
        self.state = pack_state(np.asarray(positions, dtype=np.float64),
                                np.asarray(orientations, dtype=np.float64))
        self.n_mobile = int(np.count_nonzero(~lattice.fixed))
        # a sweep is two moves a cell (each cell visited once on average)
        self.n_sweeps = 0 if budget == 0 else max(1, int(round(budget / MOVES_PER_SWEEP)))
        self.n_trials = MOVES_PER_SWEEP * self.n_sweeps * self.n_mobile
        self.seed = int(np.random.default_rng(seed_seq).integers(1, 2**63 - 1))
        self.t_init, self.t_ratio, self.delta = float(t_init), float(t_ratio), float(delta)
        self.budget = float(budget)
        self.adapt = bool(adapt)  # False: fixed step amplitudes
        self.threads = max(1, int(threads))
        self.rng = stream_seeds(self.seed, self.layout.n_strips)
        self.amp = np.array([INIT_AMP_POS, INIT_AMP_ORI])
        self.temp_energy = np.array([self.t_init, self.energy()])
        # accepted position and orientation moves, rejected by confinement, bond energies
        # evaluated, tried position and orientation moves
        self.counts = np.zeros(N_COUNTS, dtype=np.int64)
        self.sweep = 0
        self.cpu_seconds = 0.0  # process time spent in advance(), over every resumption
        self.resumed_seconds = 0.0  # of which in earlier processes (read from a checkpoint)
        n = self.layout.n_strips
        self._buf = np.empty((n, 8, self.layout.max_degree))
        self._strip_de = np.zeros(n)
        self._strip_counts = np.zeros((n, N_COUNTS), dtype=np.int64)

    @property
    def pos(self) -> np.ndarray:
        """The positions (N, 3), a copy."""
        return np.ascontiguousarray(self.state[:, 0:3])

    @property
    def ori(self) -> np.ndarray:
        """The orientations (N, 3), a copy."""
        return np.ascontiguousarray(self.state[:, 4:7])

    @property
    def done(self) -> bool:
        return self.sweep >= self.n_sweeps

    @property
    def fraction(self) -> float:
        return self.sweep / self.n_sweeps if self.n_sweeps else 1.0

    @property
    def temperature(self) -> float:
        """The temperature of the next half sweep."""
        return float(self.temp_energy[0])

    @property
    def decay(self) -> float:
        """The factor T falls by after each half sweep."""
        return math.exp(-math.log(self.t_ratio) / max(2 * self.n_sweeps, 1))

    def key(self) -> dict:
        """What this run is; a checkpoint of any other run is refused."""
        lat = self.lattice
        digest = hashlib.sha256()
        for array in (lat.positions, lat.fixed, lat.bond_i, lat.bond_j, lat.bond_rest,
                      lat.bond_kbar):
            digest.update(np.ascontiguousarray(array).tobytes())
        return {"kernel": KERNEL, "n_cells": int(lat.n_cells), "n_sweeps": self.n_sweeps,
                "budget": self.budget, "seed": self.seed, "t_init": self.t_init,
                "t_ratio": self.t_ratio, "delta": self.delta, "adapt": self.adapt,
                "strip_width": STRIP_WIDTH, "lattice_sha256": digest.hexdigest()}

    def advance(self, n_sweeps: int | None = None) -> None:
        """Run the next `n_sweeps` sweeps (None: all that are left)."""
        left = self.n_sweeps - self.sweep
        n = left if n_sweeps is None else min(int(n_sweeps), left)
        if n <= 0:
            return
        lay, region = self.layout, self.lattice.region
        args = (self.state, lay.cell_ptr, lay.other, lay.rest_a, lay.rest_b, lay.half_kbar,
                lay.strip_ptr, lay.strip_cells, lay.colours[0], lay.colours[1],
                region.phi, region.phi_x0, region.phi_y0, region.phi_h, region.posts,
                region.depth, self.rng, self.amp, self.temp_energy, self.counts,
                n, self.decay, self.adapt, self._buf, self._strip_de, self._strip_counts)
        threads = min(self.threads, numba.config.NUMBA_NUM_THREADS, lay.n_strips // 2 or 1)
        t0 = time.process_time()
        if threads <= 1:
            sweeps_serial(*args)
        else:
            before = numba.get_num_threads()
            numba.set_num_threads(threads)
            try:
                sweeps_parallel(*args)
            finally:
                numba.set_num_threads(before)
        self.sweep += n
        self.cpu_seconds += time.process_time() - t0

    def set_state(self, positions, orientations) -> None:
        """Take new positions and orientations (e.g. after a relaxation of the positions),
        with their bond energies and the running energy recomputed."""
        self.state[:, 0:3] = positions
        self.state[:, 4:7] = orientations
        self.temp_energy[1] = self.energy()

    def energy(self) -> float:
        """The energy of the present state, recomputed (the running energy drifts from it by
        round-off only)."""
        lay = self.layout
        return float(total_energy(self.state, lay.cell_ptr, lay.other, lay.rest_a, lay.rest_b,
                                  lay.half_kbar))

    def save(self, path) -> None:
        """Write the whole state to `path` atomically."""
        path = Path(path)
        path.parent.mkdir(parents=True, exist_ok=True)
        tmp = path.with_name(path.name + ".tmp")
        with open(tmp, "wb") as fh:
            np.savez_compressed(fh, key=np.array(json.dumps(self.key())),
                                sweep=np.int64(self.sweep),
                                cpu_seconds=np.float64(self.cpu_seconds),
                                pos=self.pos, ori=self.ori, rng=self.rng,
                                amp=self.amp, temp_energy=self.temp_energy, counts=self.counts)
        os.replace(tmp, path)

    def load(self, path) -> None:
        """Take the state saved in `path`; ValueError (naming the file and the value) when it
        is not a checkpoint of this run or cannot be read."""
        path = Path(path)
        try:
            with np.load(path, allow_pickle=False) as data:
                key = json.loads(str(data["key"]))
                saved = {name: data[name] for name in data.files if name != "key"}
        except Exception as err:  # zipfile, KeyError and JSON errors alike
            raise ValueError(f"{path} is not a readable anneal checkpoint "
                             f"({type(err).__name__}: {err}); delete it to start over") from err
        if key.get("kernel") != KERNEL:
            raise ValueError(f"{path} is the checkpoint of an anneal by kernel "
                             f"{key.get('kernel')!r}, not this one ({KERNEL!r}), which samples "
                             "in another order; delete it to start over")
        for name, value in self.key().items():
            if key.get(name) != value:
                raise ValueError(f"{path} is the checkpoint of another anneal: its {name} is "
                                 f"{key.get(name)!r}, this run's {value!r}; delete it or "
                                 "choose another checkpoint path")
        expected = {"pos": (self.lattice.n_cells, 3), "ori": (self.lattice.n_cells, 3),
                    "rng": self.rng.shape, "amp": self.amp.shape,
                    "temp_energy": self.temp_energy.shape, "counts": self.counts.shape,
                    "sweep": (), "cpu_seconds": ()}
        for name, shape in expected.items():
            if name not in saved or saved[name].shape != shape:
                found = saved[name].shape if name in saved else "nothing"
                raise ValueError(f"{path}: {name} has shape {found}, expected {shape} "
                                 "(truncated?); delete it to start over")
        self.state[:, 0:3] = saved["pos"]
        self.state[:, 4:7] = saved["ori"]
        for name in ("rng", "amp", "temp_energy", "counts"):
            getattr(self, name)[...] = saved[name]
        self.sweep = int(saved["sweep"])
        self.cpu_seconds = self.resumed_seconds = float(saved["cpu_seconds"])

    def info(self) -> dict:
        """The JSON-safe summary `anneal` returns."""
        acc_pos, acc_ori, n_outside, bonds_evaluated, tried_pos, tried_ori = (
            int(c) for c in self.counts)
        t_final = self.t_init / self.t_ratio
        return {
            "anneal_trials": int(MOVES_PER_SWEEP * self.sweep * self.n_mobile),
            "anneal_accept_pos": acc_pos / max(tried_pos, 1),
            "anneal_accept_ori": acc_ori / max(tried_ori, 1),
            "anneal_rejected_outside": n_outside,
            "anneal_bonds_evaluated": bonds_evaluated,
            "anneal_evaluations": float(bonds_evaluated / max(self.lattice.n_bonds, 1)),
            "anneal_running_energy": float(self.temp_energy[1]),
            "anneal_final_step_pos": float(min(self.amp[0] * math.sqrt(t_final), MAX_STEP_POS)),
            "anneal_final_step_ori": float(min(self.amp[1] * math.sqrt(t_final), MAX_STEP_ORI)),
            "anneal_cpu_seconds": float(self.cpu_seconds),
            "anneal_resumed_seconds": float(self.resumed_seconds),
        }


def anneal(
    lattice, positions, orientations, budget: float, seed_seq, t_init: float = T_INIT,
    t_ratio: float = T_RATIO, delta: float = DELTA, checkpoint=None,
    checkpoint_seconds: float = CHECKPOINT_SECONDS, log=None, threads: int = 1,
) -> tuple[np.ndarray, np.ndarray, dict]:
    """Anneal copies of (positions, orientations) with `budget` moves per mobile cell.

    seed_seq: anything numpy.random.default_rng accepts (e.g. [seed, mould_id]).
    checkpoint: a file path. The run resumes from it when it exists (a checkpoint of another
    run is refused), and saves its state there every `checkpoint_seconds` of wall time and
    at the end, so that a long anneal killed at any moment loses at most that much work.
    The result is bit-identical with or without checkpoints and interruptions, and whatever
    `threads` (the strips of a colour run in parallel on that many threads).
    log: a callable taking one progress line (about every `checkpoint_seconds`).
    Returns (positions, orientations, info) with info JSON-safe.
    """
    run = AnnealRun(lattice, positions, orientations, budget, seed_seq, t_init, t_ratio, delta,
                    threads=threads)
    if checkpoint is None:
        run.advance()
    else:
        checkpoint = Path(checkpoint)
        if checkpoint.exists():
            run.load(checkpoint)
            if log is not None and not run.done:
                log(f"{checkpoint.name}: resumed at {run.fraction:.1%}")
        chunk = max(1, run.n_sweeps // CHECKPOINT_CHUNKS)
        last = time.monotonic()
        while not run.done:
            run.advance(chunk)
            if run.done or time.monotonic() - last >= checkpoint_seconds:
                run.save(checkpoint)
                last = time.monotonic()
                if log is not None:
                    log(f"{checkpoint.name}: {run.fraction:.1%} of {run.n_sweeps:,} sweeps, "
                        f"T {run.temperature:.3g}, E/cell "
                        f"{run.temp_energy[1] / lattice.n_cells:.6f}")
        if not checkpoint.exists():
            run.save(checkpoint)
    return run.pos, run.ori, run.info()


def relaxed_anneal(lattice, positions, orientations, seed_seq, t_hi: float, t_lo: float,
                   segments: int, moves: int, relax_evaluations, delta: float = DELTA,
                   threads: int = 1) -> tuple[np.ndarray, np.ndarray, dict]:
    """An anneal from t_hi to t_lo (exponential, `segments` x `moves` moves a cell; `moves`
    a whole number of sweeps, MOVES_PER_SWEEP moves a cell each) whose
    positions are relaxed by L-BFGS (positions only, `relax_evaluations` evaluations: one
    number, or one a segment) after every segment: Metropolis samples the orientations and
    the local position fluctuations, the relaxation carries the long-wavelength elastic modes
    that single-cell moves relax only over ~L^2 sweeps. Returns (positions, orientations,
    info) with info["anneal_*"] as `anneal` and relax_evaluations spent."""
    from condor.model.lbfgs import minimise_lbfgs  # the minimiser's floor is beside this one

    if moves % MOVES_PER_SWEEP or moves <= 0:
        raise ValueError(f"moves between relaxations must be a positive multiple of "
                         f"{MOVES_PER_SWEEP} (a sweep), got {moves}")
    schedule = np.asarray(relax_evaluations, dtype=np.int64)
    if schedule.ndim > 1 or (schedule.ndim == 1 and len(schedule) != segments):
        raise ValueError(f"relax_evaluations must be one number or one a segment ({segments}), "
                         f"got {relax_evaluations!r}")
    schedule = np.broadcast_to(schedule, (segments,))
    run = AnnealRun(lattice, positions, orientations, segments * moves, seed_seq, t_hi,
                    t_hi / t_lo, delta, threads=threads)
    relax = 0
    for evaluations in schedule:
        run.advance(moves // MOVES_PER_SWEEP)
        if evaluations > 0:
            pos, ori, info = minimise_lbfgs(lattice, run.pos, run.ori, int(evaluations), 0.0,
                                            delta=delta, positions_only=True)
            relax += info["min_evaluations"]
            run.set_state(pos, ori)
    info = run.info()
    info["relax_evaluations"] = int(relax)
    info["anneal_evaluations"] += relax
    return run.pos, run.ori, info
