"""The Metropolis kernel of the anneal (numba): the trials, the strips they run in, the step
sizes' adaptation and the layout they stream. The schedule and the driver that calls it, with
its checkpoints: condor.model.anneal.

A trial picks a mobile cell uniformly at random (within a strip, below) and, with equal
probability, proposes either
  * a position move r' = r + U([-dr, dr]^3)      (uniform step-function proposal), or
  * an orientation move s' = (s + ds u) / |...|, u uniform in the unit ball (isotropic, so the
    proposal is symmetric; the energy is even in s so the sign of s carries no meaning).
    Until 2026-12 u was uniform in the cube [-1, 1]^3, whose proposal is not symmetric: at
    ds ~ 0.8 it biased the sampled orientations by 8 standard errors against quadrature.
The move is accepted with probability min(1, exp(-dE / T)). A position outside the allowed
region (the mould polygon minus tether disks, 0 <= z <= depth) would pay the paper's 1e9
penalty, so it is rejected outright without evaluating the energy.

Strips (kernel `strips-2026-12`): the mobile cells are cut into strips of STRIP_WIDTH along
x by their lattice sites, wider than any bond's reach in x (2 l0), so a bond joins cells of
one strip or of two neighbouring strips, never two strips of one colour (strip index mod 2;
checked on the bonds when the strips are built). In a half sweep every strip of one colour
runs as many trials as it has mobile cells, on its own cells only, with its own random
stream, while the other colour's cells hold still. Each half sweep is thus a product of
Metropolis updates that each keep the Boltzmann distribution, and the strips of a colour are
independent of one another, so they run on as many threads as a job has (`threads`) with the
same bits whatever the thread count. Until 2026-12 the kernel (`ball-2026-12`) picked a cell
among all mobile cells at each trial and lowered T after every trial; the default scene's
1e5/1e6 reference rungs were made with it.

Step-size adaptation: dr = a_r sqrt(T) and ds = a_s sqrt(T) follow the cooling (thermal
fluctuations scale as sqrt(T) in a harmonic well); after every sweep each amplitude a is
multiplied by 1.2 if that move type's acceptance exceeded 40% and divided by 1.2 otherwise,
with dr <= 0.5 l0 and ds <= 1. An amplitude is clamped to the one that meets its cap at the
current T: without the clamp, the orientation amplitude grew by 1.2 per sweep while ds sat at
its cap in the hot phase (acceptance > 40% even at ds = 1 above T ~ 0.01), then needed as many
sweeps to come back, and overflowed to inf beyond 4-5e4 moves per cell, which left ds = 1 and
the orientations frozen for the rest of the anneal.

A trial is O(1) and recomputes only the bonds of the moved cell. The layout streams: each
cell's position and orientation share one cache line (`Layout.state`, 8 doubles a cell), and
each cell's bond slots hold the other cell, the two parts of the rest length
(L = a + b (c_i^2 + c_j^2) with a = l0 (1 - Delta), b = l0 Delta / 2, so the energy needs
no per-bond cosine divisions), kbar / 2 and the cached bond energy, contiguously. A trial
gathers its neighbours' states into small buffers, then evaluates the bonds in a loop that the
compiler vectorises (no fast-math: the same bits on every CPU), then sums the changes in eight
fixed lanes.

Randomness: xorshift64* streams, one a strip, seeded from numpy.random.default_rng;
deterministic.
"""

from __future__ import annotations

import math
from dataclasses import dataclass

import numba
import numpy as np

from condor.model.energy import DELTA
from condor.model.lattice import region_distance

# The step sizes' adaptation (above): the acceptance aimed at, the factor, the caps.
TARGET_ACCEPT = 0.4
ADAPT_FACTOR = 1.2
MAX_STEP_POS = 0.5  # l0
MAX_STEP_ORI = 1.0
STRIP_WIDTH = 2.5  # l0, along x: wider than a bond's reach (2 l0, the fourth shell)

