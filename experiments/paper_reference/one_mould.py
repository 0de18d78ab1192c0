"""One mould's rungs and solvers, side by side: each ensemble's E/cell, cell-averaged
orientations and replica scatter, and the noise-corrected distance between every pair
(`condor.measures.estimators.ensemble_distance` of the normalised fields; one mould, so no
interval). The solvers' runs are read from experiments/fast_sampler/run.py's cache (run it for
the mould first).

    python experiments/paper_reference/one_mould.py --mould 468 --rungs 1e5 1e6 \
        --methods quench relax:0.03:0.001:15:10:40
"""

from __future__ import annotations

import argparse
import math
import sys
from pathlib import Path

import numpy as np

import condor.measures.estimators as est
from condor.model.scenes import get_scene
from condor.studies.fidelity import mean_orientation
from condor.studies.paper_reference import budget_tag, reference_rung

FAST_SAMPLER_CACHE = Path.home() / ".cache" / "condor" / "fast_sampler"


def main(argv=None) -> int:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--scene", default="default")
    ap.add_argument("--seed", type=int, default=2026)
    ap.add_argument("--mould", type=int, required=True)
    ap.add_argument("--rungs", type=float, nargs="+", default=[1e5, 1e6])
    ap.add_argument("--methods", nargs="*", default=["quench", "relax:0.03:0.001:15:10:40"])
    ap.add_argument("--seeds", type=int, default=4, help="runs of each method")
    ap.add_argument("--cache", type=Path, default=FAST_SAMPLER_CACHE)
    a = ap.parse_args(argv)
    scene = get_scene(a.scene)
    ensembles = {}
    for budget in a.rungs:
        fields, energy = reference_rung(scene, a.seed, a.mould, budget)
        if fields:
            ensembles[f"anneal {budget_tag(budget)}"] = (np.asarray(fields), np.asarray(energy))
    for spec in a.methods:
        folder = a.cache / f"{scene.name}_s{a.seed}" / spec.replace(":", "_")
        paths = [folder / f"m{a.mould}_r{k}.npz" for k in range(a.seeds)]
        missing = [str(p) for p in paths if not p.exists()]
        if missing:
            raise SystemExit(f"{spec}: no cached runs {missing}; run experiments/fast_sampler/"
                             f"run.py --moulds {a.mould} --methods {spec} first")
        runs = [np.load(p) for p in paths]
        ensembles[spec] = (np.asarray([r["fields"] for r in runs]),
                           np.asarray([float(r["energy"]) for r in runs]))
    for name, (f, e) in ensembles.items():
        noise = est.root_mean(est.noise_ceiling(f[None]))
        print(f"{name:28s} runs {len(f)}  E/cell {np.round(e, 6)}  (sx2, sy2, sz2) "
              f"{np.round(mean_orientation(f).mean(0), 3)}  one run's scatter {noise:.3f}")
    names = list(ensembles)
    for i, x in enumerate(names):
        for y in names[i + 1:]:
            d = float(np.ravel(est.ensemble_distance(ensembles[x][0][None],
                                                     ensembles[y][0][None]).corrected)[0])
            print(f"{x:28s} vs {y:28s} distance {math.sqrt(max(d, 0.0)):.3f}")
    return 0


if __name__ == "__main__":
    sys.exit(main())
