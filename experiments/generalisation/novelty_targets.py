"""What each novelty score tells, beyond the field error above the scatter (novelty.py's target):
whether a mould is of a kind its model never trained on, and how far off its mean tension is.
Reads novelty_moulds.csv (novelty.py's, the five leave-one-kind-out models x every test mould)
and prints, per score, the AUROC of three targets and the Spearman correlation with the mean
tension's |log ratio| (experiments/generalisation/README.md, "What the scores tell"); and the
descriptor distance's threshold for "a kind of mould it never trained on": the one that catches
the most moulds of the held-out kinds at no more than MAX_FALSE_ALARMS of the trained-on
moulds'. With --cache (run.py's, holding the five models), that threshold is tried family by
family on FRESH_MOULDS new moulds of each family (seed FRESH_SEED), under each model.

  python experiments/generalisation/novelty_targets.py [--cache CACHE]
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
MAX_FALSE_ALARMS = 0.2  # issue 41's goal for a domain verdict: at most 20% false alarms
FRESH_SEED, FRESH_MOULDS = 99, 16  # the per-family check's new moulds


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
    ap.add_argument("--cache", type=Path, default=None,
                    help="run.py's cache: try the threshold family by family on new moulds")
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
    choice = kind_threshold(d["descriptor_distance"], d["held_out_mould"])
    print(f"descriptor distance above {choice['threshold']:.3g}: {choice['caught']:.0%} of the "
          f"held-out kinds' moulds caught at {choice['false_alarms']:.0%} false alarms")
    if a.cache is not None:
        print(per_family(a.cache, choice["threshold"]).to_string())
    return 0


def per_family(cache: Path, threshold: float) -> pd.DataFrame:
    """Share of FRESH_MOULDS new moulds of each family above `threshold` (the descriptor
    distance to each leave-one-kind-out model's training moulds), by model."""
    from condor.model.scenes import get_scene
    from condor.moulds.lab import FAMILY_NAMES, lab_mould
    from condor.moulds.paper import generate_mould
    from condor.surrogate.novelty import bank_of, descriptors, knn_distance
    from condor.surrogate.predict import Predictor

    from run import KINDS

    scene = get_scene("default")
    ids = range(100, 100 + FRESH_MOULDS)
    moulds = {f: [lab_mould(FRESH_SEED, i, f, scene) for i in ids] for f in FAMILY_NAMES}
    moulds["paper"] = [generate_mould(FRESH_SEED, i, scene) for i in ids]
    table = {}
    for kind in KINDS:
        name = f"without_{'_'.join(kind)}"
        path = sorted(cache.glob(f"{name}_e120_*.pt"))[-1]
        bank = bank_of(Predictor(path, device="cpu").state)["descriptors"]
        table[name] = {f"{f}{' (held out)' if f in kind else ''}":
                       float((knn_distance(bank, np.stack([descriptors(m) for m in ms]))
                              > threshold).mean()) for f, ms in moulds.items()}
    return pd.DataFrame(table).round(2)


if __name__ == "__main__":
    sys.exit(main())