_U53 = 1.0 / 9007199254740992.0  # 2^-53
_STATE = 8  # doubles a cell in Layout.state: x, y, z, -, sx, sy, sz, -
# per-strip counters: accepted position moves, accepted orientation moves, rejected by
# confinement, bond energies evaluated, tried position moves, tried orientation moves
N_COUNTS = 6


@numba.njit(cache=True, inline="always")
def _next_uniform(state, s):
    """xorshift64* step on state[s]; a uniform double in [0, 1)."""
    x = state[s]
    x ^= x >> np.uint64(12)
    x ^= x << np.uint64(25)
    x ^= x >> np.uint64(27)
    state[s] = x
    y = x * np.uint64(2685821657736338717)
    return float(y >> np.uint64(11)) * _U53


def stream_seeds(seed: int, n: int) -> np.ndarray:
    """n independent non-zero xorshift states from one seed (numpy's SeedSequence)."""
    words = np.random.SeedSequence([int(seed), 0xC0D0]).generate_state(n, dtype=np.uint64)
    return words | np.uint64(1)


@dataclass(frozen=True)
class Layout:
    """The kernel's view of a lattice: per-cell bond slots in CSR order and the strips.

    Slots (`cell_ptr`): other cell, the rest length's two parts a = l0 (1 - Delta) and
    b = l0 Delta / 2, and kbar / 2 (each bond twice, once in each cell's list). Strips: the mobile cells grouped by strip
    (`strip_cells[strip_ptr[s]:strip_ptr[s + 1]]`), and each colour's strips.
    """

    cell_ptr: np.ndarray
    other: np.ndarray
    rest_a: np.ndarray
    rest_b: np.ndarray
    half_kbar: np.ndarray
    strip_ptr: np.ndarray
    strip_cells: np.ndarray
    colours: tuple  # (strips of colour 0, strips of colour 1), int64 arrays
    max_degree: int

    @property
    def n_strips(self) -> int:
        return len(self.strip_ptr) - 1

    @classmethod
    def of(cls, lattice, delta: float = DELTA, strip_width: float = STRIP_WIDTH) -> "Layout":
        cell_ptr, bonds = lattice.cell_ptr, lattice.cell_bonds
        owner = np.repeat(np.arange(lattice.n_cells), np.diff(cell_ptr))
        other = np.where(lattice.bond_i[bonds] == owner, lattice.bond_j[bonds],
                         lattice.bond_i[bonds])
        rest = lattice.bond_rest[bonds]
        mobile = np.flatnonzero(~lattice.fixed).astype(np.int64)
        x = lattice.positions[:, 0]
        x0 = x.min() if len(x) else 0.0
        strip = np.floor((x - x0) / strip_width).astype(np.int64)
        n_strips = int(strip[mobile].max()) + 1 if len(mobile) else 1
        # The colouring's condition, checked on the bonds themselves: two mobile cells that
        # share a bond lie in one strip or in neighbouring strips.
        both = ~lattice.fixed[lattice.bond_i] & ~lattice.fixed[lattice.bond_j]
        reach = np.abs(strip[lattice.bond_i[both]] - strip[lattice.bond_j[both]])
        if reach.size and reach.max() > 1:
            raise ValueError(f"a bond spans {reach.max()} strips of {strip_width} l0; "
                             "the strips must be wider than any bond's reach in x")
        by_strip = mobile[np.argsort(strip[mobile], kind="stable")]
        counts = np.bincount(strip[mobile], minlength=n_strips)
        strip_ptr = np.concatenate([[0], np.cumsum(counts)]).astype(np.int64)
        ids = np.arange(n_strips, dtype=np.int64)
        return cls(cell_ptr=np.ascontiguousarray(cell_ptr, dtype=np.int64),
                   other=other.astype(np.int64), rest_a=rest * (1.0 - delta),
                   rest_b=rest * (0.5 * delta), half_kbar=0.5 * lattice.bond_kbar[bonds],
                   strip_ptr=strip_ptr, strip_cells=by_strip.astype(np.int64),
                   colours=(ids[0::2].copy(), ids[1::2].copy()),
                   max_degree=int(np.diff(cell_ptr).max(initial=1)))


