"""Simulator speed/accuracy (rules tradeoff_mould, tradeoff) and the scene convergence study
(rule convergence): condor.tradeoff and condor.costchart do the work."""
import logging

import numpy as np
import pandas as pd

from condor import costchart, tradeoff
from condor.config import scene_of
from condor.pipeline import load_moulds, setup_logging

setup_logging(snakemake.log[0])
log = logging.getLogger("condor").info
scene = scene_of(snakemake.config)


def mould_from(path, mould_id):
    return next(m for m in load_moulds(path) if m.mould_id == int(mould_id))


if snakemake.rule == "tradeoff_mould":
    s = snakemake.params.settings
    mould = mould_from(snakemake.input[0], snakemake.wildcards.mould)
    df, fields = costchart.sweep_with_reference(
        scene, mould, s.get("anneal_budgets", (10, 100, 1000)), s.get("seeds", (1,)),
        s.get("reference_budget", 1e4), log=log)
    log(f"reference reproduced to E/cell rel. {df['reference_check'].iloc[0]:.2e}")
    df.to_csv(snakemake.output.table, index=False)
    np.savez_compressed(snakemake.output.reference, fields=fields, mould=mould.mould_id)
elif snakemake.rule == "tradeoff":
    df = pd.concat([pd.read_csv(p) for p in snakemake.input], ignore_index=True)
    df.to_csv(snakemake.output.table, index=False)
    summary = tradeoff.summary(df)
    summary.to_csv(snakemake.output.summary, index=False)
    tradeoff.chart(df, snakemake.output.chart)
    log("\n" + summary.to_string(index=False))
else:  # convergence
    s = snakemake.params.settings
    mould = mould_from(snakemake.input[0], snakemake.params.mould)
    df = tradeoff.convergence(scene, moulds=[mould], seeds=(0, 1),
                              depths=tuple(s.get("convergence_depths", (2.0, 3.0, 4.0))),
                              box_scales=tuple(s.get("convergence_box_scales", (1.0, 2.0))),
                              log=log)
    df.to_csv(snakemake.output.table, index=False)
    summary = tradeoff.convergence_summary(df)
    summary.to_csv(snakemake.output.summary, index=False)
    tradeoff.convergence_chart(df, snakemake.output.chart)
    log("\n" + summary.to_string(index=False))
