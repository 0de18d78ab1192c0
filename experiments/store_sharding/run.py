"""Does Zarr v3 sharding pay at the paper's scale? (issue 31, docs/scale.md "Store layout")

Builds two synthetic stores of `--moulds` samples at `--pixels` px with the arrays, chunks,
dtypes and codecs of condor's store (condor.data.store.expected_arrays, CODECS): one as condor
writes it today (one chunk file per sample and array), one with the same chunks packed into
shards of `--shard` samples (one batch job's samples: the job stays the shard's only writer).
Each is written a batch at a time, as the workflow's batch jobs do. Then, for each: the files
and bytes written, the time to open the store (xarray over consolidated metadata, as
condor.open_dataset does), the time to read one sample's fields, and the time to list every
file (what a check of the store does first).

    python experiments/store_sharding/run.py --out /tmp/shard-bench        # 6,500 x 256 px
    python experiments/store_sharding/run.py --moulds 200 --out /tmp/s    # a quick try

The synthetic fields are smooth (a coarse random grid, interpolated) plus float32 noise and NaN
outside a disc, so that they compress about as real ones do. Timings depend on the machine
and its load; the counts do not. Needs about 2 x 5 GB of disk at the default size.
"""

from __future__ import annotations

import argparse
import csv
import os
import shutil
import sys
import time
from pathlib import Path

import numpy as np
import xarray as xr
import zarr

from condor.data.store import CODECS, StoreSpec, expected_arrays, quiet_zarr


def synthetic(rng, n, pixels, fields):
    """n samples of smooth masked fields, 0/1 inputs and lattice densities."""
    coarse = rng.random((n, fields, 9, 9)).astype(np.float32)
    x = np.linspace(0, 8, pixels)
    i = np.minimum(x.astype(int), 7)
    t = (x - i).astype(np.float32)
    rows = coarse[:, :, i] * (1 - t)[:, None] + coarse[:, :, i + 1] * t[:, None]
    smooth = rows[..., i] * (1 - t) + rows[..., i + 1] * t
    out = smooth + rng.normal(0, 1e-3, smooth.shape).astype(np.float32)
    yy, xx = np.mgrid[:pixels, :pixels]
    disc = (yy - pixels / 2) ** 2 + (xx - pixels / 2) ** 2 < (0.4 * pixels) ** 2
    out[:, :, ~disc] = np.nan
    inputs = np.stack([disc, ~disc], 0)[None].repeat(n, 0).astype(np.uint8)
    lattice = np.where(disc, out[:, :2], 0).astype(np.float32)
    return out, inputs, lattice


def build(path: Path, arrays: dict, n: int, shard: int | None, batch: int, pool) -> float:
    t0 = time.perf_counter()
    with quiet_zarr():
        group = zarr.open_group(path, mode="w-", zarr_format=3)
        for name, (shape, chunks, dtype, dims) in arrays.items():
            shards = None
            if shard and len(shape) >= 1 and chunks[0] == 1:
                shards = (shard, *chunks[1:])
            fill = np.nan if dtype == "float32" else (0 if dtype != "str" else "")
            group.create_array(name, shape=shape, chunks=chunks, shards=shards, dtype=dtype,
                               fill_value=fill if not str(dtype).startswith("<U") else "",
                               dimension_names=dims, **CODECS)
        fields, inputs, lattice = pool
        k = len(fields)
        for start in range(0, n, batch):
            stop = min(start + batch, n)
            idx = np.arange(start, stop) % k
            group["fields"][start:stop] = fields[idx]
            group["inputs"][start:stop] = inputs[idx]
            group["lattice"][start:stop] = lattice[idx]
            for name, (shape, chunks, dtype, dims) in arrays.items():
                if len(shape) == 1 and shape[0] == n:
                    value = "ok" if str(dtype).startswith("<U") else 1
                    group[name][start:stop] = np.full(stop - start, value, dtype=dtype)
        zarr.consolidate_metadata(path)
    return time.perf_counter() - t0


def measure(path: Path, n: int, repeats: int = 5) -> dict:
    t0 = time.perf_counter()
    files = [os.path.join(d, f) for d, _, fs in os.walk(path) for f in fs]
    listing = time.perf_counter() - t0
    size = sum(os.path.getsize(f) for f in files)
    opens, reads = [], []
    rng = np.random.default_rng(1)
    for _ in range(repeats):
        t0 = time.perf_counter()
        ds = xr.open_zarr(path, consolidated=True)
        opens.append(time.perf_counter() - t0)
        sample = int(rng.integers(n))
        t0 = time.perf_counter()
        values = ds["fields"].isel(sample=sample).values
        reads.append(time.perf_counter() - t0)
        assert values.shape[-1] == ds.sizes["x"]
    return {"files": len(files), "bytes": size, "list_s": listing,
            "open_s": float(np.median(opens)), "read_sample_s": float(np.median(reads))}


def main(argv=None) -> int:
    ap = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    ap.add_argument("--moulds", type=int, default=6500)
    ap.add_argument("--pixels", type=int, default=256)
    ap.add_argument("--shard", type=int, default=20, help="samples per shard (paper batch_size)")
    ap.add_argument("--out", type=Path, required=True, help="a folder for the two stores")
    ap.add_argument("--csv", type=Path, help="also write the table here")
    ap.add_argument("--keep", action="store_true", help="keep the stores (default: delete them)")
    ap.add_argument("--force", action="store_true", help="replace stores left in --out")
    args = ap.parse_args(argv)
    n = args.moulds
    spec = StoreSpec(n_moulds=n, pixels=args.pixels, seed=0, split=("train",) * n, attrs={})
    arrays = expected_arrays(spec)
    pool = synthetic(np.random.default_rng(0), 16, args.pixels, arrays["fields"][0][1])
    args.out.mkdir(parents=True, exist_ok=True)
    rows = []
    for layout, shard in (("chunk per sample", None), (f"shards of {args.shard}", args.shard)):
        path = args.out / ("unsharded.zarr" if shard is None else "sharded.zarr")
        if path.exists():
            if not args.force:
                sys.exit(f"{path} exists: pass --force to replace it")
            shutil.rmtree(path)
        write_s = build(path, arrays, n, shard, args.shard, pool)
        row = {"layout": layout, "moulds": n, "pixels": args.pixels, "write_s": write_s,
               **measure(path, n)}
        rows.append(row)
        print(", ".join(f"{k}={v:.4g}" if isinstance(v, float) else f"{k}={v}"
                        for k, v in row.items()), flush=True)
        if not args.keep:
            shutil.rmtree(path)
    if args.csv:
        with open(args.csv, "w", newline="") as fh:
            writer = csv.DictWriter(fh, fieldnames=list(rows[0]))
            writer.writeheader()
            writer.writerows(rows)
    return 0


if __name__ == "__main__":
    sys.exit(main())
