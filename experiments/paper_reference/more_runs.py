"""A mould's rungs with runs beyond the shipped three: the ladder in pairs and the sampler.

The product ships 3 runs a rung (src/condor/paper_reference/, rung_1e5/: the file-size rule).
Runs 3, 4, ... of a mould (`run.py --runs 5 --from-run 3`) are packed into `more_runs_1e5/` and
`more_runs_1e6/` (pack_mould from the run cache); this study reads them, the shipped runs and
any in the cache together, by run number, and scores for each mould:

- the ladder, lower rung against upper, run k against run k (`estimators.paired_distance`);
- the dataset's sampler (experiments/fast_sampler's cache of `--method`, its seeds) against
  each rung's runs (`fidelity_row`), and against its first 3 alone, as before;
- each distance without the tilt fields SxSz, SySz (odd under z -> -z), and their share;
- the squared distance with its leave-one-run-out standard error over the reference's runs.

    python experiments/paper_reference/more_runs.py --scene paper --moulds 94 \\
        --out experiments/paper_reference/more_runs_paper.csv
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
from condor.model.simulate import SimResult
from condor.studies.fidelity import TILT, fidelity_row
from condor.studies.paper_reference import budget_tag, rung_by_run, run_path, scene_fields

HERE = Path(__file__).resolve().parent
FAST_SAMPLER_CACHE = Path.home() / ".cache" / "condor" / "fast_sampler"
RECIPE = "relax:0.03:0.001:80:10:200+20,40:1e-3"  # the paper scene's (docs/model.md)
# runs beyond the shipped three, packed like the product (condor.studies.paper_reference
# .pack_mould), one folder a rung (and more_runs_1e6_k5/ for runs 5 and 6 of the 1e6 rung) so
# that each file keeps within the file-size rule
MORE_RUNS = (HERE / "more_runs_1e5", HERE / "more_runs_1e6", HERE / "more_runs_1e6_k5")


def rung_runs(scene, seed: int, mould: int, budget: float, cache: Path) -> dict:
    """run number -> (normalised fields, E/cell): the shipped runs (the product, else
    rung_1e5/), those of MORE_RUNS, and the cache's finished runs of any other number."""
    runs = rung_by_run(scene, seed, mould, budget, (None, HERE / "rung_1e5", *MORE_RUNS))
    k = 0
    while k < 100:
        path = run_path(cache, scene, seed, mould, budget, k)
        if k not in runs and path.exists():
            r = SimResult.load(path)
            if r.status == "ok":
                runs[k] = (scene_fields(r, scene), r.energy_per_cell)
        k += 1
    return dict(sorted(runs.items()))


def sampler_runs(scene, seed: int, mould: int, method: str, seeds: int) -> list:
    folder = FAST_SAMPLER_CACHE / f"{scene.name}_s{seed}" / method.replace(":", "_")
    out = []
    for k in range(seeds):
        with np.load(folder / f"m{mould}_r{k}.npz") as d:
            out.append((d["fields"].astype(np.float64), float(d["energy"])))
    return out




def field_split(a, b, paired: bool) -> dict:
    """The squared distance of a against b split by field: `distance_even` leaves the tilt
    fields SxSz, SySz out (the root of the other six's share of the mean over all 8), and
    `odd_share` is the tilt fields' share of the whole (NaN where the whole is not above 0)."""
    per_field = (est.paired_distance if paired else est.ensemble_distance)(
        a, b, per_field=True).corrected[0]
    total, odd = per_field.sum(), per_field[list(TILT)].sum()
    return {"distance_even": float(np.sqrt(max(total - odd, 0.0) / len(per_field))),
            "odd_share": float(odd / total) if total > 0 else float("nan")}


