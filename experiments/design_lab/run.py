"""Design within a lab family: does the surrogate rank a family's moulds as simulation does?

`condor design --mould` searches moulds near the user's, and its value is in the ranking. For
each family named, --moulds moulds of the family (condor.moulds.lab, a seed no run uses, so
never trained on) are predicted with the checkpoint and simulated --replicas times each with
the product's solver; the objective (a design spec, condor.design.objectives) of the predicted
fields is compared with the replica-mean's: Spearman with its 95% bootstrap interval over
moulds, Pearson, bias (condor.design.confirm.agreement), and the replicas' own rank ceiling
(the Spearman of one replica's objective against the others' mean, averaged over replicas).

    python experiments/design_lab/run.py --checkpoint results/models/unet.pt \\
        --families strip dogbone cross --moulds 12 --replicas 4 --objective alignment:x

writes design_lab.csv (one row a family) and design_lab_moulds.csv (every mould: predicted and
simulated objective, the replicas' standard deviation) to --out.
"""

from __future__ import annotations

import argparse
import os
import sys
import time
from concurrent.futures import ProcessPoolExecutor
from pathlib import Path

os.environ.setdefault("OPENBLAS_NUM_THREADS", "1")

import numpy as np  # noqa: E402
import pandas as pd  # noqa: E402

from condor.design.confirm import agreement, simulate_designs, spearman  # noqa: E402
from condor.design.objectives import parse_objective  # noqa: E402
from condor.moulds.lab import FAMILY_NAMES, lab_mould  # noqa: E402
from condor.moulds.mould import input_channels  # noqa: E402
from condor.stages.predict import checkpoint_scene  # noqa: E402
from condor.surrogate.predict import Predictor  # noqa: E402

HERE = Path(__file__).resolve().parent
SEED = 31337  # a mould seed no run uses


def log(line: str) -> None:
    print(f"{time.strftime('%H:%M:%S')} {line}", flush=True)


def replica_rank_ceiling(replicas: pd.DataFrame) -> float:
    """How well one replica ranks the moulds as the others' mean does (the Spearman of a
    replica's objective against the mean of the rest, averaged over replica indices)."""
    table = replicas.pivot_table(index="mould_id", columns="replica", values="objective")
    values = []
    for r in table.columns:
        rest = table.drop(columns=r).mean(axis=1)
        values.append(spearman(table[r], rest))
    return float(np.nanmean(values))


def main(argv=None) -> int:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--checkpoint", type=Path, required=True)
    ap.add_argument("--families", nargs="+", choices=FAMILY_NAMES,
                    default=["strip", "dogbone", "cross"])
    ap.add_argument("--moulds", type=int, default=12, help="moulds a family")
    ap.add_argument("--replicas", type=int, default=4, help="simulations a mould")
    ap.add_argument("--objective", default="alignment:x", help="a design spec (docs/design.md)")
    ap.add_argument("--workers", type=int, default=2, help="simulations at a time")
    ap.add_argument("--out", type=Path, default=HERE)
    a = ap.parse_args(argv)
    predictor = Predictor(a.checkpoint, device="cpu")
    scene = checkpoint_scene(predictor)
    objective = parse_objective(a.objective, scene.pixels)
    rows, per_mould = [], []
    with ProcessPoolExecutor(a.workers) as pool:
        for family in a.families:
            moulds = [lab_mould(SEED, i, family, scene) for i in range(a.moulds)]
            inputs = np.stack([input_channels(m, predictor.native) for m in moulds])
            predicted = predictor(inputs, **predictor.mould_arguments(moulds))
            p = objective.evaluate(np.asarray(predicted.normalised, np.float64))["objective"]
            sims = simulate_designs(objective, moulds, scene, replicas=a.replicas, seed=SEED,
                                    map_fn=pool.map, progress=False)
            s = sims.table["objective"].to_numpy()
            stats = agreement(p.to_numpy(), s)
            rows.append({"family": family, "objective": objective.label, **stats,
                         "replicas": a.replicas,
                         "replica_rank_ceiling": replica_rank_ceiling(sims.replicas),
                         "simulated_range": float(np.nanmax(s) - np.nanmin(s)),
                         "replica_sd": float(np.nanmedian(sims.table["objective_std"]))})
            per_mould.append(pd.DataFrame({"family": family, "mould": range(a.moulds),
                                           "predicted": p.to_numpy(), "simulated": s,
                                           "replica_sd": sims.table["objective_std"]}))
            log(f"{family}: Spearman {stats['spearman']:.3f} "
                f"[{stats['spearman_low']:.3f}, {stats['spearman_high']:.3f}], "
                f"replicas' own {rows[-1]['replica_rank_ceiling']:.3f}")
    a.out.mkdir(parents=True, exist_ok=True)
    table = pd.DataFrame(rows)
    table.to_csv(a.out / "design_lab.csv", index=False)
    pd.concat(per_mould, ignore_index=True).to_csv(a.out / "design_lab_moulds.csv", index=False)
    print(table.round(3).to_string(index=False))
    return 0


if __name__ == "__main__":
    sys.exit(main())
