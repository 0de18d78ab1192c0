"""Benchmark rasterisation: 10,000 cells into 8 channels at 256 px (paper) and 64 px.

Times condor.data.fields.rasterise (Taylor-polynomial weights, cells splatted in groups of 8)
against the previous rasteriser (e900e43: erf weights, cells one by one), kept below, in one
process: the routes take turns in every round, so that load from other jobs on a shared
machine falls on each alike, and each round's new / previous time is a paired ratio. Prints
each route's median and range (wall and CPU time of this thread), the ratios' median and
10-90% range, and the median at 256 px against the bar (20 ms; goal 15 ms).

    python benchmarks/bench_fields.py [--cells 10000] [--repeats 31] [--threads 2]
"""

from __future__ import annotations

import argparse
import math
import time

import numba
import numpy as np

from condor.data import fields as F
from condor.model.scenes import PAPER_BOX, SIGMA_L0

BAR_MS, GOAL_MS = 20.0, 15.0


# --- the previous rasteriser (e900e43), for the paired comparison ---------------------------


@numba.njit(cache=True)
def _previous_axis_weights(coord_px, reach, width, sigma_px, first, weights):
    scale = 1.0 / (math.sqrt(2.0) * sigma_px)
    for i in range(coord_px.shape[0]):
        u = coord_px[i]
        k0 = int(math.floor(u - reach))
        first[i] = k0
        lower = math.erf((k0 - u) * scale)
        for k in range(width):
            upper = math.erf((k0 + k + 1 - u) * scale)
            weights[i, k] = 0.5 * (upper - lower)
            lower = upper


@numba.njit(cache=True)
def _previous_splat(first_y, wy, first_x, wx, values, grid):
    n_cells, width = wy.shape
    n_channels = values.shape[1]
    height, breadth = grid.shape[0], grid.shape[1]
    rows = grid.reshape((height, breadth * n_channels))
    template = np.empty(width * n_channels)
    for i in range(n_cells):
        ky0 = max(0, -first_y[i])
        ky1 = min(width, height - first_y[i])
        kx0 = max(0, -first_x[i])
        kx1 = min(width, breadth - first_x[i])
        if ky1 <= ky0 or kx1 <= kx0:
            continue
        run = (kx1 - kx0) * n_channels
        for kx in range(kx0, kx1):
            for c in range(n_channels):
                template[(kx - kx0) * n_channels + c] = wx[i, kx] * values[i, c]
        start = (first_x[i] + kx0) * n_channels
        for ky in range(ky0, ky1):
            row = rows[first_y[i] + ky, start : start + run]
            w = wy[i, ky]
            for j in range(run):
                row[j] += w * template[j]


def previous_weights(coord, pixels, pixel_size, sigma=SIGMA_L0):
    sigma_px = sigma / pixel_size
    width = F.window_width(sigma_px)
    first = np.empty(coord.shape[0], dtype=np.int64)
    weights = np.empty((coord.shape[0], width))
    _previous_axis_weights(coord / pixel_size, F.WINDOW_SIGMAS * sigma_px, width, sigma_px,
                           first, weights)
    return first, weights


def previous_rasterise(xy, values, box, pixels, sigma=SIGMA_L0):
    """The previous rasterise, float32 (C, pixels, pixels)."""
    pixel_size = box / pixels
    margin = (F.WINDOW_SIGMAS * sigma / pixel_size + 3.0) * pixel_size
    xy = np.clip(xy, -margin, box + margin)
    first_x, wx = previous_weights(xy[:, 0], pixels, pixel_size, sigma)
    first_y, wy = previous_weights(xy[:, 1], pixels, pixel_size, sigma)
    grid = np.zeros((pixels, pixels, values.shape[1]))
    _previous_splat(first_y, wy, first_x, wx, np.ascontiguousarray(values), grid)
    return np.ascontiguousarray(grid.transpose(2, 0, 1), dtype=np.float32)


# --- timing ----------------------------------------------------------------------------------


