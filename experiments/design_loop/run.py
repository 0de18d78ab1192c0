"""The whole design loop on a trained surrogate: search, confirmation by simulation, and the
comparison with the dataset's random test moulds (what `condor design` reports).

Prints the search's throughput, the confirmed designs (predicted against simulated objective
of the replica-mean fields) and the one-row summary: Spearman rho and bias with 95% bootstrap
intervals, the replicas' own rank-correlation ceiling, the best confirmed design against the
best test mould. --out writes the tables as CSV and the confirmed designs as a gallery.

    python experiments/design_loop/run.py --checkpoint model.pt --store results/dataset.zarr \
        --objective alignment:x --budget 2000 --n-top 5 --n-random 10 --replicas 2 --seed 0
"""

from __future__ import annotations

import argparse
import time
from pathlib import Path

import xarray as xr

from condor.design import (confirm_designs, dataset_baseline, default_space, design_table,
                           parse_objective, search_designs)
from condor.model.scenes import PRESETS
from condor.surrogate.predict import Predictor


def main():
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--checkpoint", required=True)
    parser.add_argument("--store", required=True, help="the dataset the checkpoint was trained on")
    parser.add_argument("--objective", default="alignment:x")
    parser.add_argument("--budget", type=int, default=2000)
    parser.add_argument("--n-top", type=int, default=5)
    parser.add_argument("--n-random", type=int, default=10)
    parser.add_argument("--replicas", type=int, default=2)
    parser.add_argument("--seed", type=int, default=0)
    parser.add_argument("--threads", type=int, default=1)
    parser.add_argument("--out", default=None)
    args = parser.parse_args()

    import torch

    torch.set_num_threads(args.threads)
    predictor = Predictor(args.checkpoint)
    scene = next(s for s in PRESETS.values()
                 if abs(s.box - predictor.box) < 1e-6 and s.pixels == predictor.native)
    objective = parse_objective(args.objective, pixels=predictor.native,
                                max_extent=scene.max_extent)
    space = default_space(scene, objective)
    result = search_designs(objective, space, predictor, budget=args.budget, seed=args.seed)
    print(f"scene {scene.name}, objective {objective.label}, space {space.symmetry} "
          f"(dim {space.dim}), seed {args.seed}: {result.evaluations} designs in "
          f"{result.seconds:.0f} s wall, {result.cpu_seconds:.0f} s CPU "
          f"({result.designs_per_cpu_minute:,.0f} per CPU minute)")
    baseline = dataset_baseline(objective, xr.open_zarr(args.store), split="test")
    start, cpu = time.perf_counter(), time.process_time()
    confirmation = confirm_designs(result, scene, n_top=args.n_top, n_random=args.n_random,
                           replicas=args.replicas, baseline=baseline)
    print(f"confirmation: {len(confirmation.simulated.replicas)} simulations in "
          f"{time.perf_counter() - start:.0f} s wall, {time.process_time() - cpu:.0f} s CPU")
    columns = ["design", "role", "predicted_objective", "simulated_objective",
               "simulated_objective_std", "n_tethers"]
    print(confirmation.table[columns].to_string(index=False))
    print(confirmation.summary.T.to_string(header=False))
    if args.out:
        out = Path(args.out)
        out.mkdir(parents=True, exist_ok=True)
        design_table(result, confirmation).to_csv(out / "designs.csv", index=False)
        confirmation.summary.to_csv(out / "summary.csv", index=False)
        baseline.to_csv(out / "baseline.csv", index=False)
        from condor.plots import mould_gallery

        mould_gallery(result.moulds(confirmation.table["design"]), out / "confirmed.png")


if __name__ == "__main__":
    main()