def pack_state(positions, orientations) -> np.ndarray:
    """(N, 8) float64: each cell's position and orientation in one cache line."""
    state = np.zeros((len(positions), _STATE))
    state[:, 0:3] = positions
    state[:, 4:7] = orientations
    return state


@numba.njit(cache=True, error_model="numpy")
def _position_changes(bx, by, bz, ox, oy, oz, rest_a, rest_b, half_kbar, diff, n, rx, ry, rz,
                      nx, ny, nz, sx, sy, sz):
    """diff[q]: the change of bond q's energy when the cell (orientation s) moves from r to n,
    its neighbours at b with orientations o (contiguous buffers: the loop vectorises)."""
    for q in range(n):
        lx = bx[q] - rx
        ly = by[q] - ry
        lz = bz[q] - rz
        d2 = lx * lx + ly * ly + lz * lz
        ci = lx * sx + ly * sy + lz * sz
        cj = lx * ox[q] + ly * oy[q] + lz * oz[q]
        g = math.sqrt(d2) - rest_a[q] - rest_b[q] * (ci * ci + cj * cj) / d2
        mx = bx[q] - nx
        my = by[q] - ny
        mz = bz[q] - nz
        m2 = mx * mx + my * my + mz * mz
        ck = mx * sx + my * sy + mz * sz
        cl = mx * ox[q] + my * oy[q] + mz * oz[q]
        h = math.sqrt(m2) - rest_a[q] - rest_b[q] * (ck * ck + cl * cl) / m2
        diff[q] = half_kbar[q] * (h * h - g * g)


@numba.njit(cache=True, error_model="numpy")
def _orientation_changes(bx, by, bz, ox, oy, oz, rest_a, rest_b, half_kbar, diff, n, rx, ry,
                         rz, sx, sy, sz, tx, ty, tz):
    """diff[q]: the change of bond q's energy when the cell at r turns from s to t: the bond
    vectors stay, so one square root and one division serve both energies."""
    for q in range(n):
        lx = bx[q] - rx
        ly = by[q] - ry
        lz = bz[q] - rz
        d2 = lx * lx + ly * ly + lz * lz
        inv = 1.0 / d2
        cj = lx * ox[q] + ly * oy[q] + lz * oz[q]
        base = math.sqrt(d2) - rest_a[q] - rest_b[q] * cj * cj * inv
        ci = lx * sx + ly * sy + lz * sz
        ck = lx * tx + ly * ty + lz * tz
        g = base - rest_b[q] * ci * ci * inv
        h = base - rest_b[q] * ck * ck * inv
        diff[q] = half_kbar[q] * (h * h - g * g)


@numba.njit(cache=True, inline="always")
def _sum_lanes(x, n):
    """x[:n].sum() in eight fixed lanes: the same bits on every CPU, and no serial chain."""
    a0 = a1 = a2 = a3 = a4 = a5 = a6 = a7 = 0.0
    q = 0
    while q + 8 <= n:
        a0 += x[q]
        a1 += x[q + 1]
        a2 += x[q + 2]
        a3 += x[q + 3]
        a4 += x[q + 4]
        a5 += x[q + 5]
        a6 += x[q + 6]
        a7 += x[q + 7]
        q += 8
    while q < n:
        a0 += x[q]
        q += 1
    return ((a0 + a1) + (a2 + a3)) + ((a4 + a5) + (a6 + a7))


@numba.njit(cache=True, error_model="numpy")
def gather_neighbours(state, cell, cell_ptr, other, buf):
    """Copy the states of `cell`'s bonded neighbours into buf[0:6, :n] (x, y, z, sx, sy, sz,
    each contiguous); returns n, the cell's bond count."""
    p0 = cell_ptr[cell]
    n = cell_ptr[cell + 1] - p0
    bx, by, bz, ox, oy, oz = buf[0], buf[1], buf[2], buf[3], buf[4], buf[5]
    for q in range(n):
        o = other[p0 + q]
        bx[q] = state[o, 0]
        by[q] = state[o, 1]
        bz[q] = state[o, 2]
        ox[q] = state[o, 4]
        oy[q] = state[o, 5]
        oz[q] = state[o, 6]
    return n


