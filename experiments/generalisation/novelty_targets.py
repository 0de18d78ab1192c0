"""What each novelty score tells, beyond the field error above the scatter (novelty.py's target):
whether a mould is of a kind its model never trained on, and how far off its mean tension is.
Reads novelty_moulds.csv (novelty.py's, the five leave-one-kind-out models x every test mould)
and prints, per score, the AUROC of three targets and the Spearman correlation with the mean
tension's |log ratio| (experiments/generalisation/README.md, "What the scores tell"); and
chooses the descriptor distance's threshold for "a kind of mould it never trained on": the one
that catches the most moulds of the held-out kinds at no more than MAX_FALSE_ALARMS of the
trained-on moulds' (new_kind.json, which ship.py ships as the finding `new_kind`).

  python experiments/generalisation/novelty_targets.py
"""

from __future__ import annotations

import argparse
import json
import sys
from pathlib import Path

import numpy as np
import pandas as pd
from scipy.stats import mannwhitneyu, spearmanr

HERE = Path(__file__).resolve().parent
SCORES = ("feature_distance", "disagreement", "descriptor_distance")
MAX_FALSE_ALARMS = 0.2  # issue 41's goal for a domain verdict: at most 20% false alarms


def kind_threshold(score, new, max_false_alarms: float = MAX_FALSE_ALARMS) -> dict:
    """The threshold on `score` above which a mould is called a new kind: of the candidate
    thresholds (every score value), the lowest whose share of `new` False above it is at most
    `max_false_alarms`; with the share of `new` True it catches."""
    score, new = np.asarray(score, float), np.asarray(new, bool)
    for t in np.sort(score):
        false_alarms = float((score[~new] > t).mean())
        if false_alarms <= max_false_alarms:
            return {"threshold": float(t), "caught": float((score[new] > t).mean()),
                    "false_alarms": false_alarms, "n_new": int(new.sum()),
                    "n_known": int((~new).sum())}
    raise ValueError("no threshold meets the false-alarm limit")


def auroc(flag, score) -> float:
    """P(score of a flagged mould > score of an unflagged one), ties counted half."""
    flag, score = np.asarray(flag, bool), np.asarray(score, float)
    return float(mannwhitneyu(score[flag], score[~flag]).statistic / (flag.sum() * (~flag).sum()))


def main(argv=None) -> int:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--table", type=Path, default=HERE / "novelty_moulds.csv")
    ap.add_argument("--out", type=Path, default=HERE, help="where new_kind.json goes")
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
    choice = {"score": "descriptor_distance",
              **kind_threshold(d["descriptor_distance"], d["held_out_mould"])}
    (a.out / "new_kind.json").write_text(json.dumps(choice, indent=1) + "\n")
    print(f"new kind above {choice['threshold']:.3g}: {choice['caught']:.0%} of the held-out "
          f"kinds' moulds caught at {choice['false_alarms']:.0%} false alarms")
    return 0


if __name__ == "__main__":
    sys.exit(main())
