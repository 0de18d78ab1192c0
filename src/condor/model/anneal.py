"""The paper's single-cell Metropolis simulated annealing (numba kernel + a thin driver).

Schedule: exponential, T_k = T_init * ratio^(-k / n_trials) for trial k, from T_init = 0.0625
kappa0 l0^2 down to T_init / 1e7, over n_trials = budget * n_mobile trials (budget = moves
per cell; the paper's is 1e6).

A trial picks a mobile cell uniformly at random and, with equal probability, proposes either
  * a position move r' = r + U([-dr, dr]^3)      (uniform step-function proposal), or
  * an orientation move s' = (s + ds u) / |...|, u uniform in the unit ball (isotropic, so the
    proposal is symmetric; the energy is even in s so the sign of s carries no meaning).
    Until 2026-12 u was uniform in the cube [-1, 1]^3, whose proposal is not symmetric: at
    ds ~ 0.8 it biased the sampled orientations by 8 standard errors against quadrature.
The move is accepted with probability min(1, exp(-dE / T)). A position outside the allowed
region (the mould polygon minus tether disks, 0 <= z <= depth) would pay the paper's 1e9
penalty, so it is rejected outright without evaluating the energy.

Step-size adaptation: dr = a_r sqrt(T) and ds = a_s sqrt(T) follow the cooling (thermal
fluctuations scale as sqrt(T) in a harmonic well); after every sweep (n_mobile trials) each
amplitude a is multiplied by 1.2 if that move type's acceptance exceeded 40% and divided by
1.2 otherwise, with dr <= 0.5 l0 and ds <= 1. An amplitude is clamped to the one that meets
its cap at the current T: without the clamp, the orientation amplitude grew by 1.2 per sweep
while ds sat at its cap in the hot phase (acceptance > 40% even at ds = 1 above T ~ 0.01),
then needed as many sweeps to come back, and overflowed to inf beyond 4-5e4 moves per cell,
which left ds = 1 and the orientations frozen for the rest of the anneal.

A trial is O(1): it recomputes only the bonds of the moved cell through per-cell bond lists
that hold each bond's other cell, rest length, kbar and cached energy contiguously
(`neighbour_lists`; an accepted move updates both copies).

Randomness: a xorshift64* stream seeded from numpy.random.default_rng; deterministic.
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

from condor.model.energy import DELTA, bond_energies, rest_length
from condor.model.lattice import region_distance

T_INIT = 0.0625  # kappa0 l0^2 (paper)
T_RATIO = 1.0e7  # T_init / T_final (paper)
PAPER_BUDGET = 1.0e6  # moves per cell (paper)
TARGET_ACCEPT = 0.4
ADAPT_FACTOR = 1.2
MAX_STEP_POS = 0.5  # l0
MAX_STEP_ORI = 1.0
INIT_AMP_POS = 0.4  # dr = 0.1 l0 at T_init
INIT_AMP_ORI = 1.2  # ds = 0.3 at T_init
KERNEL = "ball-2026-12"  # the orientation proposal; a checkpoint of another kernel is refused
CHECKPOINT_SECONDS = 300.0  # wall time between a resumable anneal's checkpoints
CHECKPOINT_CHUNKS = 1000  # a resumable anneal runs in about this many segments

_U53 = 1.0 / 9007199254740992.0  # 2^-53


@numba.njit(cache=True, inline="always")
def _next_uniform(state):
    """xorshift64* step on state[0]; a uniform double in [0, 1)."""
    x = state[0]
    x ^= x >> np.uint64(12)
    x ^= x << np.uint64(25)
    x ^= x >> np.uint64(27)
    state[0] = x
    y = x * np.uint64(2685821657736338717)
    return float(y >> np.uint64(11)) * _U53


@numba.njit(cache=True)
def trial_energy_change(pos, ori, cell, new_r, new_s, cell_ptr, nbr_other, nbr_rest, nbr_kbar,
                        delta, slot_e, scratch):
    """Energy change of moving `cell` to (new_r, new_s), using cached bond energies.

    The cell's bonds are the slots cell_ptr[cell]:cell_ptr[cell + 1] of the per-cell lists
    (`neighbour_lists`): the other cell, rest length, kbar and cached energy of each bond,
    laid out contiguously so that a trial reads them in order. Writes the new energy of each
    of the cell's bonds into scratch[0:count] (in slot order).
    """
    de = 0.0
    n = 0
    for k in range(cell_ptr[cell], cell_ptr[cell + 1]):
        other = nbr_other[k]
        # Bond vector from cell to other; c_i, c_j are even in the sign of l.
        lx = pos[other, 0] - new_r[0]
        ly = pos[other, 1] - new_r[1]
        lz = pos[other, 2] - new_r[2]
        d = math.sqrt(lx * lx + ly * ly + lz * lz)
        inv = 1.0 / d
        c1 = (lx * new_s[0] + ly * new_s[1] + lz * new_s[2]) * inv
        c2 = (lx * ori[other, 0] + ly * ori[other, 1] + lz * ori[other, 2]) * inv
        g = d - rest_length(nbr_rest[k], c1, c2, delta)
        e_new = 0.5 * nbr_kbar[k] * g * g
        scratch[n] = e_new
        n += 1
        de += e_new - slot_e[k]
    return de


def neighbour_lists(lattice):
    """Per-cell bond slots in CSR order (cell_ptr): (other cell, rest, kbar, twin), twin being
    the slot of the same bond in the other cell's list (both hold its cached energy)."""
    cell_ptr, bonds = lattice.cell_ptr, lattice.cell_bonds
    owner = np.repeat(np.arange(lattice.n_cells), np.diff(cell_ptr))
    other = np.where(lattice.bond_i[bonds] == owner, lattice.bond_j[bonds], lattice.bond_i[bonds])
    order = np.argsort(bonds, kind="stable")  # the two slots of each bond, adjacent
    twin = np.empty(len(bonds), dtype=np.int64)
    twin[order[0::2]] = order[1::2]
    twin[order[1::2]] = order[0::2]
    return (other.astype(np.int64), lattice.bond_rest[bonds].copy(),
            lattice.bond_kbar[bonds].copy(), twin)