@numba.njit(cache=True, error_model="numpy")
def position_change(buf, n, rest_a, rest_b, half_kbar, rx, ry, rz, nx, ny, nz, sx, sy, sz):
    """Energy change of the gathered cell (orientation s) moving from r to n; rest_a, rest_b,
    half_kbar: its own slots."""
    _position_changes(buf[0], buf[1], buf[2], buf[3], buf[4], buf[5], rest_a, rest_b,
                      half_kbar, buf[6], n, rx, ry, rz, nx, ny, nz, sx, sy, sz)
    return _sum_lanes(buf[6], n)


@numba.njit(cache=True, error_model="numpy")
def orientation_change(buf, n, rest_a, rest_b, half_kbar, rx, ry, rz, sx, sy, sz, tx, ty, tz):
    """Energy change of the gathered cell at r turning from s to t."""
    _orientation_changes(buf[0], buf[1], buf[2], buf[3], buf[4], buf[5], rest_a, rest_b,
                         half_kbar, buf[6], n, rx, ry, rz, sx, sy, sz, tx, ty, tz)
    return _sum_lanes(buf[6], n)


@numba.njit(cache=True, error_model="numpy")
def trial_energy_change(state, cell, nx, ny, nz, tx, ty, tz, cell_ptr, other, rest_a, rest_b,
                        half_kbar, buf):
    """Energy change of moving `cell` from its state to position n and orientation t (a
    position move, then a turn in place: the two moves of a visit). buf: (7, max_degree)
    scratch. No bond energy is cached: each move computes its bonds before and after, so an
    accepted move writes the cell's state (one cache line) and nothing else."""
    n = gather_neighbours(state, cell, cell_ptr, other, buf)
    p0, p1 = cell_ptr[cell], cell_ptr[cell + 1]
    ra, rb, hk = rest_a[p0:p1], rest_b[p0:p1], half_kbar[p0:p1]
    rx, ry, rz = state[cell, 0], state[cell, 1], state[cell, 2]
    sx, sy, sz = state[cell, 4], state[cell, 5], state[cell, 6]
    return (position_change(buf, n, ra, rb, hk, rx, ry, rz, nx, ny, nz, sx, sy, sz)
            + orientation_change(buf, n, ra, rb, hk, nx, ny, nz, sx, sy, sz, tx, ty, tz))


@numba.njit(cache=True)
def total_energy(state, cell_ptr, other, rest_a, rest_b, half_kbar):
    """E, each bond once (from its lower-numbered cell), computed as the trials compute it."""
    e = 0.0
    for c in range(len(cell_ptr) - 1):
        for k in range(cell_ptr[c], cell_ptr[c + 1]):
            o = other[k]
            if o < c:
                continue
            lx = state[o, 0] - state[c, 0]
            ly = state[o, 1] - state[c, 1]
            lz = state[o, 2] - state[c, 2]
            d2 = lx * lx + ly * ly + lz * lz
            ci = lx * state[c, 4] + ly * state[c, 5] + lz * state[c, 6]
            cj = lx * state[o, 4] + ly * state[o, 5] + lz * state[o, 6]
            g = math.sqrt(d2) - rest_a[k] - rest_b[k] * (ci * ci + cj * cj) / d2
            e += half_kbar[k] * g * g
    return e


