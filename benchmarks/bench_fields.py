"""Benchmark rasterisation: 10,000 cells into 8 channels at 256 px (paper) and 64 px.

Compares condor.data.fields.rasterise (numba, grid laid out (y, x, channel)) with two
alternatives measured in the same run: a numba kernel on a (channel, y, x) grid and the best
numpy route found (dense separable weights, one matrix product per channel). Prints medians
and ratios. Target: <= 50 ms median at 256 px.

    python benchmarks/bench_fields.py [--cells 10000] [--repeats 15]
"""

from __future__ import annotations

import argparse
import os
import time

# One BLAS thread: on this 2-core machine threaded BLAS contends with other jobs and the
# numpy route's timing swings tenfold (the numba routes are single-threaded too).
os.environ.setdefault("OPENBLAS_NUM_THREADS", "1")

import numba
import numpy as np

from condor.data import fields as F
from condor.model.scenes import PAPER_BOX, SIGMA_L0


@numba.njit(cache=True)
def _splat_channel_first(first_y, wy, first_x, wx, values, grid):
    """The same kernel on grid[channel, y, x]: contiguous runs along x, one per channel."""
    n_cells, width = wy.shape
    n_channels = values.shape[1]
    height, breadth = grid.shape[1], grid.shape[2]
    for i in range(n_cells):
        ky0, ky1 = max(0, -first_y[i]), min(width, height - first_y[i])
        kx0, kx1 = max(0, -first_x[i]), min(width, breadth - first_x[i])
        for c in range(n_channels):
            for ky in range(ky0, ky1):
                w = wy[i, ky] * values[i, c]
                row = grid[c, first_y[i] + ky]
                for kx in range(kx0, kx1):
                    row[first_x[i] + kx] += w * wx[i, kx]


def rasterise_channel_first(xy, values, box, pixels, sigma=SIGMA_L0):
    ps = box / pixels
    first_x, wx = F.pixel_weights(xy[:, 0], pixels, ps, sigma)
    first_y, wy = F.pixel_weights(xy[:, 1], pixels, ps, sigma)
    grid = np.zeros((values.shape[1], pixels, pixels))
    _splat_channel_first(first_y, wy, first_x, wx, values, grid)
    return grid.astype(np.float32)


def dense_weights(first, weights, pixels):
    """Scatter windowed weights into a dense (N, pixels) matrix, dropping off-grid pixels."""
    index = first[:, None] + np.arange(weights.shape[1])
    inside = (index >= 0) & (index < pixels)
    dense = np.zeros((first.shape[0], pixels))
    rows = np.broadcast_to(np.arange(first.shape[0])[:, None], index.shape)
    dense[rows[inside], index[inside]] = weights[inside]
    return dense


def rasterise_numpy(xy, values, box, pixels, sigma=SIGMA_L0):
    """field[c] = Wy^T diag(values[:, c]) Wx: one BLAS matrix product per channel."""
    ps = box / pixels
    wx = dense_weights(*F.pixel_weights(xy[:, 0], pixels, ps, sigma), pixels)
    wy = dense_weights(*F.pixel_weights(xy[:, 1], pixels, ps, sigma), pixels)
    out = np.empty((values.shape[1], pixels, pixels), dtype=np.float32)
    for c in range(values.shape[1]):
        out[c] = wy.T @ (values[:, c, None] * wx)
    return out


def interleaved_medians(functions: dict, repeats: int) -> dict[str, float]:
    """Median ms of each function, timed round-robin so that load from other jobs on this
    shared machine falls on every method alike and the ratios stay meaningful."""
    times: dict[str, list[float]] = {name: [] for name in functions}
    for _ in range(repeats):
        for name, function in functions.items():
            start = time.perf_counter()
            function()
            times[name].append(time.perf_counter() - start)
    return {name: 1e3 * float(np.median(t)) for name, t in times.items()}


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--cells", type=int, default=10_000)
    parser.add_argument("--repeats", type=int, default=15)
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

    # Warm numba (compile or load the cache) and check the alternatives agree.
    reference = F.rasterise(xy, values, PAPER_BOX, 256)
    for alternative in (rasterise_channel_first, rasterise_numpy):
        difference = np.abs(alternative(xy, values, PAPER_BOX, 256) - reference).max()
        assert difference < 1e-4 * np.abs(reference).max(), (alternative.__name__, difference)
    F.rasterise(xy, values, PAPER_BOX, 64)

    timings = interleaved_medians(
        {
            "rasterise (y, x, channel), 256 px": lambda: F.rasterise(xy, values, PAPER_BOX, 256),
            "rasterise (y, x, channel), 64 px": lambda: F.rasterise(xy, values, PAPER_BOX, 64),
            "numba (channel, y, x), 256 px": lambda: rasterise_channel_first(
                xy, values, PAPER_BOX, 256
            ),
            "numpy dense matmul, 256 px": lambda: rasterise_numpy(xy, values, PAPER_BOX, 256),
            "pixel_weights x and y, 256 px": lambda: [
                F.pixel_weights(xy[:, k], 256, PAPER_BOX / 256, SIGMA_L0) for k in (0, 1)
            ],
        },
        args.repeats,
    )
    base = timings["rasterise (y, x, channel), 256 px"]
    print(f"{args.cells} cells, 8 channels, sigma {SIGMA_L0} l0, window +-{F.WINDOW_SIGMAS} sigma")
    for name, ms in timings.items():
        ratio = ms / base
        print(f"  {name:34s} median {ms:8.2f} ms   ratio to (y, x, channel) 256 px {ratio:5.2f}")
    print(f"  target <= 50 ms at 256 px: {'met' if base <= 50 else 'NOT met'}")


if __name__ == "__main__":
    main()