@numba.njit(cache=True)
def anneal_segment(
    pos, ori, mobile, cell_ptr, nbr_other, nbr_rest, nbr_kbar, twin, delta, phi, phi_x0, phi_y0,
    phi_h, posts, depth, slot_e, rng_state, amp, temp_energy, counts, trial_start, trial_stop,
    decay, scratch, adapt=True,
):
    """Run trials trial_start..trial_stop - 1 of an anneal in place: the whole mutable state is
    in the arguments, so an anneal cut into segments (and saved between them) is bit-identical
    to one call over all its trials.

    slot_e: cached energy of every bond slot (`neighbour_lists` order); rng_state: uint64[1];
    amp: float64[2] step amplitudes (a_r, a_s); temp_energy: float64[2] (the temperature of
    the next trial, the running energy); counts: int64[8] (accepted position moves, accepted
    orientation moves, rejected by confinement, bond energies evaluated, and this sweep's tried
    and accepted position and orientation moves); decay: the factor T falls by per trial.
    """
    n_mobile = len(mobile)
    temp = temp_energy[0]
    energy = temp_energy[1]
    new_r = np.empty(3)
    new_s = np.empty(3)
    acc_pos, acc_ori, n_outside, bonds_evaluated = counts[0], counts[1], counts[2], counts[3]
    tried_pos_sweep, tried_ori_sweep = counts[4], counts[5]
    acc_pos_sweep, acc_ori_sweep = counts[6], counts[7]
    for trial in range(trial_start, trial_stop):
        cell = mobile[min(int(_next_uniform(rng_state) * n_mobile), n_mobile - 1)]
        sqrt_t = math.sqrt(temp)
        move_pos = _next_uniform(rng_state) < 0.5
        if move_pos:
            tried_pos_sweep += 1
            step = min(amp[0] * sqrt_t, MAX_STEP_POS)
            for a in range(3):
                new_r[a] = pos[cell, a] + step * (2.0 * _next_uniform(rng_state) - 1.0)
                new_s[a] = ori[cell, a]
            outside = new_r[2] < 0.0 or new_r[2] > depth
            if not outside:
                outside = region_distance(phi, phi_x0, phi_y0, phi_h, posts, new_r[0],
                                          new_r[1]) < 0.0
            if outside:
                n_outside += 1
        else:
            outside = False
            tried_ori_sweep += 1
            step = min(amp[1] * sqrt_t, MAX_STEP_ORI)
            # A uniform point of the ball of radius `step` (rejection from the cube), added
            # and renormalised: the ball is isotropic, so the proposal density depends on
            # s . s' alone and is symmetric (detailed balance). A cube's is not, and biased
            # the sampled orientations at large steps (tests/test_anneal.py).
            while True:
                u2 = 0.0
                for a in range(3):
                    new_s[a] = 2.0 * _next_uniform(rng_state) - 1.0
                    u2 += new_s[a] * new_s[a]
                if u2 <= 1.0:
                    break
            norm2 = 0.0
            for a in range(3):
                new_r[a] = pos[cell, a]
                new_s[a] = ori[cell, a] + step * new_s[a]
                norm2 += new_s[a] * new_s[a]
            inv = 1.0 / math.sqrt(norm2)
            for a in range(3):
                new_s[a] *= inv
        de = 0.0
        if not outside:
            bonds_evaluated += cell_ptr[cell + 1] - cell_ptr[cell]
            de = trial_energy_change(pos, ori, cell, new_r, new_s, cell_ptr, nbr_other,
                                     nbr_rest, nbr_kbar, delta, slot_e, scratch)
        if not outside and (de <= 0.0 or _next_uniform(rng_state) < math.exp(-de / temp)):
            energy += de
            n = 0
            for k in range(cell_ptr[cell], cell_ptr[cell + 1]):
                slot_e[k] = scratch[n]
                slot_e[twin[k]] = scratch[n]
                n += 1
            for a in range(3):
                pos[cell, a] = new_r[a]
                ori[cell, a] = new_s[a]
            if move_pos:
                acc_pos += 1
                acc_pos_sweep += 1
            else:
                acc_ori += 1
                acc_ori_sweep += 1
        temp *= decay
        if adapt and (trial + 1) % n_mobile == 0:  # adapt once per sweep
            # Anti-windup: an amplitude never grows past the one that reaches its step cap at
            # the current temperature, so it can shrink as soon as the acceptance falls.
            cap_scale = 1.0 / math.sqrt(temp) if temp > 0.0 else math.inf
            if tried_pos_sweep > 0:
                up = acc_pos_sweep > TARGET_ACCEPT * tried_pos_sweep
                amp[0] = amp[0] * ADAPT_FACTOR if up else amp[0] / ADAPT_FACTOR
                amp[0] = min(amp[0], MAX_STEP_POS * cap_scale)
            if tried_ori_sweep > 0:
                up = acc_ori_sweep > TARGET_ACCEPT * tried_ori_sweep
                amp[1] = amp[1] * ADAPT_FACTOR if up else amp[1] / ADAPT_FACTOR
                amp[1] = min(amp[1], MAX_STEP_ORI * cap_scale)
            tried_pos_sweep = tried_ori_sweep = acc_pos_sweep = acc_ori_sweep = 0
    temp_energy[0] = temp
    temp_energy[1] = energy
    counts[0], counts[1], counts[2], counts[3] = acc_pos, acc_ori, n_outside, bonds_evaluated
    counts[4], counts[5] = tried_pos_sweep, tried_ori_sweep
    counts[6], counts[7] = acc_pos_sweep, acc_ori_sweep


