"""Ship the study's results as the product reads them: docs/data/generalisation.csv (every
leave-one-kind-out model on every family scored), and two findings (src/condor/findings):
`generalisation` (each held-out family's row, and each model's rows on the paper test moulds
and the fresh seed's) and `novelty` (novelty_calibration.csv and the threshold chosen by
novelty.py, which `condor predict` reads).

  python experiments/generalisation/ship.py --commit COMMIT [--tables n450 --n-train 450 \
      --lab-share 0.44] [--extra-share 0.2] [--set noise_weight=1]

reads generalisation.csv, novelty.csv and novelty_calibration.csv of --tables (a folder of this
study: run.py's and novelty.py's outputs; this folder itself by default) and
novelty_choice.json (novelty.py's chosen score and threshold with its rates).
"""

from __future__ import annotations

import argparse
import json
import sys
from pathlib import Path

import pandas as pd

from condor.findings import GENERALISATION_COLUMNS, NOVELTY_COLUMNS, record_finding

HERE = Path(__file__).resolve().parent
REPO = HERE.parents[1]
FRESH = "fresh seed"


def held_out_rows(table: pd.DataFrame) -> pd.DataFrame:
    """Each model's rows on the families it never saw, then on the paper test moulds and the
    fresh seed's."""
    held = [f in h.split("+") for f, h in zip(table["family"], table["held_out"])]
    other = table["family"].isin(["paper", FRESH])
    return pd.concat([table[held], table[other]], ignore_index=True)


def main(argv=None) -> int:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--commit", required=True, help="the commit the study ran at")
    ap.add_argument("--tables", default=".", help="the folder of the tables, in this study's")
    ap.add_argument("--n-train", type=int, default=250, help="the models' training moulds")
    ap.add_argument("--lab-share", type=float, default=0.5, help="their lab share")
    ap.add_argument("--extra-name", default="COMPOSITE_RIM",
                    help="what the source line calls the extra store (composite_rim.yaml's: COMPOSITE_RIM)")
    ap.add_argument("--extra-share", type=float, default=0.0,
                    help="run.py's --extra-share: the share of composite moulds "
                         "(composite_rim.yaml's store) among their training moulds")
    ap.add_argument("--set", nargs="+", default=[], metavar="KEY=VALUE",
                    help="run.py's --set: the settings the models changed from the preset")
    a = ap.parse_args(argv)
    tables = (HERE / a.tables).resolve()
    where = tables.relative_to(REPO).as_posix()
    table = pd.read_csv(tables / "generalisation.csv")[list(GENERALISATION_COLUMNS)]
    (REPO / "docs" / "data").mkdir(exist_ok=True)
    table.to_csv(REPO / "docs" / "data" / "generalisation.csv", index=False)
    calibration = pd.read_csv(tables / "novelty_calibration.csv")[list(NOVELTY_COLUMNS)]
    choice = json.loads((tables / "novelty_choice.json").read_text())
    n_models = table["held_out"].nunique()
    extra = (f" --extra {a.extra_name} --extra-share {a.extra_share:g}" if a.extra_share else "")
    extra += f" --set {' '.join(a.set)}" if a.set else ""
    composite = (f" ({round(a.extra_share * a.n_train)} of them composite)" if a.extra_share
                 else "")
    record_finding("generalisation", {
        "question": "How close does the default recipe come to the expected fields on lab "
                    "families it never trained on (each kind of two kindred families held out "
                    "of training in turn), and on the paper's moulds and a fresh generator seed "
                    "beside them?",
        "table": "generalisation.csv",
        "experiment": "experiments/generalisation",
        "source": f"{where}/generalisation.csv (run.py --steps lofo --epochs 120 "
                  f"--n-train {a.n_train} --lab-share {a.lab_share:g}{extra}: {n_models} models "
                  f"of {a.n_train} training moulds, {a.lab_share:.0%} lab{composite}; 8 test "
                  "moulds a family x 4 replicas; error against the expected fields with the "
                  "noise removed, 95% intervals over moulds)",
        "commit": a.commit,
    }, held_out_rows(table), float_format=None)
    record_finding("novelty", {
        "question": ("How new is a mould to the surrogate, and how far off are its "
                     "predictions on moulds that new (the error over one simulation's scatter, "
                     "by novelty)?" if choice["score"] == "feature_distance" else
                     "Is the surrogate's error on a mould likely within one simulation's "
                     "scatter, read from how tight its own predicted scatter is (the error over "
                     "one simulation's scatter, by inverse_spread)?"),
        "table": "novelty.csv",
        "experiment": "experiments/generalisation",
        "source": f"{where}/novelty_calibration.csv (novelty.py: the "
                  f"{choice['score']} of {choice['n_moulds']} test moulds under the "
                  f"{n_models} leave-one-kind-out models; above the threshold"
                  + (" (the lowest that raises at most 20% false alarms)"
                     if choice["threshold"] < choice.get("threshold_median_rule", 0) else "")
                  + " "
                  f"{choice['caught']:.0%} of the moulds above one simulation's scatter are "
                  f"flagged, at {choice['false_alarms']:.0%} false alarms)",
        "commit": a.commit,
        "values": {k: choice[k] for k in ("score", "threshold", "caught", "false_alarms",
                                          "n_bad", "n_good")},
    }, calibration, float_format=None)
    print(f"wrote docs/data/generalisation.csv, findings generalisation and novelty "
          f"({choice['score']} above {choice['threshold']:.3g})")
    return 0


if __name__ == "__main__":
    sys.exit(main())
