"""What the surrogate reads of a mould, measured: the paper's 0/1 masks, their sub-pixel
coverage, the lattice channels (condor.data.inputs), or the lattice channels estimated from the
masks; the default variant otherwise, trained on the same moulds, scored against the expected
fields of the replica moulds, paired against the first kind (docs/surrogate.md "The inputs").

    PYTHONPATH=src python experiments/surrogate/inputs.py KIND --store STORE \\
        --moulds RESULTS/moulds --replicas REPLICAS.npz --out DIR [--settings JSON]
    PYTHONPATH=src python experiments/surrogate/inputs.py table --replicas REPLICAS.npz \\
        --out DIR mask coverage lattice estimated

KIND is mask | coverage | lattice | estimated | both (masks and lattice channels, 4 input
channels). The network reads the store variables of its TrainConfig.inputs; coverage and estimated replace the store's `lattice` in memory by
`condor.moulds.mould.input_channels(mould, pixels, 8)` and `condor.data.inputs.estimate_lattice_channels`
of the masks, so every kind runs the same code. Each run writes DIR/KIND.pt and
DIR/KIND_pred.npz (raw predictions of the replica moulds); `table` prints and writes
DIR/inputs_paired.csv (field error ratios against the first kind, bench_surrogate_paired's
estimator) and DIR/inputs.csv (bench_surrogate_study's figures for every kind).
Replicas come from experiments/surrogate/replicas.py --from-store.
"""

from __future__ import annotations

import argparse
import json
from pathlib import Path

import numpy as np
import pandas as pd
import torch
from study import (
    evaluate_checkpoint,  # experiments/surrogate/study.py: Python puts a script's folder on its path
)

from condor.data import inputs as model_inputs
from condor.data.dataset import open_dataset
from condor.moulds.mould import input_channels
from condor.stages.build import load_moulds
from condor.studies.scoring import (
    field_errors,
    paired_rows,
    predict_replica_moulds,
    study_dataset,
)
from condor.surrogate.samples import FIELD_NAMES, dataset_pixel_size
from condor.surrogate.train import train
from condor.surrogate.variants import train_config

KINDS = ("mask", "coverage", "lattice", "estimated", "both", "mechanics", "mechanics_shear")
# the workflow default's settings (config/config.yaml, variant unet) but for `inputs`
DEFAULT = {"model": "unet", "head": "physics", "loss": "gaussian", "upsample": "bilinear",
           "detach_spread": True, "base": 32, "n_dropout": 0, "epochs": 120,
           "lr_schedule": "cosine", "batch_size": 8, "lr": 0.002, "augment": True,
           "symmetrise": True}
SUPERSAMPLE = 8
READ_AS_IS = ("mask", "both", "mechanics", "mechanics_shear")  # the store's own inputs kinds


def inputs_of_kind(ds, kind: str, moulds_dir: str | None):
    """`ds` whose `lattice` variable holds what a network of `kind` reads."""
    if kind in READ_AS_IS + ("lattice",):  # the stress channels come from the masks
        return ds
    if kind == "estimated":
        scene = ds.attrs["scene"]
        channels = model_inputs.estimate_lattice_channels(
            ds["inputs"].values, dataset_pixel_size(ds), float(scene["depth"]),
            float(scene["sigma"]))
    else:
        if moulds_dir is None:
            raise SystemExit("coverage needs --moulds (the workflow's results/moulds folder)")
        moulds = {m.mould_id: m for f in sorted(Path(moulds_dir).glob("*.json"))
                  for m in load_moulds(f)}
        pixels = int(ds.sizes["x"])
        by_mould = {i: input_channels(moulds[i], pixels, SUPERSAMPLE)
                    for i in np.unique(ds["mould"].values)}
        channels = np.stack([by_mould[int(i)] for i in ds["mould"].values])
    return ds.assign(lattice=(ds["lattice"].dims, channels.astype(np.float32)))


def run(args) -> None:
    data = np.load(args.replicas)
    ds = inputs_of_kind(study_dataset(open_dataset(args.store), data["mould_ids"]), args.kind,
                        args.moulds)
    settings = {**DEFAULT, **json.loads(args.settings or "{}"), "num_threads": args.threads,
                "inputs": args.kind if args.kind in READ_AS_IS else "lattice"}
    out = Path(args.out)
    out.mkdir(parents=True, exist_ok=True)
    checkpoint = out / f"{args.kind}.pt"
    train(ds, train_config(settings, int(ds.sizes["x"])), checkpoint,
          log=lambda line: print(args.kind, line, flush=True))
    raw = predict_replica_moulds(checkpoint, ds, data["mould_ids"])
    np.savez(out / f"{args.kind}_pred.npz", raw=raw.astype(np.float32))
    rows = evaluate_checkpoint(checkpoint, ds, args.replicas, ["eval"], [True])
    pd.DataFrame([{"kind": args.kind, **r} for r in rows]).to_csv(out / f"{args.kind}.csv",
                                                                  index=False)


def table(args) -> None:
    replicas = np.load(args.replicas)["fields"].astype(np.float64)
    out = Path(args.out)
    errors = [field_errors(np.load(out / f"{k}_pred.npz")["raw"].astype(np.float64), replicas)
              for k in args.kinds]
    paired = paired_rows(list(args.kinds), errors, FIELD_NAMES)
    paired.to_csv(out / "inputs_paired.csv", index=False)
    figures = pd.concat([pd.read_csv(out / f"{k}.csv") for k in args.kinds], ignore_index=True)
    figures.to_csv(out / "inputs.csv", index=False)
    cols = ["kind", "field_rms", "ceiling_rms", "P:rms", "T:rms", "mean_T:r", "mean_T:bias",
            "mean_T:bias_lo", "mean_T:bias_hi", "mean_Sx2:bias", "n_P_gt_0.2:r", "coverage_90",
            "spread_r"]
    print(figures[cols].round(4).to_string(index=False))
    print(paired[["reference", "checkpoint", "ratio", "ratio_lo", "ratio_hi", "P:ratio", "P:lo",
                  "P:hi", "T:ratio", "T:lo", "T:hi"]].round(3).to_string(index=False))


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("kind", choices=KINDS + ("table",))
    ap.add_argument("kinds", nargs="*", help="with table: the kinds, reference first")
    ap.add_argument("--store")
    ap.add_argument("--moulds", help="the workflow's moulds folder (for coverage)")
    ap.add_argument("--replicas", required=True)
    ap.add_argument("--out", required=True)
    ap.add_argument("--settings", help="JSON settings over the default's")
    ap.add_argument("--threads", type=int, default=1)
    args = ap.parse_args()
    torch.set_num_threads(args.threads)
    if args.kind == "table":
        table(args)
    elif args.store is None:
        ap.error("--store is required to train")
    else:
        run(args)


if __name__ == "__main__":
    main()