@numba.njit(cache=True)
def _kernel_sum(values):
    """values.sum() as the kernels take it (numba's order), so that a driver's running energy
    starts from the same bits as anneal_kernel's."""
    return values.sum()


@numba.njit(cache=True)
def max_degree(cell_ptr):
    out = 1
    for c in range(len(cell_ptr) - 1):
        out = max(out, cell_ptr[c + 1] - cell_ptr[c])
    return out


@numba.njit(cache=True)
def anneal_kernel(
    pos, ori, mobile, bond_i, bond_j, kbar, rest, cell_ptr, cell_bonds, nbr_other, nbr_rest,
    nbr_kbar, twin, delta, phi, phi_x0, phi_y0, phi_h, posts, depth, n_trials, t_init, t_ratio,
    seed, amp,
):
    """Run n_trials Metropolis trials in place on pos, ori (N, 3) (one `anneal_segment`).

    amp: float64[2] step amplitudes (a_r, a_s), updated in place. Returns
    (energy, accepted position moves, accepted orientation moves, rejected by confinement,
    bond energies evaluated).
    """
    bond_e = bond_energies(pos, ori, bond_i, bond_j, kbar, rest, delta)
    slot_e = bond_e[cell_bonds]
    rng_state = np.empty(1, dtype=np.uint64)
    rng_state[0] = np.uint64(seed) | np.uint64(1)
    temp_energy = np.array([t_init, bond_e.sum()])
    counts = np.zeros(8, dtype=np.int64)
    decay = math.exp(-math.log(t_ratio) / max(n_trials, 1))
    anneal_segment(pos, ori, mobile, cell_ptr, nbr_other, nbr_rest, nbr_kbar, twin, delta, phi,
                   phi_x0, phi_y0, phi_h, posts, depth, slot_e, rng_state, amp, temp_energy,
                   counts, 0, n_trials, decay, np.empty(max_degree(cell_ptr)))
    return temp_energy[1], counts[0], counts[1], counts[2], counts[3]


