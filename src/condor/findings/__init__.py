"""Findings measured outside the workflow, shipped as data with their provenance.

`findings.json` names each finding: the question it answers, its numbers (a small table in
this folder, or `values` with the sentence they fill), the experiment folder that measured it
(experiments/<name>/, its script, data and README) and the commit it ran at. The report reads
them from here; nothing in the library states a measured number as prose.
"""

from __future__ import annotations

import json
from dataclasses import dataclass, field
from pathlib import Path

import pandas as pd

from condor.files import write_text

HERE = Path(__file__).resolve().parent


@dataclass(frozen=True)
class Finding:
    """One finding: `key`, the question, where it was measured (experiment folder, source
    table, commit), and its numbers (`values`, or `table` in this folder)."""

    key: str
    question: str
    experiment: str
    source: str
    commit: str
    statement: str = ""
    values: dict = field(default_factory=dict)
    table: str = ""
    folder: Path = HERE  # where `table` lies: the findings.json's own folder

    @property
    def provenance(self) -> str:
        return f"{self.experiment} at {self.commit}; {self.source}"

    def frame(self) -> pd.DataFrame:
        """The finding's table (ValueError when it has none)."""
        if not self.table:
            raise ValueError(f"finding {self.key!r} has no table")
        return pd.read_csv(self.folder / self.table)

    def sentence(self) -> str:
        """The statement with its values filled in, and its provenance."""
        if not self.statement:
            raise ValueError(f"finding {self.key!r} has no statement")
        return f"{self.statement.format(**self.values)} ({self.provenance})"


# Columns a finding's table must hold, for the findings the product reads by key.
OUT_OF_DOMAIN_COLUMNS = ("kind", "outside_on", "description", "n_moulds", "replicas", "z", "z_lo",
                         "z_hi", "spread_ratio", "spread_ratio_lo", "spread_ratio_hi",
                         "coverage_90", "coverage_90_lo", "coverage_90_hi", "field_error",
                         "field_error_lo", "field_error_hi", "noise_ceiling")
# One row per statistic with a drawn spread: its calibration factor (condor.surrogate.answer
# .spread_factors) and the checkpoint it was fitted for.
SPREAD_CALIBRATION_COLUMNS = ("statistic", "factor", "factor_lo", "factor_hi", "n_moulds",
                              "replicas", "weights_sha256")
# The novelty score's calibration (condor.surrogate.novelty.novelty_verdict; fitted by
# experiments/generalisation/novelty.py on the families held out): per score bin, the measured
# error over one simulation's scatter (median and 10-90% range) and the share above 1; the
# finding's values hold the `threshold` above which a mould is called outside.
NOVELTY_COLUMNS = ("score_lo", "score_hi", "n_moulds", "ratio_median", "ratio_lo", "ratio_hi",
                   "share_above_ceiling")
# Generalisation to lab families held out of training (issue 41's table, docs/data/
# generalisation.csv): per family scored, the model's error against the expected fields with
# its 95% interval, the family's noise ceiling, and the mean tension bias with its interval.
GENERALISATION_COLUMNS = ("family", "held_out", "n_moulds", "replicas", "error", "error_lo",
                          "error_hi", "noise_ceiling", "tension_bias", "tension_bias_lo",
                          "tension_bias_hi")
# Kinds of mould that no training source draws (experiments/unseen_kinds): a default run's
# checkpoint checked by simulation on each mould, one row a mould.
NEVER_DRAWN_COLUMNS = ("kind", "variant", "replicas", "error", "ceiling", "ratio",
                       "tension_bias")
# What a check of a few simulations reads, against the truth (experiments/check_verdict): per bin
# of the check's ratio (the prediction's error against the simulations' mean over their scatter),
# the moulds checked and how many lay above one simulation's scatter by 8 more simulations; the
# finding's values hold the `threshold` at or above which predict flags a mould and `n_check`.
CHECK_VERDICT_COLUMNS = ("ratio_lo", "ratio_hi", "n_moulds", "n_above", "share_above")
TABLE_COLUMNS = {"out_of_domain": OUT_OF_DOMAIN_COLUMNS, "never_drawn": NEVER_DRAWN_COLUMNS,
                 "check_verdict": CHECK_VERDICT_COLUMNS,
                 "spread_calibration": SPREAD_CALIBRATION_COLUMNS,
                 "novelty": NOVELTY_COLUMNS, "generalisation": GENERALISATION_COLUMNS}