@numba.njit(cache=True, error_model="numpy")
def _strip_visits(s, state, cell_ptr, other, rest_a, rest_b, half_kbar, strip_ptr,
                  strip_cells, phi, phi_x0, phi_y0, phi_h, posts, depth, rng, temp, step_pos,
                  step_ori, strip_de, strip_counts, buf):
    """One half sweep of strip s: as many visits as it has cells, at temperature `temp` with
    steps (step_pos, step_ori), on its own cells and random stream rng[s]. A visit tries a
    position move, then an orientation move, of one cell picked at random; both read the
    neighbours gathered once. Writes the energy change to strip_de[s] and the counters to
    strip_counts[s]."""
    start = strip_ptr[s]
    n_cells = strip_ptr[s + 1] - start
    inv_t = 1.0 / temp
    de_total = 0.0
    acc_pos = acc_ori = outside_n = evaluated = 0
    b = buf[s]
    for _ in range(n_cells):
        cell = strip_cells[start + min(int(_next_uniform(rng, s) * n_cells), n_cells - 1)]
        n = gather_neighbours(state, cell, cell_ptr, other, b)
        p0, p1 = cell_ptr[cell], cell_ptr[cell + 1]
        ra, rb, hk = rest_a[p0:p1], rest_b[p0:p1], half_kbar[p0:p1]
        rx, ry, rz = state[cell, 0], state[cell, 1], state[cell, 2]
        sx, sy, sz = state[cell, 4], state[cell, 5], state[cell, 6]
        # the position move: uniform in the cube of half-side step_pos
        nx = rx + step_pos * (2.0 * _next_uniform(rng, s) - 1.0)
        ny = ry + step_pos * (2.0 * _next_uniform(rng, s) - 1.0)
        nz = rz + step_pos * (2.0 * _next_uniform(rng, s) - 1.0)
        if nz < 0.0 or nz > depth or region_distance(phi, phi_x0, phi_y0, phi_h, posts,
                                                     nx, ny) < 0.0:
            outside_n += 1
        else:
            evaluated += n
            de = position_change(b, n, ra, rb, hk, rx, ry, rz, nx, ny, nz, sx, sy, sz)
            if de <= 0.0 or _next_uniform(rng, s) < math.exp(-de * inv_t):
                de_total += de
                rx, ry, rz = nx, ny, nz
                state[cell, 0], state[cell, 1], state[cell, 2] = rx, ry, rz
                acc_pos += 1
        # the orientation move: a uniform point of the ball of radius step_ori (rejection from
        # the cube), added and renormalised. The ball is isotropic, so the proposal density
        # depends on s . s' alone and is symmetric (detailed balance). A cube's is not, and
        # biased the sampled orientations at large steps (tests/test_anneal.py).
        while True:
            ux = 2.0 * _next_uniform(rng, s) - 1.0
            uy = 2.0 * _next_uniform(rng, s) - 1.0
            uz = 2.0 * _next_uniform(rng, s) - 1.0
            if ux * ux + uy * uy + uz * uz <= 1.0:
                break
        tx = sx + step_ori * ux
        ty = sy + step_ori * uy
        tz = sz + step_ori * uz
        inv = 1.0 / math.sqrt(tx * tx + ty * ty + tz * tz)
        tx *= inv
        ty *= inv
        tz *= inv
        evaluated += n
        de = orientation_change(b, n, ra, rb, hk, rx, ry, rz, sx, sy, sz, tx, ty, tz)
        if de <= 0.0 or _next_uniform(rng, s) < math.exp(-de * inv_t):
            de_total += de
            state[cell, 4], state[cell, 5], state[cell, 6] = tx, ty, tz
            acc_ori += 1
    strip_de[s] = de_total
    c = strip_counts[s]
    c[0], c[1], c[2], c[3], c[4], c[5] = acc_pos, acc_ori, outside_n, evaluated, n_cells, n_cells


@numba.njit(cache=True, inline="always")
def _close_half_sweep(strips, strip_de, strip_counts, temp_energy, counts, sweep_counts):
    """Add the strips' energy changes and counters in strip order (the same bits whatever the
    threads did)."""
    for i in range(len(strips)):
        s = strips[i]
        temp_energy[1] += strip_de[s]
        for a in range(N_COUNTS):
            counts[a] += strip_counts[s, a]
        sweep_counts[0] += strip_counts[s, 4]  # tried position moves
        sweep_counts[1] += strip_counts[s, 5]  # tried orientation moves
        sweep_counts[2] += strip_counts[s, 0]
        sweep_counts[3] += strip_counts[s, 1]


