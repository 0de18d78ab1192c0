"""The paper-reference ladder's table and the shipped data product, from the run cache.

  python experiments/paper_reference/tables.py --moulds 468 302 143 557 27 128 553 392 \
      --rungs 1e5 1e6 [--pack]

Writes experiments/paper_reference/ladder_<scene>.csv from the shipped data product
(src/condor/paper_reference/): for each rung below the top, its distance to
the next rung up (noise-corrected, RMS over the 8 normalised fields, bootstrap over moulds),
the replica noise of the upper rung, the cell-averaged orientations and energies, and
whether the pair is unresolved by the bar (upper 95% bound <= 0.5 x the noise). Run k of
every rung shares its seed (`reference_seed` does not depend on the budget), and the runs
stay alike from rung to rung, so the distance is the paired one (`paired_distance`;
`--unpaired`: the independent-ensemble estimator of the tables before 2026-12-07, biased low
here). Only moulds
with >= 2 finished runs at both rungs count. --pack first adds the run cache's finished runs
to src/condor/paper_reference/ (one .npz per mould, every run of every rung, each with its commit and
kernel); run.py does this itself as each run finishes.
"""

from __future__ import annotations

import argparse
import sys
from pathlib import Path

import pandas as pd

from condor.files import write_text
from condor.measures.estimators import pad_replicas
from condor.model.scenes import get_scene
from condor.studies.fidelity import fidelity_row
from condor.studies.paper_reference import (budget_tag, pack_mould, paired_rungs,
                                             reference_rung_from, run_provenance)

HERE = Path(__file__).resolve().parent
RUNGS_MOVED = HERE / "rung_1e5"  # the paper scene's 1e5 runs of moulds whose 1e6 rung is done

CACHE = HERE / "cache"  # run.py's default too


def main(argv=None) -> int:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--scene", default="default")
    ap.add_argument("--seed", type=int, default=2026)
    ap.add_argument("--moulds", type=int, nargs="+", required=True)
    ap.add_argument("--rungs", type=float, nargs="+", required=True)
    ap.add_argument("--runs", type=int, default=3)
    ap.add_argument("--pack", action="store_true")
    ap.add_argument("--cache", type=Path, default=CACHE)
    ap.add_argument("--out", type=Path, default=None,
                    help="write the table here (default: ladder_<scene>.csv beside this script)")
    ap.add_argument("--unpaired", action="store_true",
                    help="score the rungs as independent ensembles (the tables before "
                         "2026-12-07); by default run k of both is a pair, since it shares its "
                         "seed (estimators.paired_distance)")
    ap.add_argument("--z-symmetric", action="store_true",
                    help="score the rungs symmetrised under z -> depth - z, the tilt fields' "
                         "noise left out (studies.fidelity, docs/model.md)")
    ap.add_argument("--reference-folder", type=Path, default=None,
                    help="read the runs from this folder (run.py --product) instead of the "
                         "shipped product")
    a = ap.parse_args(argv)
    scene = get_scene(a.scene)
    rows = []
    rungs = sorted(a.rungs)
    if a.pack:
        for m in a.moulds:
            out = pack_mould(a.cache, scene, a.seed, m, rungs, a.runs,
                             run_provenance("experiments/paper_reference/run.py"))
            if out is not None:
                print(f"packed {out} ({out.stat().st_size / 1024:.0f} KiB)")
    folders = (a.reference_folder, RUNGS_MOVED)  # None: the shipped product
    for lower, upper in zip(rungs, rungs[1:]):
        if a.unpaired:  # every run of each rung, as the tables before 2026-12-07
            per = []
            for m in a.moulds:
                (lf, le), (uf, ue) = (reference_rung_from(scene, a.seed, m, b, folders)
                                      for b in (lower, upper))
                per.append((lf, uf, le, ue))
        else:  # the runs both rungs hold, run k against run k
            per = [paired_rungs(scene, a.seed, m, lower, upper, folders) for m in a.moulds]
        keep = [i for i, p in enumerate(per) if len(p[0]) >= 2 and len(p[1]) >= 2]
        if not keep:
            print(f"anneal {budget_tag(lower)} / {budget_tag(upper)}: no mould has 2 runs of both")
            continue
        row = fidelity_row(f"anneal {budget_tag(lower)}", scene.name,
                           f"anneal {budget_tag(upper)}",
                           *(pad_replicas([per[i][j] for i in keep]) for j in (0, 1)),
                           energy=pad_replicas([per[i][2] for i in keep]),
                           ref_energy=pad_replicas([per[i][3] for i in keep]),
                           paired=not a.unpaired, z_symmetric=a.z_symmetric)
        row["moulds"] = " ".join(str(a.moulds[i]) for i in keep)
        row["paired"] = not a.unpaired
        rows.append(row)
        print(row)
    if rows:
        out = a.out or HERE / f"ladder_{scene.name}.csv"
        write_text(out, pd.DataFrame(rows).to_csv(index=False, float_format="%.5g"))
        print(f"wrote {out}")
    return 0


if __name__ == "__main__":
    sys.exit(main())
