"""What each novelty score tells, beyond the field error above the scatter (novelty.py's target):
whether a mould is of a kind its model never trained on, and how far off its mean tension is.
Reads novelty_moulds.csv (novelty.py's, the five leave-one-kind-out models x every test mould)
and prints, per score, the AUROC of three targets and the Spearman correlation with the mean
tension's |log ratio| (experiments/generalisation/README.md, "What the scores tell").

  python experiments/generalisation/novelty_targets.py
"""

from __future__ import annotations

import argparse
import sys
from pathlib import Path

import numpy as np
import pandas as pd
from scipy.stats import mannwhitneyu, spearmanr

HERE = Path(__file__).resolve().parent
SCORES = ("feature_distance", "disagreement", "descriptor_distance")


def auroc(flag, score) -> float:
    """P(score of a flagged mould > score of an unflagged one), ties counted half."""
    flag, score = np.asarray(flag, bool), np.asarray(score, float)
    return float(mannwhitneyu(score[flag], score[~flag]).statistic / (flag.sum() * (~flag).sum()))


def main(argv=None) -> int:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--table", type=Path, default=HERE / "novelty_moulds.csv")
    a = ap.parse_args(argv)
    d = pd.read_csv(a.table)
    d = d[d["held_out"] != "none"]
    with np.errstate(invalid="ignore", divide="ignore"):
        d = d.assign(tension_error=np.abs(np.log(d["tension_ratio"])))
    d = d[np.isfinite(d["tension_error"])]
    rows = [{"score": s,
             "auroc_error_above_scatter": auroc(d["bad"], d[s]),
             "auroc_held_out_kind": auroc(d["held_out_mould"], d[s]),
             "auroc_tension_off_10pct": auroc(d["tension_error"] > 0.10, d[s]),
             "spearman_tension_error": float(spearmanr(d[s], d["tension_error"])[0])}
            for s in SCORES]
    print(f"{len(d)} model x mould pairs, {int(d['held_out_mould'].sum())} of a held-out kind")
    print(pd.DataFrame(rows).round(3).to_string(index=False))
    print("median |log tension ratio|, held-out kind / trained-on:",
          d.groupby("held_out_mould")["tension_error"].median().round(3).to_dict())
    return 0


if __name__ == "__main__":
    sys.exit(main())