@numba.njit(cache=True, inline="always")
def _adapt(amp, sweep_counts, temp):
    """After a sweep: each amplitude up by ADAPT_FACTOR if its acceptance beat the target,
    down otherwise; never past the one that reaches its step cap at this temperature."""
    cap_scale = 1.0 / math.sqrt(temp) if temp > 0.0 else math.inf
    if sweep_counts[0] > 0:
        up = sweep_counts[2] > TARGET_ACCEPT * sweep_counts[0]
        amp[0] = amp[0] * ADAPT_FACTOR if up else amp[0] / ADAPT_FACTOR
        amp[0] = min(amp[0], MAX_STEP_POS * cap_scale)
    if sweep_counts[1] > 0:
        up = sweep_counts[3] > TARGET_ACCEPT * sweep_counts[1]
        amp[1] = amp[1] * ADAPT_FACTOR if up else amp[1] / ADAPT_FACTOR
        amp[1] = min(amp[1], MAX_STEP_ORI * cap_scale)
    sweep_counts[:] = 0


# The sweep loop, twice: one thread, and the strips of a colour in parallel (numba's prange).
# Both call the same per-strip kernel and close each half sweep in strip order, so they give
# the same bits; the serial one skips the threads' start-up on small moulds.

@numba.njit(cache=True, error_model="numpy")
def sweeps_serial(state, cell_ptr, other, rest_a, rest_b, half_kbar, strip_ptr,
                   strip_cells, colour0, colour1, phi, phi_x0, phi_y0, phi_h, posts, depth,
                   rng, amp, temp_energy, counts, n_sweeps, decay, adapt, buf,
                   strip_de, strip_counts):
    sweep_counts = np.zeros(4, dtype=np.int64)
    for _ in range(n_sweeps):
        for colour in range(2):
            strips = colour0 if colour == 0 else colour1
            temp = temp_energy[0]
            step_pos = min(amp[0] * math.sqrt(temp), MAX_STEP_POS)
            step_ori = min(amp[1] * math.sqrt(temp), MAX_STEP_ORI)
            for i in range(len(strips)):
                _strip_visits(strips[i], state, cell_ptr, other, rest_a, rest_b, half_kbar,
                              strip_ptr, strip_cells, phi, phi_x0, phi_y0, phi_h, posts,
                              depth, rng, temp, step_pos, step_ori, strip_de,
                              strip_counts, buf)
            _close_half_sweep(strips, strip_de, strip_counts, temp_energy, counts, sweep_counts)
            temp_energy[0] = temp * decay
        if adapt:
            _adapt(amp, sweep_counts, temp_energy[0])


@numba.njit(cache=True, parallel=True, error_model="numpy")
def sweeps_parallel(state, cell_ptr, other, rest_a, rest_b, half_kbar, strip_ptr,
                     strip_cells, colour0, colour1, phi, phi_x0, phi_y0, phi_h, posts, depth,
                     rng, amp, temp_energy, counts, n_sweeps, decay, adapt, buf,
                     strip_de, strip_counts):
    sweep_counts = np.zeros(4, dtype=np.int64)
    for _ in range(n_sweeps):
        for colour in range(2):
            strips = colour0 if colour == 0 else colour1
            temp = temp_energy[0]
            step_pos = min(amp[0] * math.sqrt(temp), MAX_STEP_POS)
            step_ori = min(amp[1] * math.sqrt(temp), MAX_STEP_ORI)
            for i in numba.prange(len(strips)):
                _strip_visits(strips[i], state, cell_ptr, other, rest_a, rest_b, half_kbar,
                              strip_ptr, strip_cells, phi, phi_x0, phi_y0, phi_h, posts,
                              depth, rng, temp, step_pos, step_ori, strip_de,
                              strip_counts, buf)
            _close_half_sweep(strips, strip_de, strip_counts, temp_energy, counts, sweep_counts)
            temp_energy[0] = temp * decay
        if adapt:
            _adapt(amp, sweep_counts, temp_energy[0])
