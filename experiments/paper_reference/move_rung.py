"""Move one rung's runs of a mould out of its product reference file into a folder of this
study (by default rung_1e5/, which tables.py and fast_sampler/run.py read when the product
lacks the rung), so that the product file keeps the rung load_reference reads within the
file-size rule:

  python experiments/paper_reference/move_rung.py --scene paper --mould 647 --budget 1e5

Both files are written whole (a temporary file, then a rename) under the product file's lock,
which the background worker's pack_mould takes too; a run already in the target file is
replaced by the product's.
"""

from __future__ import annotations

import argparse
import fcntl
import json
import sys
from pathlib import Path

import numpy as np

from condor.files import atomic_path
from condor.studies.paper_reference import budget_tag, reference_file

HERE = Path(__file__).resolve().parent


def _write(path: Path, meta: dict, arrays: dict) -> None:
    with atomic_path(path) as tmp:  # a hidden name: reference_moulds globs *.npz
        with open(tmp, "wb") as fh:
            np.savez_compressed(fh, meta=np.array(json.dumps(meta)), **arrays)


def _read(path: Path) -> tuple[dict, dict]:
    with np.load(path, allow_pickle=False) as data:
        return json.loads(str(data["meta"])), {k: data[k] for k in data.files if k != "meta"}


def move_rung(scene: str, seed: int, mould: int, budget: float, target: Path) -> tuple[Path, int]:
    source = reference_file(scene, seed, mould, None)
    dest = reference_file(scene, seed, mould, target)
    prefix = f"anneal{budget_tag(budget)}_"
    with open(source.with_name(source.name + ".lock"), "w") as lock:
        fcntl.flock(lock, fcntl.LOCK_EX)
        meta, arrays = _read(source)
        moving = [r for r in meta["runs"] if r["key"].startswith(prefix)]
        if not moving:
            raise SystemExit(f"{source} holds no run of budget {budget:g}")
        if len(moving) == len(meta["runs"]):
            raise SystemExit(f"{source} holds only budget {budget:g}: nothing would stay")
        kept = {k: v for k, v in arrays.items() if not k.startswith(prefix)}
        moved = {k: v for k, v in arrays.items() if k.startswith(prefix)}
        if dest.exists():
            old_meta, old_arrays = _read(dest)
            keys = {r["key"] for r in moving}
            moving = [r for r in old_meta["runs"] if r["key"] not in keys] + moving
            moved = {**old_arrays, **moved}
        dest.parent.mkdir(parents=True, exist_ok=True)
        _write(dest, {**meta, "runs": sorted(moving, key=lambda r: r["run"])},
               {**moved, "fixed": arrays["fixed"]})
        _write(source, {**meta, "runs": [r for r in meta["runs"]
                                         if not r["key"].startswith(prefix)]}, kept)
    return dest, len(moving)


def main(argv=None) -> int:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--scene", default="paper")
    ap.add_argument("--seed", type=int, default=2026)
    ap.add_argument("--mould", type=int, required=True)
    ap.add_argument("--budget", type=float, default=1e5)
    ap.add_argument("--to", type=Path, default=HERE / "rung_1e5")
    a = ap.parse_args(argv)
    dest, n = move_rung(a.scene, a.seed, a.mould, a.budget, a.to)
    print(f"{n} runs of budget {a.budget:g} now in {dest}; "
          f"{reference_file(a.scene, a.seed, a.mould, None)} keeps the rest")
    return 0


if __name__ == "__main__":
    sys.exit(main())
