"""Does the surrogate's own predicted scatter tell the moulds it gets wrong better than the
novelty score? (experiments/generalisation/README.md, "The predicted scatter as a verdict").

A mould's error is "above one simulation's scatter" when its squared error against the
expected fields exceeds one simulation's (novelty.py's `bad`). Where that scatter is small
(moulds held tightly by their posts) the bar is low. The surrogate predicts the scatter: its
spread map, whose RMS over the tissue pixels (raw units, cells a pixel) this calls its
reproducibility; novelty.py scores one over it, `inverse_spread`
(condor.surrogate.novelty.inverse_spread), for every model x test mould of its table
(`--table`, e.g. rim_n500/novelty_moulds.csv). From that table this gives each score's AUROC
for `bad`, the share caught at 20% false alarms and the false alarms at 90% caught
(novelty.py's `flagging`), over every pair, the held-out kinds' moulds and each held-out kind:

- the feature distance (the verdict's score until f1402e7);
- 1 / reproducibility, `inverse_spread` (a tight predicted scatter: likely above it);
- their product's log, log(feature distance) - log(reproducibility).

  python experiments/generalisation/spread_verdict.py \
      --table experiments/generalisation/rim_n500/novelty_moulds.csv \
      --out experiments/generalisation/rim_n500/spread_verdict.csv
"""

from __future__ import annotations

import argparse
import sys
from pathlib import Path

import numpy as np
import pandas as pd

from novelty import flagging  # noqa: E402  (this folder's novelty.py)


def main(argv=None) -> int:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--table", type=Path, required=True, help="novelty.py's novelty_moulds.csv")
    ap.add_argument("--out", type=Path, required=True)
    a = ap.parse_args(argv)
    rows = pd.read_csv(a.table)
    if "inverse_spread" not in rows:
        raise SystemExit(f"{a.table} has no inverse_spread column: novelty.py writes it since "
                         "a0e3c13")
    rows["reproducibility"] = 1.0 / rows["inverse_spread"]
    rows["feature_over_spread"] = (np.log(rows["feature_distance"])
                                   - np.log(rows["reproducibility"]))
    scores = ("feature_distance", "inverse_spread", "feature_over_spread")
    summary = []
    for scope, part in [("every model x test mould", rows),
                        ("moulds of the held-out kinds", rows[rows["held_out_mould"]]),
                        *[(f"held out {h}", g) for h, g in rows.groupby("held_out")]]:
        for score in scores:
            summary.append({"scope": scope, "score": score,
                            **flagging(part[score].to_numpy(float),
                                       part["bad"].to_numpy(bool))})
    summary = pd.DataFrame(summary)
    a.out.parent.mkdir(parents=True, exist_ok=True)
    summary.to_csv(a.out, index=False)
    rows.to_csv(a.out.with_name(a.out.stem + "_moulds.csv"), index=False)
    print(summary.round(3).to_string(index=False))
    return 0


if __name__ == "__main__":
    sys.exit(main())