def jackknife(a, b, paired: bool) -> dict:
    """The squared distance (`distance_sq`, the mean over fields as fidelity_row's distance is
    its root) and its leave-one-out standard error over the reference's runs (`distance_sq_se`;
    paired: both runs of a pair left out together): how far one mould's figure can be trusted
    with so few runs."""
    estimate = (est.paired_distance if paired else est.ensemble_distance)
    full = float(estimate(a, b).corrected[0])
    n = b.shape[1]
    if n < 3:
        return {"distance_sq": full, "distance_sq_se": float("nan")}
    out = np.array([float(estimate(np.delete(a, i, 1) if paired else a, np.delete(b, i, 1))
                          .corrected[0]) for i in range(n)])
    return {"distance_sq": full,
            "distance_sq_se": float(np.sqrt((n - 1) / n * ((out - out.mean()) ** 2).sum()))}


def main(argv=None) -> int:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--scene", default="paper")
    ap.add_argument("--seed", type=int, default=2026)
    ap.add_argument("--moulds", type=int, nargs="+", required=True)
    ap.add_argument("--rungs", type=float, nargs=2, default=[1e5, 1e6])
    ap.add_argument("--method", default=RECIPE)
    ap.add_argument("--seeds", type=int, default=32, help="the sampler's cached runs a mould")
    ap.add_argument("--cache", type=Path, default=HERE / "cache")
    ap.add_argument("--out", type=Path)
    a = ap.parse_args(argv)
    scene = get_scene(a.scene)
    lower_tag, upper_tag = (f"anneal {budget_tag(b)}" for b in a.rungs)
    rows = []
    for m in a.moulds:
        low, high = (rung_runs(scene, a.seed, m, b, a.cache) for b in a.rungs)
        if not high:
            raise SystemExit(f"mould {m}: no finished run of the {upper_tag} rung (run.py "
                             f"--moulds {m} --rungs {a.rungs[1]:g})")
        pairs = sorted(set(low) & set(high))
        if pairs:  # the ladder, run k against run k (a mould with no lower rung has none)
            lower = np.stack([low[k][0] for k in pairs])[None]
            upper = np.stack([high[k][0] for k in pairs])[None]
            row = fidelity_row(lower_tag, scene.name, upper_tag, lower, upper,
                               energy=np.array([[low[k][1] for k in pairs]]),
                               ref_energy=np.array([[high[k][1] for k in pairs]]), paired=True)
            rows.append({**row, **field_split(lower, upper, True),
                         **jackknife(lower, upper, True), "mould": m,
                         "runs": " ".join(map(str, pairs))})
        else:
            print(f"mould {m}: no run of the {lower_tag} rung, so no ladder row")
        sampler = sampler_runs(scene, a.seed, m, a.method, a.seeds)
        fields = np.stack([f for f, _ in sampler])[None]
        energy = np.array([[e for _, e in sampler]])
        for rung, tag in ((high, upper_tag), (low, lower_tag)):
            if len(rung) < 2:  # a reference needs two runs for its noise
                continue
            for runs in (sorted(rung), sorted(rung)[:3]):
                reference = np.stack([rung[k][0] for k in runs])[None]
                row = fidelity_row(a.method, scene.name, tag, fields, reference, energy=energy,
                                   ref_energy=np.array([[rung[k][1] for k in runs]]))
                rows.append({**row, **field_split(fields, reference, False),
                             **jackknife(fields, reference, False), "mould": m,
                             "runs": " ".join(map(str, runs))})
    table = pd.DataFrame(rows)
    for r in table.itertuples():
        print(f"mould {r.mould}: {r.method} against {r.reference} runs {r.runs}: "
              f"{r.distance:.3f} / scatter {r.replica_noise:.3f} = "
              f"{r.distance / r.replica_noise:.2f}x (without the tilt fields {r.distance_even:.3f}"
              f"; their share {r.odd_share:.0%}); squared {r.distance_sq:+.4f} +- "
              f"{r.distance_sq_se:.4f} against the scatter's {r.replica_noise ** 2:.4f}; "
              f"E/cell {r.energy_difference_pct:+.2f}%")
    if a.out:
        write_text(a.out, table.to_csv(index=False, float_format="%.5g"))
    return 0


if __name__ == "__main__":
    sys.exit(main())
