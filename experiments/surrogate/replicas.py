"""Replicas of a dataset's test moulds, for measuring the surrogate against the expected fields.

Replica r of mould i (global seed S) is simulated with seed `condor.data.seeds.replica_seed(S, i, r)`,
the store's replica convention (r = 0 is the dataset's own sample), by the store's solver and
budget unless --solver names another. Writes an .npz with `mould_ids` (M,), `fields`
(M, R, 8, H, W) float32 (replica 0 from the store), `n_cells` (M,), `seeds` (M, R), `energy`
(M, R) total energies. Resumable: finished moulds are kept in a per-mould cache beside the
output.

    PYTHONPATH=src python experiments/surrogate/replicas.py --store S --replicas 8 \
        --out DATA/replicas.npz

A store built with `simulation.replicas.test` > 1 (the default config: 8) already holds its
test moulds' replicas: `--from-store` copies them into the same .npz, simulating nothing
(every replica of the split's replicated moulds, replica 0 first; each sample's seed is
checked against condor.data.seeds.replica_seed):

    PYTHONPATH=src python experiments/surrogate/replicas.py --store S --from-store \
        --out replicas.npz
"""

from __future__ import annotations

import argparse
import time
from pathlib import Path

import numpy as np

from condor.data.dataset import open_dataset
from condor.moulds.paper import MouldParams
from condor.model.scenes import Scene
from condor.data.seeds import replica_seed
from condor.stages.build import make_mould, rasterise_result, simulate_mould
from condor.data.store import replica_samples


def from_store(store: str, split: str, out: str) -> None:
    """The .npz of the store's own replicas of `split`'s replicated moulds (no simulation)."""
    ds = open_dataset(store)
    seed = int(ds.attrs["seed"])
    first = np.asarray(ds["replica"].values) == 0
    in_split = np.asarray(ds["split"].values).astype(str) == split
    counts = np.asarray(ds.attrs["replicas"])
    ids = np.flatnonzero(first & in_split & (counts[np.asarray(ds["mould"].values)] > 1))
    if len(ids) == 0:
        raise SystemExit(f"{store}: no {split} mould has more than one replica")
    samples = np.array([replica_samples(store, int(m)) for m in ids])  # (M, R); ragged raises
    status = np.asarray(ds["status"].values).astype(str)[samples]
    if not np.all(status == "ok"):
        raise SystemExit(f"{store}: {int(np.sum(status != 'ok'))} replica samples not ok")
    seeds = np.asarray(ds["sim_seed"].values)[samples]
    expected = np.array([[replica_seed(seed, int(m), r) for r in range(samples.shape[1])]
                         for m in ids])
    if not np.array_equal(seeds, expected):
        raise SystemExit(f"{store}: sample seeds differ from condor.data.seeds.replica_seed")
    n_cells = np.asarray(ds["n_cells"].values)[samples]
    if not np.all(n_cells == n_cells[:, :1]):
        raise SystemExit(f"{store}: replicas of one mould disagree on the number of cells")
    fields = np.asarray(ds["fields"].isel(sample=samples.ravel()).values, dtype=np.float32)
    np.savez(out, mould_ids=ids, fields=fields.reshape(*samples.shape, *fields.shape[1:]),
             seeds=seeds, energy=np.asarray(ds["energy"].values)[samples],
             n_cells=n_cells[:, 0])
    print(f"wrote {out}: {len(ids)} moulds x {samples.shape[1]} replicas from {store}")


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--store", required=True)
    ap.add_argument("--replicas", type=int, default=8)
    ap.add_argument("--split", default="test")
    ap.add_argument("--solver", default=None,
                    help="default: the store's solver and budget (replicas of its samples)")
    ap.add_argument("--out", required=True)
    ap.add_argument("--from-store", action="store_true",
                    help="copy the replicas the store already holds (simulates nothing)")
    args = ap.parse_args()
    if args.from_store:
        return from_store(args.store, args.split, args.out)

    ds = open_dataset(args.store)
    scene = Scene(**ds.attrs["scene"])
    params = MouldParams(**ds.attrs["mould_params"])
    seed = int(ds.attrs["seed"])
    solver = args.solver or ds.attrs["solver"]
    budget = ds.attrs["solver_budget"] if solver == ds.attrs["solver"] else None
    # Replica 0 of each mould of the split: for these samples the sample index is the mould id.
    ids = np.flatnonzero((np.asarray(ds["split"].values).astype(str) == args.split)
                         & (np.asarray(ds["replica"].values) == 0))
    cache = Path(args.out).with_suffix("")
    cache.mkdir(parents=True, exist_ok=True)
    for k, mould_id in enumerate(ids):  # replicas 1.. need only the mould's geometry
        part = cache / f"{mould_id:06d}.npz"
        if part.exists():
            continue
        mould = make_mould(scene, seed, int(mould_id), params=params)
        fields, seeds, energies = [], [], []
        t0 = time.perf_counter()
        for r in range(1, args.replicas):
            s = replica_seed(seed, int(mould_id), r)
            res = simulate_mould(mould, scene, solver, budget, s)
            if res.status != "ok":
                raise RuntimeError(f"mould {mould_id} replica {r}: {res.status}")
            fields.append(rasterise_result(res, scene))
            seeds.append(s)
            energies.append(res.energy)
        np.savez(part, fields=np.stack(fields), seeds=np.array(seeds, dtype=np.int64),
                 energy=np.array(energies), n_cells=res.n_cells)
        print(f"[{k + 1}/{len(ids)}] mould {mould_id}: {args.replicas - 1} replicas in "
              f"{time.perf_counter() - t0:.1f} s", flush=True)
    status = np.asarray(ds["status"].values).astype(str)[ids]
    if not np.all(status == "ok"):
        print(f"replicas 1.. done; replica 0 waits for the store ({np.sum(status != 'ok')} "
              "test samples not ok yet)")
        return
    store_fields = np.asarray(ds["fields"].isel(sample=ids).values, dtype=np.float32)
    parts = [np.load(cache / f"{m:06d}.npz") for m in ids]
    n_cells = np.asarray(ds["n_cells"].values)[ids]
    for m, p, n in zip(ids, parts, n_cells):
        if int(p["n_cells"]) != int(n):
            raise RuntimeError(f"mould {m}: replicas have {p['n_cells']} cells, store {n}")
    fields = np.concatenate([store_fields[:, None], np.stack([p["fields"] for p in parts])], 1)
    seeds = np.array([[replica_seed(seed, int(m), 0)] + list(p["seeds"]) for m, p in zip(ids, parts)])
    energy = np.concatenate([np.asarray(ds["energy"].values)[ids][:, None],
                             np.stack([p["energy"] for p in parts])], 1)
    np.savez(args.out, mould_ids=ids, fields=fields, seeds=seeds, energy=energy, n_cells=n_cells)
    print(f"wrote {args.out}")


if __name__ == "__main__":
    main()
