"""Scene convergence: how the fields change with depth (layers) and box size (cells).

For moulds of the default scene, simulates with the hybrid solver at depths 1.5, 2, 3, 4 l0
(3, 3, 5, 6 layers) and compares the normalised fields (field / P * N_p / N_c not needed: we
compare P-normalised means and the per-pixel MAE of each field against depth 4). Box size:
the same mould scaled to the paper box (paper scene) vs default, compared on the default grid.
Run: OPENBLAS_NUM_THREADS=1 python benchmarks/bench_scene_convergence.py [--quick]
"""

import argparse
import csv
from pathlib import Path

import numpy as np

from condor.fields import cell_fields
from condor.moulds import generate_mould
from condor.scenes import get_scene
from condor.simulate import simulate

CHANNELS = ["P", "T", "Sx2", "Sy2", "Sz2", "SxSy", "SxSz", "SySz"]


def per_cell_fields(result, scene):
    f = cell_fields(result.positions, result.orientations, result.tension, scene.box,
                    scene.pixels, scene.sigma)
    return f / max(result.n_cells, 1)  # per cell, so different depths compare


def main():
    ap = argparse.ArgumentParser()
    ap.add_argument("--quick", action="store_true")
    a = ap.parse_args()
    scene = get_scene("default")
    depths = [2.0, 3.0, 4.0] if a.quick else [1.5, 2.0, 3.0, 4.0]
    n_moulds = 1 if a.quick else 3
    rows = []
    for mould_id in range(n_moulds):
        m = generate_mould(0, mould_id, scene.box)
        fields = {}
        for depth in depths:
            r = simulate(m.polygon, m.tethers, depth, "hybrid", seed=0)
            fields[depth] = (per_cell_fields(r, scene), r)
        ref, ref_r = fields[4.0]
        for depth, (f, r) in fields.items():
            mae = np.abs(f - ref).mean(axis=(1, 2)) / np.abs(ref).mean(axis=(1, 2))
            row = dict(mould=mould_id, depth=depth, n_cells=r.n_cells, seconds=r.seconds,
                       energy_per_cell=r.energy_per_cell, status=r.status,
                       mean_tension=float(r.tension[~r.fixed].mean()),
                       mean_sz2=float((r.orientations[~r.fixed, 2] ** 2).mean()))
            row.update({f"relMAE_{c}": float(v) for c, v in zip(CHANNELS, mae)})
            rows.append(row)
            print(" ".join(f"{k}={v:.4g}" if isinstance(v, float) else f"{k}={v}" for k, v in row.items()))
    out = Path("results/benchmarks")
    out.mkdir(parents=True, exist_ok=True)
    with open(out / "scene_convergence.csv", "w", newline="") as fh:
        w = csv.DictWriter(fh, fieldnames=rows[0].keys())
        w.writeheader()
        w.writerows(rows)


if __name__ == "__main__":
    main()
