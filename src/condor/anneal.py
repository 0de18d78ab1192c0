"""The paper's single-cell Metropolis simulated annealing (numba kernel + a thin driver).

Schedule: exponential, T_k = T_init * ratio^(-k / n_trials) for trial k, from T_init = 0.0625
kappa0 l0^2 down to T_init / 1e7, over n_trials = budget * n_mobile trials (budget = moves
per cell; the paper's is 1e6).

A trial picks a mobile cell uniformly at random and, with equal probability, proposes either
  * a position move r' = r + U([-dr, dr]^3)      (uniform step-function proposal), or
  * an orientation move s' = (s + U([-ds, ds]^3)) / |...|  (uniform in a cube, renormalised;
    the energy is even in s so the sign of s carries no meaning).
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

import math

import numba
import numpy as np

from condor.energy import DELTA, bond_energies, rest_length
from condor.lattice import region_distance

T_INIT = 0.0625  # kappa0 l0^2 (paper)
T_RATIO = 1.0e7  # T_init / T_final (paper)
PAPER_BUDGET = 1.0e6  # moves per cell (paper)
TARGET_ACCEPT = 0.4
ADAPT_FACTOR = 1.2
MAX_STEP_POS = 0.5  # l0
MAX_STEP_ORI = 1.0
INIT_AMP_POS = 0.4  # dr = 0.1 l0 at T_init
INIT_AMP_ORI = 1.2  # ds = 0.3 at T_init

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
def anneal_kernel(
    pos, ori, mobile, bond_i, bond_j, kbar, rest, cell_ptr, cell_bonds, nbr_other, nbr_rest,
    nbr_kbar, twin, delta, phi, phi_x0, phi_y0, phi_h, posts, depth, n_trials, t_init, t_ratio,
    seed, amp,
):
    """Run n_trials Metropolis trials in place on pos, ori (N, 3).

    amp: float64[2] step amplitudes (a_r, a_s), updated in place. Returns
    (energy, accepted position moves, accepted orientation moves, rejected by confinement,
    bond energies evaluated).
    """
    bond_e = bond_energies(pos, ori, bond_i, bond_j, kbar, rest, delta)
    energy = bond_e.sum()
    slot_e = bond_e[cell_bonds]
    max_deg = 0
    for c in range(len(cell_ptr) - 1):
        max_deg = max(max_deg, cell_ptr[c + 1] - cell_ptr[c])
    scratch = np.empty(max(max_deg, 1))
    state = np.empty(1, dtype=np.uint64)
    state[0] = np.uint64(seed) | np.uint64(1)
    n_mobile = len(mobile)
    decay = math.exp(-math.log(t_ratio) / max(n_trials, 1))
    temp = t_init
    new_r = np.empty(3)
    new_s = np.empty(3)
    acc_pos = acc_ori = 0
    tried_pos_sweep = tried_ori_sweep = acc_pos_sweep = acc_ori_sweep = 0
    n_outside = 0
    bonds_evaluated = 0
    for trial in range(n_trials):
        cell = mobile[min(int(_next_uniform(state) * n_mobile), n_mobile - 1)]
        sqrt_t = math.sqrt(temp)
        move_pos = _next_uniform(state) < 0.5
        if move_pos:
            tried_pos_sweep += 1
            step = min(amp[0] * sqrt_t, MAX_STEP_POS)
            for a in range(3):
                new_r[a] = pos[cell, a] + step * (2.0 * _next_uniform(state) - 1.0)
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
            norm2 = 0.0
            for a in range(3):
                new_r[a] = pos[cell, a]
                new_s[a] = ori[cell, a] + step * (2.0 * _next_uniform(state) - 1.0)
                norm2 += new_s[a] * new_s[a]
            inv = 1.0 / math.sqrt(norm2)
            for a in range(3):
                new_s[a] *= inv
        de = 0.0
        if not outside:
            bonds_evaluated += cell_ptr[cell + 1] - cell_ptr[cell]
            de = trial_energy_change(pos, ori, cell, new_r, new_s, cell_ptr, nbr_other,
                                     nbr_rest, nbr_kbar, delta, slot_e, scratch)
        if not outside and (de <= 0.0 or _next_uniform(state) < math.exp(-de / temp)):
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
        if (trial + 1) % n_mobile == 0:  # adapt once per sweep
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
    return energy, acc_pos, acc_ori, n_outside, bonds_evaluated


def anneal(
    lattice, positions, orientations, budget: float, seed_seq, t_init: float = T_INIT,
    t_ratio: float = T_RATIO, delta: float = DELTA,
) -> tuple[np.ndarray, np.ndarray, dict]:
    """Anneal copies of (positions, orientations) with `budget` moves per mobile cell.

    seed_seq: anything numpy.random.default_rng accepts (e.g. [seed, mould_id]).
    Returns (positions, orientations, info) with info JSON-safe.
    """
    if not np.isfinite(budget) or budget < 0:
        raise ValueError(f"anneal budget must be a non-negative number of moves per cell, got {budget}")
    pos = np.array(positions, dtype=np.float64, order="C")
    ori = np.array(orientations, dtype=np.float64, order="C")
    mobile = np.flatnonzero(~lattice.fixed).astype(np.int64)
    n_trials = int(round(budget * len(mobile)))
    seed = int(np.random.default_rng(seed_seq).integers(1, 2**63 - 1))
    amp = np.array([INIT_AMP_POS, INIT_AMP_ORI])
    region = lattice.region
    energy, acc_pos, acc_ori, n_outside, bonds_evaluated = anneal_kernel(
        pos, ori, mobile, lattice.bond_i, lattice.bond_j, lattice.bond_kbar, lattice.bond_rest,
        lattice.cell_ptr, lattice.cell_bonds, *neighbour_lists(lattice), delta, region.phi,
        region.phi_x0, region.phi_y0, region.phi_h, region.posts, region.depth, n_trials, t_init, t_ratio, seed, amp,
    )
    info = {
        "anneal_trials": n_trials,
        "anneal_accept_pos": acc_pos / max(n_trials / 2, 1),
        "anneal_accept_ori": acc_ori / max(n_trials / 2, 1),
        "anneal_rejected_outside": int(n_outside),
        "anneal_bonds_evaluated": int(bonds_evaluated),
        "anneal_evaluations": float(bonds_evaluated / max(lattice.n_bonds, 1)),
        "anneal_running_energy": float(energy),
        "anneal_final_step_pos": float(min(amp[0] * math.sqrt(t_init / t_ratio), MAX_STEP_POS)),
        "anneal_final_step_ori": float(min(amp[1] * math.sqrt(t_init / t_ratio), MAX_STEP_ORI)),
    }
    return pos, ori, info