class AnnealRun:
    """A resumable anneal: every piece of its state (positions, orientations, cached bond
    energies, the random stream, the temperature, the step amplitudes and the counters), so
    that it can be advanced in segments, saved to a checkpoint file between them and resumed
    in another process, bit-identical to one uninterrupted `anneal`.

    The checkpoint is an .npz written atomically (a temporary file, then a rename). It records
    what the run is (`key`: cells, trials, schedule, seed and a fingerprint of the lattice);
    `load` refuses a checkpoint of another run, naming the value that differs.
    """

    def __init__(self, lattice, positions, orientations, budget: float, seed_seq,
                 t_init: float = T_INIT, t_ratio: float = T_RATIO, delta: float = DELTA,
                 adapt: bool = True):
        if not np.isfinite(budget) or budget < 0:
            raise ValueError(f"anneal budget must be a non-negative number of moves per cell, "
                             f"got {budget}")
        self.lattice = lattice
        self.pos = np.array(positions, dtype=np.float64, order="C")
        self.ori = np.array(orientations, dtype=np.float64, order="C")
        self.mobile = np.flatnonzero(~lattice.fixed).astype(np.int64)
        self.n_trials = int(round(budget * len(self.mobile)))
        self.seed = int(np.random.default_rng(seed_seq).integers(1, 2**63 - 1))
        self.t_init, self.t_ratio, self.delta = float(t_init), float(t_ratio), float(delta)
        self.budget = float(budget)
        self.adapt = bool(adapt)  # False: fixed step amplitudes (`anneal_segment`)
        self.neighbours = neighbour_lists(lattice)
        bond_e = bond_energies(self.pos, self.ori, lattice.bond_i, lattice.bond_j,
                               lattice.bond_kbar, lattice.bond_rest, self.delta)
        self.slot_e = bond_e[lattice.cell_bonds]
        self.rng_state = np.array([np.uint64(self.seed) | np.uint64(1)], dtype=np.uint64)
        self.amp = np.array([INIT_AMP_POS, INIT_AMP_ORI])
        self.temp_energy = np.array([self.t_init, _kernel_sum(bond_e)])
        self.counts = np.zeros(8, dtype=np.int64)
        self.trial = 0
        self.cpu_seconds = 0.0  # process time spent in advance(), over every resumption
        self.resumed_seconds = 0.0  # of which in earlier processes (read from a checkpoint)
        self._scratch = np.empty(int(max_degree(lattice.cell_ptr)))

    @property
    def done(self) -> bool:
        return self.trial >= self.n_trials

    @property
    def fraction(self) -> float:
        return self.trial / self.n_trials if self.n_trials else 1.0

    @property
    def temperature(self) -> float:
        """The temperature of the next trial."""
        return float(self.temp_energy[0])

    def key(self) -> dict:
        """What this run is; a checkpoint of any other run is refused."""
        lat = self.lattice
        digest = hashlib.sha256()
        for array in (lat.positions, lat.fixed, lat.bond_i, lat.bond_j, lat.bond_rest,
                      lat.bond_kbar):
            digest.update(np.ascontiguousarray(array).tobytes())
        return {"kernel": KERNEL, "n_cells": int(lat.n_cells), "n_trials": self.n_trials, "budget": self.budget,
                "seed": self.seed, "t_init": self.t_init, "t_ratio": self.t_ratio,
                "delta": self.delta, "adapt": self.adapt, "lattice_sha256": digest.hexdigest()}

    def advance(self, n_trials: int | None = None) -> None:
        """Run the next `n_trials` trials (None: all that are left)."""
        stop = self.n_trials if n_trials is None else min(self.trial + int(n_trials),
                                                          self.n_trials)
        if stop <= self.trial:
            return
        region = self.lattice.region
        t0 = time.process_time()
        decay = math.exp(-math.log(self.t_ratio) / max(self.n_trials, 1))
        anneal_segment(self.pos, self.ori, self.mobile, self.lattice.cell_ptr, *self.neighbours,
                       self.delta, region.phi, region.phi_x0, region.phi_y0, region.phi_h,
                       region.posts, region.depth, self.slot_e, self.rng_state, self.amp,
                       self.temp_energy, self.counts, self.trial, stop, decay, self._scratch,
                       self.adapt)
        self.trial = stop
        self.cpu_seconds += time.process_time() - t0

    def set_state(self, positions, orientations) -> None:
        """Take new positions and orientations (e.g. after a relaxation of the positions),
        with their bond energies and the running energy recomputed."""
        lat = self.lattice
        self.pos[...] = positions
        self.ori[...] = orientations
        bond_e = bond_energies(self.pos, self.ori, lat.bond_i, lat.bond_j, lat.bond_kbar,
                               lat.bond_rest, self.delta)
        self.slot_e[...] = bond_e[lat.cell_bonds]
        self.temp_energy[1] = _kernel_sum(bond_e)

    def save(self, path) -> None:
        """Write the whole state to `path` atomically."""
        path = Path(path)
        path.parent.mkdir(parents=True, exist_ok=True)
        tmp = path.with_name(path.name + ".tmp")
        # The cached bond energies are kept as their bits XOR those recomputed from the state:
        # 97% zero on a 1e6 run of mould 468, whose checkpoint shrinks from 872 to 121 KB
        # (small enough to commit at a session's end), and the resume stays bit-identical.
        slot_xor = self.slot_e.view(np.uint64) ^ self._recomputed_slots().view(np.uint64)
        with open(tmp, "wb") as fh:
            np.savez_compressed(fh, key=np.array(json.dumps(self.key())),
                                trial=np.int64(self.trial),
                                cpu_seconds=np.float64(self.cpu_seconds),
                                pos=self.pos, ori=self.ori, slot_xor=slot_xor,
                                rng_state=self.rng_state, amp=self.amp,
                                temp_energy=self.temp_energy, counts=self.counts)
        os.replace(tmp, path)

    def _recomputed_slots(self) -> np.ndarray:
        lat = self.lattice
        return bond_energies(self.pos, self.ori, lat.bond_i, lat.bond_j, lat.bond_kbar,
                             lat.bond_rest, self.delta)[lat.cell_bonds]

    def load(self, path) -> None:
        """Take the state saved in `path`; ValueError (naming the file and the value) when it
        is not a checkpoint of this run or cannot be read."""
        path = Path(path)
        try:
            with np.load(path, allow_pickle=False) as data:
                key = json.loads(str(data["key"]))
                state = {name: data[name] for name in
                         ("pos", "ori", "rng_state", "amp", "temp_energy", "counts")}
                # slot_e itself in a checkpoint written before slot_xor
                slot = data["slot_xor"] if "slot_xor" in data.files else data["slot_e"]
                slot_is_xor = "slot_xor" in data.files
                trial = int(data["trial"])
                cpu_seconds = float(data["cpu_seconds"])
        except Exception as err:  # zipfile, KeyError and JSON errors alike
            raise ValueError(f"{path} is not a readable anneal checkpoint "
                             f"({type(err).__name__}: {err}); delete it to start over") from err
        mine = self.key()
        for name, value in mine.items():
            if key.get(name) != value:
                raise ValueError(f"{path} is the checkpoint of another anneal: its {name} is "
                                 f"{key.get(name)!r}, this run's {value!r}; delete it or "
                                 "choose another checkpoint path")
        for name, value in state.items():
            if value.shape != getattr(self, name).shape:
                raise ValueError(f"{path}: {name} has shape {value.shape}, expected "
                                 f"{getattr(self, name).shape} (truncated?)")
            getattr(self, name)[...] = value
        if slot.shape != self.slot_e.shape:
            raise ValueError(f"{path}: the bond energies have shape {slot.shape}, expected "
                             f"{self.slot_e.shape} (truncated?)")
        self.slot_e[...] = ((slot ^ self._recomputed_slots().view(np.uint64)).view(np.float64)
                            if slot_is_xor else slot)
        self.trial = trial
        self.cpu_seconds = self.resumed_seconds = cpu_seconds

    def info(self) -> dict:
        """The JSON-safe summary `anneal` returns."""
        acc_pos, acc_ori, n_outside, bonds_evaluated = (int(c) for c in self.counts[:4])
        t_final = self.t_init / self.t_ratio
        return {
            "anneal_trials": self.n_trials,
            "anneal_accept_pos": acc_pos / max(self.n_trials / 2, 1),
            "anneal_accept_ori": acc_ori / max(self.n_trials / 2, 1),
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
    checkpoint_seconds: float = CHECKPOINT_SECONDS, log=None,
) -> tuple[np.ndarray, np.ndarray, dict]:
    """Anneal copies of (positions, orientations) with `budget` moves per mobile cell.

    seed_seq: anything numpy.random.default_rng accepts (e.g. [seed, mould_id]).
    checkpoint: a file path. The run resumes from it when it exists (a checkpoint of another
    run is refused), and saves its state there every `checkpoint_seconds` of wall time and
    at the end, so that a long anneal killed at any moment loses at most that much work.
    The result is bit-identical with or without checkpoints and interruptions.
    log: a callable taking one progress line (about every `checkpoint_seconds`).
    Returns (positions, orientations, info) with info JSON-safe.
    """
    run = AnnealRun(lattice, positions, orientations, budget, seed_seq, t_init, t_ratio, delta)
    if checkpoint is None:
        run.advance()
    else:
        checkpoint = Path(checkpoint)
        if checkpoint.exists():
            run.load(checkpoint)
            if log is not None and not run.done:
                log(f"{checkpoint.name}: resumed at {run.fraction:.1%}")
        n_mobile = max(len(run.mobile), 1)
        chunk = n_mobile * max(1, run.n_trials // (n_mobile * CHECKPOINT_CHUNKS))
        last = time.monotonic()
        while not run.done:
            run.advance(chunk)
            if run.done or time.monotonic() - last >= checkpoint_seconds:
                run.save(checkpoint)
                last = time.monotonic()
                if log is not None:
                    log(f"{checkpoint.name}: {run.fraction:.1%} of {run.n_trials:,} trials, "
                        f"T {run.temperature:.3g}, E/cell "
                        f"{run.temp_energy[1] / lattice.n_cells:.6f}")
        if not checkpoint.exists():
            run.save(checkpoint)
    return run.pos, run.ori, run.info()


def relaxed_anneal(lattice, positions, orientations, seed_seq, t_hi: float, t_lo: float,
                   segments: int, sweeps: int, relax_evaluations: int, delta: float = DELTA
                   ) -> tuple[np.ndarray, np.ndarray, dict]:
    """An anneal from t_hi to t_lo (exponential, `segments` x `sweeps` moves a cell) whose
    positions are relaxed by L-BFGS (positions only, `relax_evaluations` evaluations) after
    every segment: Metropolis samples the orientations and the local position fluctuations,
    the relaxation carries the long-wavelength elastic modes that single-cell moves relax
    only over ~L^2 sweeps. Returns (positions, orientations, info) with info["anneal_*"] as
    `anneal` and relax_evaluations spent."""
    from condor.model.lbfgs import minimise_lbfgs  # the minimiser's floor is beside this one

    run = AnnealRun(lattice, positions, orientations, segments * sweeps, seed_seq, t_hi,
                    t_hi / t_lo, delta)
    n_mobile = len(run.mobile)
    relax = 0
    for _ in range(segments):
        run.advance(sweeps * n_mobile)
        if relax_evaluations > 0:
            pos, ori, info = minimise_lbfgs(lattice, run.pos, run.ori, relax_evaluations, 0.0,
                                            delta=delta, positions_only=True)
            relax += info["min_evaluations"]
            run.set_state(pos, ori)
    info = run.info()
    info["relax_evaluations"] = int(relax)
    info["anneal_evaluations"] += relax
    return run.pos, run.ori, info
