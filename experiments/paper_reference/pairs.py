"""Do two rungs' runs of the same seed stay alike? The evidence for the paired ladder.

Run k of every rung starts from the same lattice and orientations and draws the same random
stream (`reference_seed` does not depend on the budget). If the anneal forgot its start, run k
of 1e5 would lie as far from run k of 1e6 as from any other 1e6 run. For each mould this
writes the RMS distance between the two rungs' normalised fields for runs of the same seed
and of different seeds, and the paired and unpaired noise-corrected distances
(`estimators.paired_distance`, `ensemble_distance`) beside the upper rung's scatter:

    python experiments/paper_reference/pairs.py --out experiments/paper_reference/pairs.csv
"""

from __future__ import annotations

import argparse
import sys
from pathlib import Path

import numpy as np
import pandas as pd

import condor.measures.estimators as est
from condor.files import write_text
from condor.model.scenes import get_scene
from condor.studies.paper_reference import paired_rungs, reference_moulds

HERE = Path(__file__).resolve().parent
# scene -> (the folder of its runs (None: the shipped product), its moulds (None: the product's))
SCENES = {"tiny": (HERE / "tiny_reference", (0, 1, 2, 3, 4, 5, 6, 7, 74)),
          "default": (None, None), "paper": (None, (94, 647, 34, 231, 3))}


def rms(x, y) -> float:
    return float(np.sqrt(np.mean((x - y) ** 2)))


def main(argv=None) -> int:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--seed", type=int, default=2026)
    ap.add_argument("--rungs", type=float, nargs=2, default=[1e5, 1e6])
    ap.add_argument("--out", type=Path)
    a = ap.parse_args(argv)
    rows = []
    for name, (folder, moulds) in SCENES.items():
        scene = get_scene(name)
        for m in moulds or reference_moulds(name, a.seed, folder):
            lower, upper, _, _ = paired_rungs(scene, a.seed, m, *a.rungs,
                                              (folder, HERE / "rung_1e5"))
            lower, upper, n = np.asarray(lower), np.asarray(upper), len(lower)
            if n < 2:
                continue
            same = [rms(lower[k], upper[k]) for k in range(n)]
            other = [rms(lower[k], upper[j]) for k in range(n) for j in range(n) if j != k]
            pair = (lower[None], upper[None])
            rows.append({
                "scene": name, "mould": m, "pairs": n,
                "same_seed_rms": float(np.mean(same)), "other_seed_rms": float(np.mean(other)),
                "paired": est.root_mean(est.paired_distance(*pair).corrected),
                "unpaired": est.root_mean(est.ensemble_distance(*pair).corrected),
                "scatter": est.root_mean(est.noise_ceiling(upper[None]))})
            r = rows[-1]
            print(f"{name} {m}: same seed {r['same_seed_rms']:.3f}, other {r['other_seed_rms']:.3f}"
                  f"; distance paired {r['paired']:.3f}, unpaired {r['unpaired']:.3f}, "
                  f"scatter {r['scatter']:.3f}", flush=True)
    if a.out:
        write_text(a.out, pd.DataFrame(rows).to_csv(index=False, float_format="%.4g"))
    return 0


if __name__ == "__main__":
    sys.exit(main())
