"""Is the tilt's expectation 0? The tilt fields SxSz, SySz at the paper scene, rung by rung.

The tilt fields are odd under the slab's reflection z -> depth - z. The energy, the floor and
the lid are even under it; the posts' cells, fixed at the lattice's layers z = 0 .. 3.54 in a
slab of depth 4, are not (condor.studies.fidelity). This study asks the runs whether a tilt
field's expectation is 0, for each paper-scene mould's reference rungs (the shipped runs,
rung_1e5/, more_runs_*/ and the cache, as more_runs.py reads them) and for the dataset's
sampler (experiments/fast_sampler's cache of RECIPE):

- per mould and ensemble, the unbiased |E f|^2 of each tilt field (the mean over pixels of
  mean^2 - s^2/n) with its leave-one-run-out standard error, beside the field's scatter s^2;
- the sign-flip test: under the reflection a run's tilt fields and their negation are equally
  likely, so |sum_k f_k|^2 against its values under random signs (exact for one mould,
  20,000 draws pooled over moulds, each mould weighed by its runs' sum of |f_k|^2);
- the mean height of the cells, and whether the lowest touches the floor.

    python experiments/paper_reference/tilt.py --out experiments/paper_reference/tilt_paper.csv
"""

from __future__ import annotations

import argparse
import itertools
import runpy
import sys
from pathlib import Path

import numpy as np
import pandas as pd

from condor.files import write_text
from condor.model.scenes import get_scene
from condor.studies.fidelity import TILT
from condor.studies.paper_reference import budget_tag, load_reference

HERE = Path(__file__).resolve().parent
MORE_RUNS = runpy.run_path(str(HERE / "more_runs.py"))
MOULDS = (94, 3, 647, 34, 231, 293, 555)


def tilt_squares(a: np.ndarray) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """Runs a (n, 2, H, W) of the tilt fields: unbiased |E f|^2 per field (pixel mean), its
    leave-one-run-out SE, and the scatter s^2."""
    def estimate(x):
        return (x.mean(0) ** 2 - x.var(0, ddof=1) / len(x)).mean(axis=(1, 2))
    n = len(a)
    jack = np.array([estimate(np.delete(a, i, 0)) for i in range(n)])
    se = np.sqrt((n - 1) / n * ((jack - jack.mean(0)) ** 2).sum(0))
    return estimate(a), se, a.var(0, ddof=1).mean(axis=(1, 2))


def gram(a: np.ndarray) -> np.ndarray:
    flat = a.reshape(len(a), -1)
    return flat @ flat.T / (flat * flat).sum()


def sign_flip_p(grams: list, draws: int, rng) -> float:
    """P(statistic >= observed) under random signs, sum over moulds of s' G s."""
    observed = sum(g.sum() for g in grams)
    if len(grams) == 1 and len(grams[0]) <= 12:
        signs = itertools.product((1.0, -1.0), repeat=len(grams[0]))
        null = [np.asarray(s) @ grams[0] @ np.asarray(s) for s in signs]
    else:
        null = [sum(s @ g @ s for g in grams for s in [rng.choice((-1.0, 1.0), len(g))])
                for _ in range(draws)]
    return float(np.mean(np.asarray(null) >= observed - 1e-12))


def main(argv=None) -> int:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--moulds", type=int, nargs="+", default=list(MOULDS))
    ap.add_argument("--seeds", type=int, default=16, help="the sampler's runs a mould")
    ap.add_argument("--draws", type=int, default=20000)
    ap.add_argument("--recipes", nargs="*", default=[MORE_RUNS["RECIPE"]],
                    help="samplers (experiments/fast_sampler/run.py's methods, cached there) to "
                         "test beside the anneals; RECIPE is named the dataset's solver; none: "
                         "the anneals alone")
    ap.add_argument("--out", type=Path, required=True)
    a = ap.parse_args(argv)
    scene, rng = get_scene("paper"), np.random.default_rng(0)
    rows, pooled = [], {}
    for m in a.moulds:
        ensembles = {}  # name -> (runs' fields, the rung's budget or None)
        for budget in (1e5, 1e6):
            runs = MORE_RUNS["rung_runs"](scene, 2026, m, budget, HERE / "cache")
            if len(runs) >= 3:
                ensembles[f"anneal {budget_tag(budget)}"] = (
                    np.stack([f for f, _ in runs.values()]), budget)
        for recipe in a.recipes:
            sampler = MORE_RUNS["sampler_runs"](scene, 2026, m, recipe, a.seeds)
            name = "the dataset's solver" if recipe == MORE_RUNS["RECIPE"] else recipe
            ensembles[name] = (np.stack([f for f, _ in sampler]), None)
        for name, (fields, budget) in ensembles.items():
            tilt = fields[:, list(TILT)].astype(np.float64)
            e2, se, s2 = tilt_squares(tilt)
            pooled.setdefault(name, []).append(gram(tilt))
            row = {"mould": m, "ensemble": name, "runs": len(tilt),
                   "SxSz_sq": e2[0], "SxSz_sq_se": se[0], "SxSz_scatter_sq": s2[0],
                   "SySz_sq": e2[1], "SySz_sq_se": se[1], "SySz_scatter_sq": s2[1],
                   "sign_flip_p": sign_flip_p([gram(tilt)], a.draws, rng)}
            if budget is not None:
                shipped = [r for folder in (None, HERE / "rung_1e5")
                           for r in _maybe(scene, m, budget, folder)]
                z = [r.positions[:, 2] for r in shipped]
                row.update(mean_height=float(np.mean([h.mean() for h in z])),
                           on_floor=all(h.min() < 1e-6 for h in z))
            rows.append(row)
            print({k: (round(v, 5) if isinstance(v, float) else v) for k, v in row.items()},
                  flush=True)
    for name, grams in pooled.items():
        rows.append({"mould": "pooled", "ensemble": name, "runs": sum(len(g) for g in grams),
                     "sign_flip_p": sign_flip_p(grams, a.draws, rng)})
        print(rows[-1], flush=True)
    write_text(a.out, pd.DataFrame(rows).to_csv(index=False, float_format="%.5g"))
    return 0


def _maybe(scene, mould: int, budget: float, folder) -> list:
    try:
        return load_reference(scene.name, 2026, mould, budget, folder)
    except FileNotFoundError:
        return []


if __name__ == "__main__":
    sys.exit(main())