# Values a finding must state, for the findings the product reads by key.
VALUE_KEYS = {"novelty": ("threshold", "score"), "check_verdict": ("threshold", "n_check")}


def load_findings(path=HERE / "findings.json") -> dict[str, Finding]:
    """Every finding of `path` by key; ValueError naming a finding that lacks its provenance,
    whose table is missing, whose table lacks a column the product reads (TABLE_COLUMNS;
    the out-of-domain table also needs its "inside" row), or that lacks a value the product
    reads (VALUE_KEYS)."""
    raw = json.loads(Path(path).read_text())
    folder = Path(path).resolve().parent
    findings = {}
    for key, entry in raw.items():
        missing = [k for k in ("question", "experiment", "source", "commit") if not entry.get(k)]
        if missing:
            raise ValueError(f"finding {key!r} lacks {missing}")
        if not entry.get("table") and not entry.get("statement"):
            raise ValueError(f"finding {key!r} has neither a table nor a statement")
        if entry.get("table") and not (folder / entry["table"]).is_file():
            raise ValueError(f"finding {key!r}: no table {entry['table']!r}")
        findings[key] = Finding(key=key, folder=folder, **entry)
        if key in TABLE_COLUMNS:
            if not entry.get("table"):
                raise ValueError(f"finding {key!r} needs a table")
            frame = findings[key].frame()
            absent = [c for c in TABLE_COLUMNS[key] if c not in frame.columns]
            if absent:
                raise ValueError(f"finding {key!r}: table {entry['table']!r} lacks columns "
                                 f"{absent}")
            if key == "out_of_domain" and "inside" not in set(frame["kind"]):
                raise ValueError(f"finding {key!r}: table {entry['table']!r} has no 'inside' row")
        absent = [k for k in VALUE_KEYS.get(key, ()) if k not in entry.get("values", {})]
        if absent:
            raise ValueError(f"finding {key!r} lacks the values {absent}")
    return findings


def record_finding(key: str, entry: dict, table: pd.DataFrame | None = None,
                   float_format: str | None = "%.6g", path=HERE / "findings.json") -> None:
    """Ship one finding, as a study's script does: `table` (if given) written to entry["table"]
    beside `path`, then `entry` set under `key` in `path`, each file whole or not at all.
    Raises ValueError, writing nothing, for an entry that lacks its provenance."""
    missing = [k for k in ("question", "experiment", "source", "commit") if not entry.get(k)]
    if missing or (table is not None and not entry.get("table")):
        raise ValueError(f"finding {key!r} lacks {missing or ['table']}")
    path = Path(path)
    if table is not None:
        write_text(path.parent / entry["table"], table.to_csv(index=False,
                                                              float_format=float_format))
    findings = json.loads(path.read_text())
    findings[key] = entry
    write_text(path, json.dumps(findings, indent=1) + "\n")


def more_moulds_sentence(finding: Finding) -> str:
    """What the training-set study found for the orientation statistics, from its table: the
    orientation r of the default recipe, of more training moulds at the same epochs, and of
    longer training on the same moulds."""
    t = finding.frame().set_index("name")
    base = t[(t["n_train"] == t["n_train"].min()) & (t["epochs"] == t["epochs"].min())].iloc[0]
    more = t[(t["n_train"] == t["n_train"].max()) & (t["epochs"] == base["epochs"])].iloc[0]
    longer = t[(t["n_train"] == base["n_train"]) & (t["epochs"] == t["epochs"].max())].iloc[0]
    words = (f"Measured outside this run on {int(base['n_moulds'])} pooled test moulds, the "
             f"orientation r (mean Sx2 / Sy2) rises with more training moulds "
             f"({int(base['n_train']):,} -> {int(more['n_train']):,} at {int(base['epochs'])} "
             f"epochs: {base['mean_Sx2:r']:.3f} / {base['mean_Sy2:r']:.3f} -> "
             f"{more['mean_Sx2:r']:.3f} / {more['mean_Sy2:r']:.3f}) and not with longer "
             f"training ({int(longer['epochs'])} epochs: {longer['mean_Sx2:r']:.3f} / "
             f"{longer['mean_Sy2:r']:.3f})")
    return f"{words} ({finding.provenance})."