def interleaved(functions: dict, repeats: int) -> tuple[dict, dict]:
    """Wall and thread-CPU seconds of each function per round, the functions taking turns."""
    wall = {name: [] for name in functions}
    cpu = {name: [] for name in functions}
    for _ in range(repeats):
        for name, function in functions.items():
            c0, w0 = time.thread_time(), time.perf_counter()
            function()
            wall[name].append(time.perf_counter() - w0)
            cpu[name].append(time.thread_time() - c0)
    return ({k: 1e3 * np.array(v) for k, v in wall.items()},
            {k: 1e3 * np.array(v) for k, v in cpu.items()})


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--cells", type=int, default=10_000)
    parser.add_argument("--repeats", type=int, default=31)
    parser.add_argument("--threads", type=int, default=2,
                        help="also time rasterise(threads=...) when above 1 (default 2)")
    args = parser.parse_args()

    # Cells spread over a centred disc of 40% of the paper box, as in a mould.
    rng = np.random.default_rng([0, args.cells])
    radius = np.sqrt(0.4 / np.pi) * PAPER_BOX
    r = radius * np.sqrt(rng.uniform(size=args.cells))
    angle = rng.uniform(0, 2 * np.pi, size=args.cells)
    xy = PAPER_BOX / 2 + np.stack([r * np.cos(angle), r * np.sin(angle)], axis=1)
    s = rng.normal(size=(args.cells, 3))
    s /= np.linalg.norm(s, axis=1, keepdims=True)
    values = F.cell_values(s, rng.normal(0.1, 0.05, size=args.cells))
    ps = PAPER_BOX / 256

    # Warm numba (compile or load the cache) and check that the two agree (tests/test_fields.py
    # checks it to float64 rounding).
    for pixels in (256, 64):
        new, old = F.rasterise(xy, values, PAPER_BOX, pixels), previous_rasterise(
            xy, values, PAPER_BOX, pixels)
        difference = float(np.abs(new - old).max())
        assert difference <= 1e-6 * np.abs(old).max(), (pixels, difference)
        if pixels == 256:
            print(f"{args.cells} cells, 8 channels, sigma {SIGMA_L0} l0, window "
                  f"+-{F.WINDOW_SIGMAS} sigma; largest difference from the previous fields "
                  f"at 256 px {difference:.1e} (largest value {np.abs(old).max():.3f})")
    threads = min(args.threads, numba.config.NUMBA_NUM_THREADS)
    routes = {
        "rasterise, 256 px": lambda: F.rasterise(xy, values, PAPER_BOX, 256),
        "previous, 256 px": lambda: previous_rasterise(xy, values, PAPER_BOX, 256),
        "rasterise, 64 px": lambda: F.rasterise(xy, values, PAPER_BOX, 64),
        "previous, 64 px": lambda: previous_rasterise(xy, values, PAPER_BOX, 64),
        "pixel_weights x and y, 256 px": lambda: [
            F.pixel_weights(xy[:, k], 256, ps, SIGMA_L0) for k in (0, 1)],
        "previous weights x and y, 256 px": lambda: [
            previous_weights(xy[:, k], 256, ps) for k in (0, 1)],
    }
    if threads > 1:
        routes[f"rasterise, 256 px, {threads} threads"] = lambda: F.rasterise(
            xy, values, PAPER_BOX, 256, threads=threads)
        routes[f"rasterise, 256 px, {threads} threads"]()
    wall, cpu = interleaved(routes, args.repeats)

    print(f"{args.repeats} interleaved rounds; wall ms median [min, max] | CPU ms of this "
          "thread, median (threads: the caller's only)")
    for name in routes:
        w = wall[name]
        print(f"  {name:36s} {np.median(w):8.2f} [{w.min():7.2f}, {w.max():8.2f}] | "
              f"{np.median(cpu[name]):7.2f}")
    print("paired ratios, new / previous, per round: median [10%, 90%] of wall time | of CPU")
    pairs = [("rasterise, 256 px", "previous, 256 px"), ("rasterise, 64 px", "previous, 64 px"),
             ("pixel_weights x and y, 256 px", "previous weights x and y, 256 px")]
    if threads > 1:
        pairs.append((f"rasterise, 256 px, {threads} threads", "rasterise, 256 px"))
    for new, old in pairs:
        ratio, cpu_ratio = wall[new] / wall[old], cpu[new] / cpu[old]
        lo, hi = np.percentile(ratio, [10, 90])
        c_lo, c_hi = np.percentile(cpu_ratio, [10, 90])
        print(f"  {new} / {old}: {np.median(ratio):.3f} [{lo:.3f}, {hi:.3f}] | "
              f"{np.median(cpu_ratio):.3f} [{c_lo:.3f}, {c_hi:.3f}]")
    median = float(np.median(wall["rasterise, 256 px"]))
    verdict = "met" if median <= BAR_MS else "NOT met"
    print(f"rasterise at 256 px, one thread: median {median:.2f} ms against the bar of "
          f"{BAR_MS:g} ms (goal {GOAL_MS:g}): {verdict}"
          + ("; goal met" if median <= GOAL_MS else "")
          + f" (CPU median {np.median(cpu['rasterise, 256 px']):.2f} ms: on a busy machine the "
          "wall time includes waiting for a core)")


if __name__ == "__main__":
    main()
