"""What a check's reading says of a mould: the check's ratio binned against the truth's, and the
threshold above which `condor predict` says the surrogate may be off (issue 41's goal: catch
90% of the moulds above one simulation's scatter at no more than 20% false alarms).

From run.py's table (one row a mould and N; the check's ratio `check_ratio` from N simulations,
the truth's `truth_ratio` from 8 others):

- per bin of the check's ratio (EDGES): the moulds in it, how many lie above one simulation's
  scatter by the truth, and the truth's ratio there (median, 10-90%);
- the threshold: the highest of the bins' inner edges at which flagging every mould whose check
  reads at or above it catches at least 90% of the moulds above the scatter;
- how that rule does on moulds it did not see: the moulds split in halves at random (SPLITS
  times), the rule chosen on one half and scored on the other (median and 95% range).

    python experiments/check_verdict/calibrate.py \\
        --table experiments/check_verdict/check_verdict.csv \\
        --out experiments/check_verdict/calibration.csv [--ship COMMIT]

--ship writes the `check_verdict` finding (condor.findings) that `condor predict` reads.
"""

from __future__ import annotations

import argparse
from pathlib import Path

import numpy as np
import pandas as pd

from condor.files import write_text
from condor.findings import record_finding

EDGES = (0.0, 0.6, 0.8, 1.0, 1.2, np.inf)  # bins of the check's ratio, fixed before looking
CATCH = 0.9  # the share of the moulds above the scatter the threshold must flag
SPLITS = 200


def bins(table: pd.DataFrame) -> pd.DataFrame:
    """One row a bin of EDGES: ratio_lo, ratio_hi, n_moulds, n_above, share_above and the
    truth's ratio (median, 10% and 90%) of the moulds whose check read within it."""
    rows = []
    for lo, hi in zip(EDGES[:-1], EDGES[1:]):
        inside = table[(table.check_ratio >= lo) & (table.check_ratio < hi)]
        truth = inside.truth_ratio
        rows.append({"ratio_lo": lo, "ratio_hi": hi, "n_moulds": len(inside),
                     "n_above": int((truth > 1).sum()),
                     "share_above": float((truth > 1).mean()) if len(inside) else np.nan,
                     "truth_median": truth.median(), "truth_lo": truth.quantile(0.1),
                     "truth_hi": truth.quantile(0.9)})
    return pd.DataFrame(rows)


def threshold(table: pd.DataFrame) -> float:
    """The highest inner edge t of EDGES at which `check_ratio >= t` flags at least CATCH of the
    moulds whose truth_ratio exceeds 1 (the lowest inner edge when none does)."""
    above = table.truth_ratio > 1
    for t in sorted(EDGES[1:-1], reverse=True):
        if (table.check_ratio[above] >= t).sum() >= CATCH * above.sum():
            return float(t)
    return float(EDGES[1])


def rates(table: pd.DataFrame, t: float) -> tuple[float, float]:
    """(the share of the moulds above the scatter flagged at t, the share of the others)."""
    above, flagged = table.truth_ratio > 1, table.check_ratio >= t
    return float(flagged[above].mean()), float(flagged[~above].mean())


def held_out_rates(table: pd.DataFrame, splits: int = SPLITS, seed: int = 0) -> np.ndarray:
    """(caught, false alarms) of the threshold chosen on one random half and scored on the
    other, both ways round, `splits` times: (2 splits, 2)."""
    rng, out = np.random.default_rng(seed), []
    for _ in range(splits):
        order = rng.permutation(len(table))
        halves = table.iloc[order[:len(table) // 2]], table.iloc[order[len(table) // 2:]]
        for fit, score in (halves, halves[::-1]):
            out.append(rates(score, threshold(fit)))
    return np.array(out)


def main(argv=None) -> int:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--table", type=Path, required=True, help="run.py's table")
    ap.add_argument("--n-check", type=int, default=4, help="the check's simulations (AUTO_CHECK)")
    ap.add_argument("--out", type=Path, required=True)
    ap.add_argument("--ship", metavar="COMMIT", help="write the check_verdict finding, "
                    "measured at COMMIT")
    a = ap.parse_args(argv)
    table = pd.read_csv(a.table)
    table = table[table.n_check == a.n_check]
    if table.empty:
        raise SystemExit(f"{a.table} holds no rows of --n-check {a.n_check}")
    calibration = bins(table)
    t = threshold(table)
    caught, false_alarms = rates(table, t)
    held = held_out_rates(table)
    values = {"threshold": t, "n_check": a.n_check, "caught": caught,
              "false_alarms": false_alarms, "n_bad": int((table.truth_ratio > 1).sum()),
              "n_good": int((table.truth_ratio <= 1).sum()),
              "caught_held_out": float(np.median(held[:, 0])),
              "caught_held_out_lo": float(np.percentile(held[:, 0], 2.5)),
              "caught_held_out_hi": float(np.percentile(held[:, 0], 97.5)),
              "false_alarms_held_out": float(np.median(held[:, 1])),
              "false_alarms_held_out_lo": float(np.percentile(held[:, 1], 2.5)),
              "false_alarms_held_out_hi": float(np.percentile(held[:, 1], 97.5))}
    write_text(a.out, calibration.to_csv(index=False, float_format="%.5g"))
    print(calibration.to_string(index=False))
    print({k: round(v, 3) if isinstance(v, float) else v for k, v in values.items()})
    if a.ship:
        record_finding("check_verdict", {
            "question": "How often does a mould lie above one simulation's scatter, given what "
                        f"a check of {a.n_check} simulations reads (the prediction's error "
                        "against their mean over their scatter)?",
            "table": "check_verdict.csv",
            "experiment": "experiments/check_verdict",
            "source": f"experiments/check_verdict/calibrate.py --table {a.table} (run.py: "
                      f"{len(table)} moulds, each checked by {a.n_check} simulations and scored "
                      "against 8 others; flagged at or above the threshold, the highest bin "
                      f"edge that catches {CATCH:.0%} of the moulds above the scatter)",
            "commit": a.ship, "values": values}, calibration, float_format="%.5g")
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
