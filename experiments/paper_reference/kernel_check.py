"""The strips kernel (`strips-2026-12`) against the former one (`ball-2026-12`) at the default
scene: its 1e5 rung (a study's own product, run.py --product) against the shipped 1e5 and 1e6
rungs, which the former kernel made, with the ladder's estimator (noise-corrected distance of
the ensemble means, one simulation's scatter, s_x^2, s_y^2, s_z^2 and E/cell differences).

  python experiments/paper_reference/run.py --scene default --moulds 468 302 27 128 \\
      --rungs 1e5 --runs 3 --cache CACHE --product FOLDER
  python experiments/paper_reference/kernel_check.py --folder FOLDER --moulds 468 302 27 128

writes experiments/paper_reference/kernel_check_default.csv.
"""

from __future__ import annotations

import argparse
import sys
from pathlib import Path

import pandas as pd

from condor.measures.estimators import pad_replicas
from condor.model.scenes import get_scene
from condor.studies.fidelity import fidelity_row
from condor.studies.paper_reference import reference_rung

HERE = Path(__file__).resolve().parent


def main(argv=None) -> int:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--folder", type=Path, required=True, help="the new kernel's product")
    ap.add_argument("--moulds", type=int, nargs="+", required=True)
    ap.add_argument("--seed", type=int, default=2026)
    ap.add_argument("--budget", type=float, default=1e5)
    a = ap.parse_args(argv)
    scene = get_scene("default")
    new = [reference_rung(scene, a.seed, m, a.budget, folder=a.folder) for m in a.moulds]
    rows = []
    for reference in (1e5, 1e6):
        shipped = [reference_rung(scene, a.seed, m, reference) for m in a.moulds]
        keep = [i for i in range(len(a.moulds)) if len(new[i][0]) >= 2 and len(shipped[i][0]) >= 2]
        if not keep:
            continue
        row = fidelity_row(f"strips-2026-12 anneal {a.budget:g}", scene.name,
                           f"ball-2026-12 anneal {reference:g}",
                           pad_replicas([new[i][0] for i in keep]),
                           pad_replicas([shipped[i][0] for i in keep]),
                           energy=pad_replicas([new[i][1] for i in keep]),
                           ref_energy=pad_replicas([shipped[i][1] for i in keep]))
        row["moulds"] = " ".join(str(a.moulds[i]) for i in keep)
        rows.append(row)
        print({k: row[k] for k in ("method", "reference", "distance", "distance_lo",
                                   "distance_hi", "replica_noise", "sz2_difference",
                                   "energy_difference_pct", "moulds")})
    out = HERE / "kernel_check_default.csv"
    pd.DataFrame(rows).to_csv(out, index=False, float_format="%.5g")
    print(f"wrote {out}")
    return 0


if __name__ == "__main__":
    sys.exit(main())
