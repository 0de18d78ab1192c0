"""Ship the paper scene's fidelity as the product reads it: docs/data/fidelity.csv's paper rows
(the dataset's solver and the quench against the 1e6 rung, over all 8 fields and over the six
even under z -> depth - z) and the finding `paper_fidelity` (src/condor/findings), which the
report shows with the ladder beside it.

  python experiments/fast_sampler/ship_paper.py --commit COMMIT \
      --solvers experiments/fast_sampler/paper_seven_1e6.csv \
      --solvers-even experiments/fast_sampler/paper_seven_even_1e6.csv \
      --ladder experiments/paper_reference/ladder_paper_six_1e6.csv \
      --ladder-even experiments/paper_reference/ladder_paper_six_even_1e6.csv

--solvers (--solvers-even): run.py's table of the dataset's recipe (relax:...) and the quench
against the 1e6 rung (with --z-symmetric), every run of it with --more-runs (--reference-runs
names how many a mould, for the finding's source); --ladder (--ladder-even): tables.py's 1e5 against
1e6, run k against run k (with --z-symmetric).
"""

from __future__ import annotations

import argparse
import sys
from pathlib import Path

import pandas as pd

from condor.files import write_text
from condor.findings import record_finding

HERE = Path(__file__).resolve().parent
REPO = HERE.parents[1]
FIDELITY = REPO / "docs" / "data" / "fidelity.csv"
QUENCH = "quench"
EVEN = "the six fields even under z -> depth - z"


def as_fidelity_rows(table: pd.DataFrame, reference: str, columns) -> pd.DataFrame:
    """run.py's rows as docs/data/fidelity.csv's `columns`: the method named by its solver, the
    recipe beside it (run.py names a method by its recipe)."""
    rows = table[table["scene"] == "paper"].copy()
    rows["recipe"] = rows["method"]
    rows["method"] = ["lbfgs" if m == QUENCH else "relaxed_anneal" for m in rows["recipe"]]
    rows["reference"] = reference
    rows = rows.sort_values("method", ascending=False, kind="stable")  # the dataset's first
    return rows[[c for c in columns if c in rows.columns]]


def where(path: Path) -> str:
    return path.resolve().relative_to(REPO).as_posix()


def finding_rows(tables: dict) -> pd.DataFrame:
    """One row each: the recipe, the quench and the ladder's 1e5 rung (in pairs) against the
    1e6 rung, over all 8 fields and over the six even ones: the distance with its 95% interval
    (lo, hi), one simulation's scatter, hi over the scatter (the bar: 0.5), and the cost in
    evaluations a mould and as a multiple of the quench's."""
    out = []
    for fields, (solvers, ladder) in tables.items():
        quench = float(solvers.loc[solvers["method"] == QUENCH, "evaluations_per_mould"].iloc[0])
        for what, frame in (("the dataset's solver", solvers[solvers["method"] != QUENCH]),
                            ("the quench", solvers[solvers["method"] == QUENCH]),
                            ("anneal 1e5, in pairs", ladder)):
            row = frame.iloc[0]
            evaluations = row.get("evaluations_per_mould")
            out.append({"what": what, "fields": fields, "moulds": int(row["n_moulds"]),
                        "runs": int(row["n_seeds"]), "distance": row["distance"],
                        "lo": row["distance_lo"], "hi": row["distance_hi"],
                        "scatter": row["replica_noise"],
                        "hi_per_scatter": row["distance_hi"] / row["replica_noise"],
                        "evaluations": (round(evaluations) if pd.notna(evaluations)
                                        else pd.NA),
                        "x_quench": evaluations / quench})
    frame = pd.DataFrame(out)
    frame["evaluations"] = frame["evaluations"].astype("Int64")
    return frame


def main(argv=None) -> int:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--commit", required=True, help="the commit the tables were measured at")
    for name in ("--solvers", "--solvers-even", "--ladder", "--ladder-even"):
        ap.add_argument(name, type=Path, required=True)
    ap.add_argument("--reference-runs", default="",
                    help="the 1e6 rung's runs the solvers' tables read, as the finding's source "
                         "should say (e.g. run.py --more-runs: '94: 7, 647: 4, ...')")
    a = ap.parse_args(argv)
    solvers, solvers_even, ladder, ladder_even = (
        pd.read_csv(p) for p in (a.solvers, a.solvers_even, a.ladder, a.ladder_even))
    if any(QUENCH not in set(t["method"]) for t in (solvers, solvers_even)):
        raise SystemExit("--solvers and --solvers-even need the quench beside the recipe")
    if not (solvers_even.get("z_symmetric", pd.Series([False])).all()
            and ladder_even.get("z_symmetric", pd.Series([False])).all()):
        raise SystemExit("--solvers-even and --ladder-even must be run with --z-symmetric")
    fidelity = pd.read_csv(FIDELITY)
    old = (fidelity["scene"] == "paper") & (fidelity["reference"].str.startswith("anneal 1e6")) \
        & fidelity["method"].isin(["relaxed_anneal", "lbfgs"])
    new = pd.concat([as_fidelity_rows(solvers, "anneal 1e6", fidelity.columns),
                     as_fidelity_rows(solvers_even, f"anneal 1e6, {EVEN}", fidelity.columns)])
    at = int(old.idxmax()) if old.any() else len(fidelity)
    kept = fidelity[~old]
    fidelity = pd.concat([kept.iloc[:at], new, kept.iloc[at:]], ignore_index=True)
    write_text(FIDELITY, fidelity.to_csv(index=False, float_format="%.5g"))
    table = finding_rows({"all 8": (solvers, ladder), "6 even": (solvers_even, ladder_even)})
    record_finding("paper_fidelity", {
        "question": "At the paper's own scene (config/paper.yaml: a 62.5 l0 box, about 9,300 "
                    "cells), how close do the dataset's solver (800 moves a cell) and the quench "
                    "come to the paper's anneal of 1e6 moves a cell, at what cost, and how far "
                    "does that anneal still move from 1e5 moves a cell? Over all 8 fields, and "
                    "over the six even under the slab's reflection (the tilt fields SxSz, SySz, "
                    "whose expectation is near 0 and whose noise dominates, left out).",
        "table": "paper_fidelity.csv",
        "experiment": "experiments/fast_sampler",
        "source": f"{where(a.solvers)}, {a.solvers_even.name}; {where(a.ladder)}, "
                  f"{a.ladder_even.name}: noise-corrected distance of the "
                  "ensemble means, RMS over the normalised fields (divided by all 8), 95% "
                  "bootstrap interval over moulds; one simulation's scatter; "
                  "evaluation-equivalents a mould"
                  + (f"; the 1e6 rung's runs a mould: {a.reference_runs}" if a.reference_runs
                     else ""),
        "commit": a.commit,
    }, table, float_format="%.4g")
    print(table.to_string(index=False))
    return 0


if __name__ == "__main__":
    sys.exit(main())
