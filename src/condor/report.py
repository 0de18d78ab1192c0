"""The run's report as one self-contained HTML file (pure library: no Snakemake).

Building blocks (`figure`, `table`, `paragraph`, `folded`, `Section`, `render`) make any
report: PNGs are embedded as base64 data URIs, tables come from CSV files or DataFrames, every
figure and table has a caption, long galleries fold away (<details>), and a table of contents
links the sections. `condor_report` assembles the workflow's report from its output files
(named by REPORT_INPUTS): one screen of summary first (the dataset and its failures, the
cost-against-error chart, the surrogate's statistics beside the paper's), details after. A
section whose inputs are missing or empty raises ReportError instead of showing a placeholder.
"""

from __future__ import annotations

import base64
import datetime
import html
import shutil
import subprocess
from dataclasses import dataclass, field
from pathlib import Path

import numpy as np
import pandas as pd

from condor.version import __version__
from condor.findings import load_findings, more_moulds_sentence
from condor.data.store import open_store
from condor.measures.bars import MAX_BIAS, MIN_R, R_CEILING_SLACK, SAME_STATES

CSS = """
body{font-family:system-ui,sans-serif;max-width:1150px;margin:2em auto;padding:0 1em;color:#222}
h1{font-size:1.5em}h2{border-bottom:1px solid #ccc;padding-bottom:.2em;margin-top:2em}
figure{margin:1.2em 0}figure img{max-width:100%;border:1px solid #eee}
figcaption,caption{font-size:.9em;color:#444;text-align:left;margin:.3em 0}
table{border-collapse:collapse;font-size:.85em;margin:.8em 0}
td,th{border:1px solid #ddd;padding:.2em .5em;text-align:right}th{background:#f4f4f4}
td:first-child,th:first-child{text-align:left}nav li{margin:.15em 0}
.scroll{overflow-x:auto}
.meta{color:#666;font-size:.85em}
details{margin:.8em 0;border:1px solid #e4e4e4;border-radius:4px;padding:.3em .7em}
summary{cursor:pointer;font-weight:600;color:#08519c}
.verdict{background:#f5f9ff;border-left:4px solid #08519c;padding:.5em .9em;margin:1em 0}
.headline{font-size:1em;margin:.6em 0}.headline th{text-align:left;white-space:nowrap}
.headline td{text-align:left}nav{font-size:.9em;margin:.3em 0}h1{margin:.4em 0}
section#summary h2{margin-top:.6em}
.grid{display:flex;flex-wrap:wrap;gap:1.5em;align-items:flex-start}.grid>div{flex:1 1 420px}
"""


class ReportError(ValueError):
    """A report input is missing or empty; the message names it."""


@dataclass
class Section:
    """One section: an anchor id, a title and HTML blocks (figures, tables, paragraphs)."""

    id: str
    title: str
    blocks: list[str] = field(default_factory=list)


def _existing(path, what: str) -> Path:
    path = Path(path)
    if not path.is_file() or path.stat().st_size == 0:
        raise ReportError(f"{what}: {str(path)!r} is missing or empty")
    return path


def paragraph(text: str) -> str:
    """A paragraph of plain text (escaped)."""
    return f"<p>{html.escape(text)}</p>"


def figure(path, caption: str, alt: str | None = None) -> str:
    """A PNG embedded as a base64 data URI, with its caption."""
    path = _existing(path, "figure")
    if path.suffix.lower() != ".png":
        raise ReportError(f"figure {str(path)!r} must be a .png")
    data = base64.b64encode(_compact_png(path)).decode("ascii")
    alt = html.escape(alt or path.stem)
    return (f'<figure><img alt="{alt}" src="data:image/png;base64,{data}">'
            f"<figcaption>{html.escape(caption)}</figcaption></figure>")


# A PNG larger than this is embedded with its colours quantised to a 256-colour palette
# (matplotlib's figures hold few colours; the page stays small), when that is smaller.
COMPACT_PNG_BYTES = 20_000


def _compact_png(path: Path) -> bytes:
    """The PNG's bytes, or those of its 256-colour quantised copy when it is larger than
    COMPACT_PNG_BYTES and the copy is smaller."""
    raw = path.read_bytes()
    if len(raw) <= COMPACT_PNG_BYTES:
        return raw
    import io

    from PIL import Image

    with Image.open(io.BytesIO(raw)) as image:
        small = image.convert("RGB").quantize(colors=256, method=Image.Quantize.MEDIANCUT)
        out = io.BytesIO()
        small.save(out, format="PNG", optimize=True)
    return out.getvalue() if out.tell() < len(raw) else raw


def _format(value, digits: int) -> str:
    if isinstance(value, (float, np.floating)):
        if not np.isfinite(value):
            return "" if np.isnan(value) else str(value)
        return f"{value:.{digits}g}"
    return html.escape(str(value))


def folded(title: str, blocks: list[str], open_: bool = False) -> str:
    """Blocks folded under a one-line summary (HTML <details>)."""
    flag = " open" if open_ else ""
    return (f"<details{flag}><summary>{html.escape(title)}</summary>" + "".join(blocks)
            + "</details>")


def verdict(text: str) -> str:
    """A highlighted paragraph: what the numbers mean, in plain words."""
    return f'<p class="verdict">{html.escape(text)}</p>'


def side_by_side(*blocks: str) -> str:
    return '<div class="grid">' + "".join(f"<div>{b}</div>" for b in blocks) + "</div>"


def table(data, caption: str, columns=None, digits: int = 4, index: bool = False,
          max_rows: int = 60) -> str:
    """An HTML table from a DataFrame or a CSV path (floats to `digits` significant digits);
    `columns` picks and orders columns; at most `max_rows` rows (the rest are counted)."""
    if not isinstance(data, pd.DataFrame):
        data = pd.read_csv(_existing(data, "table"))
    if index:
        data = data.reset_index()
    if columns is not None:
        missing = [c for c in columns if c not in data.columns]
        if missing:
            raise ReportError(f"table {caption!r}: no column(s) {missing} in {list(data.columns)}")
        data = data[list(columns)]
    if data.empty:
        raise ReportError(f"table {caption!r} has no rows")
    shown = data.head(max_rows)
    head = "".join(f"<th>{html.escape(str(c))}</th>" for c in shown.columns)
    body = "".join("<tr>" + "".join(f"<td>{_format(v, digits)}</td>" for v in row) + "</tr>"
                   for row in shown.itertuples(index=False))
    more = len(data) - len(shown)
    note = f" ({more} more rows in the CSV)" if more > 0 else ""
    return (f'<div class="scroll"><table><caption>{html.escape(caption)}{note}</caption>'
            f"<thead><tr>{head}</tr></thead><tbody>{body}</tbody></table></div>")


def render(title: str, sections: list[Section], meta: str = "") -> str:
    """The whole HTML document: title, table of contents, sections. A section without
    blocks raises ReportError (no placeholders)."""
    for s in sections:
        if not s.blocks:
            raise ReportError(f"section {s.title!r} has no content")
    ids = [s.id for s in sections]
    if len(set(ids)) != len(ids):
        raise ReportError(f"section ids repeat: {ids}")
    toc = " · ".join(f'<a href="#{html.escape(s.id)}">{html.escape(s.title)}</a>'
                     for s in sections)
    body = "".join(f'<section id="{html.escape(s.id)}"><h2>{html.escape(s.title)}</h2>'
                   + "".join(s.blocks) + "</section>" for s in sections)
    return (f'<!DOCTYPE html><html lang="en"><head><meta charset="utf-8">'
            f"<title>{html.escape(title)}</title><style>{CSS}</style></head><body>"
            f"<h1>{html.escape(title)}</h1><p class=\"meta\">{html.escape(meta)}</p>"
            f"<nav>Contents: {toc}</nav>{body}</body></html>")


def write_report(path, title: str, sections: list[Section], meta: str = "") -> Path:
    path = Path(path)
    path.parent.mkdir(parents=True, exist_ok=True)
    path.write_text(render(title, sections, meta), encoding="utf-8")
    return path


# --- the workflow's report ---------------------------------------------------------------

# Every file the workflow report reads, by the key the report rule names it with.
REPORT_INPUTS = {
    "dataset_summary": "per-sample table of the finished store (CSV, condor.stages.build)",
    "regimes": "mould regime and removal frequencies beside the paper's table (CSV)",
    "gallery": "mould gallery (PNG)",
    "samples": "example samples: mould and 8 fields (PNG)",
    "accuracy": "every method against the expected fields (results/evaluation/accuracy.csv)",
    "statistics": "r, ceiling and bias per method and statistic (results/evaluation/statistics.csv)",
    "accuracy_chart": "cost per mould against error (PNG)",
    "calibration": "each surrogate's spread map against the replicas' scatter (CSV)",
    "statistics_test": "statistics of the surrogates and baselines on every test mould (CSV)",
    "accuracy_test": "field error of the surrogates and baselines on every test mould (CSV)",
    "calibration_test": "each surrogate's spread map on every test mould (CSV)",
    "spread_chart": "the reproducibility map beside the replicas' scatter (PNG)",
    "ladder": "the anneal ladder (CSV)",
    "convergence": "scene convergence study (CSV)",
    "convergence_chart": "scene convergence chart (PNG)",
    "stability": "stability cases with every solver (CSV)",
    "fidelity": "the dataset's solver against the paper's CONDOR, the reference anneals (CSV)",
    "surrogate_summary": "the paper's measures per variant and baseline (CSV)",
    "evaluations": "evaluation folders, one per variant and one for the baselines",
    "histories": "training history per variant (CSV)",
    "design_table": "the ranked designs, predicted and simulated objectives (CSV)",
    "design_summary": "rank correlation, bias and improvement of the design run (CSV)",
    "design_confirmation": "predicted against simulated objective of the confirmed designs (PNG)",
    "design_history": "the design search's progress (PNG)",
    "design_figure": "the best designs: moulds, predicted fields and spread (PNG)",
}
# Statistics as the report names them.
STATISTIC_LABELS = {"mean_P": "mean P", "n_P_gt_0.2": "N(P > 0.2)", "mean_T": "mean T",
                    "mean_T_norm": "mean T (normalised)", "mean_Sx2": "mean Sx2",
                    "mean_Sx2_norm": "mean Sx2 (normalised)", "mean_Sy2": "mean Sy2",
                    "mean_Sy2_norm": "mean Sy2 (normalised)"}


def _csv(inputs, key: str) -> pd.DataFrame:
    return pd.read_csv(_existing(inputs[key], REPORT_INPUTS[key]))


def _against_ceiling(row, ceiling) -> str:
    """'closer', 'farther' or 'as close': a field error's 95% interval against the noise
    ceiling's (one simulation's), resolved only when the intervals do not overlap."""
    if row.field_error_hi < ceiling.field_error_lo:
        return "closer"
    if row.field_error_lo > ceiling.field_error_hi:
        return "farther"
    return "as close"


def _interval(value, lo, hi, digits: int = 3) -> str:
    if not np.isfinite(value):
        return ""
    return f"{value:.{digits}g} [{lo:.{digits}g}, {hi:.{digits}g}]"


def _percent(value, lo, hi) -> str:
    if not np.isfinite(value):
        return ""
    return f"{100 * value:+.1f}% [{100 * lo:+.1f}, {100 * hi:+.1f}]"


def accuracy_verdict(accuracy: pd.DataFrame) -> str:
    """The cost-against-error chart in plain words: each surrogate and the unconverged anneals
    against one simulation (the noise ceiling)."""
    rows = accuracy.set_index("method")
    if "single simulation" not in rows.index:
        return "No replicas: the noise ceiling cannot be measured."
    c = rows.loc["single simulation"]
    words = [f"One simulation of the dataset's solver scatters by {c.field_error:.3g} "
             f"[{c.field_error_lo:.3g}, {c.field_error_hi:.3g}] about the expected fields "
             f"(RMS, normalised fields; {int(c.n_moulds)} test moulds)."]
    for row in accuracy[accuracy["family"] == "surrogate"].itertuples():
        where = {"closer": "closer to the average organisation than one simulation is",
                 "farther": "farther from the average organisation than one simulation is",
                 "as close": "as close to the average organisation as one simulation, within "
                             "the intervals"}[_against_ceiling(row, c)]
        words.append(f"The surrogate {row.method} ({_interval(row.field_error, row.field_error_lo, row.field_error_hi)}, "
                     f"{row.cpu_s_per_mould * 1e3:.3g} ms per mould) is {where}.")
    anneals = accuracy[accuracy["family"] == "anneal"]
    unconverged = [r.method for r in anneals.itertuples() if r.field_error_lo > c.field_error_hi]
    if unconverged:
        words.append(f"Unconverged anneals ({', '.join(unconverged)}) are farther than the "
                     "ceiling beyond their intervals.")
    return " ".join(words)


def statistics_table(statistics: pd.DataFrame, method: str) -> pd.DataFrame:
    """One method's statistics: r [interval] against the expected statistic, r against the
    replica mean as it is, ceiling, bias [interval], n, the paper's r."""
    rows = statistics[statistics["method"] == method]
    plain = rows["r_plain"].to_numpy() if "r_plain" in rows else np.full(len(rows), np.nan)
    return pd.DataFrame({
        "statistic": [STATISTIC_LABELS.get(s, s) for s in rows["statistic"]],
        "r [95%]": [_interval(r.r, r.r_lo, r.r_hi) for r in rows.itertuples()],
        "r, replica noise kept": plain,
        "ceiling r": rows["r_ceiling"].to_numpy(),
        "bias [95%]": [_percent(r.bias, r.bias_lo, r.bias_hi) for r in rows.itertuples()],
        "n": rows["n"].to_numpy(),
        "paper r": [f"{'=' if r.paper_relation == '=' else '>'} {r.paper_r:g}"
                    for r in rows.itertuples()],
    })


# The whole-mould statistics of the orientation, which the training-set study outside the run
# (condor.findings "more_moulds") measured against the number of training moulds.
ORIENTATION_STATISTICS = {"mean_Sx2", "mean_Sx2_norm", "mean_Sy2", "mean_Sy2_norm"}


def statistics_verdict(statistics: pd.DataFrame, method: str) -> str:
    rows = statistics[statistics["method"] == method]
    if rows.empty:
        return f"No statistics for {method}."
    n = int(rows["n"].max())
    if not bool(rows["informative"].all()):
        return (f"Only {n} test moulds: a Pearson r over so few moulds is not informative "
                "(two moulds always give r = +-1); read the biases and the field errors.")
    biased = [STATISTIC_LABELS.get(r.statistic, r.statistic) for r in rows.itertuples()
              if abs(r.bias) > MAX_BIAS]
    short_rows = [r for r in rows.itertuples() if r.r < min(MIN_R, r.r_ceiling - R_CEILING_SLACK)]
    short = [STATISTIC_LABELS.get(r.statistic, r.statistic) for r in short_rows]
    words = [f"{method} on {n} test moulds against the expected statistics (the replica means):"]
    words.append(f"biased by more than {MAX_BIAS:.0%} on {', '.join(biased)}." if biased
                 else f"no statistic is biased by more than {MAX_BIAS:.0%}.")
    words.append(f"The r is below both {MIN_R:g} and its ceiling - {R_CEILING_SLACK:g} on "
                 f"{', '.join(short)}." if short else
                 f"Every r is at least {MIN_R:g} or within {R_CEILING_SLACK:g} of its ceiling.")
    if any(r.statistic in ORIENTATION_STATISTICS for r in short_rows):
        words.append(more_moulds_sentence(load_findings()["more_moulds"]))
    return " ".join(words)


def ladder_verdict(ladder: pd.DataFrame) -> str:
    """Whether the longest rung's ensemble matches the dataset solver's, and what the longer
    ladder measured outside the run says beyond it."""
    paper_ladder = load_findings()["paper_ladder"].sentence()  # measured outside the run
    rungs = ladder[ladder["rung"] != "dataset solver"].dropna(subset=["distance_to_dataset"])
    if rungs.empty:
        return "The ladder has no finished rung."
    longest = rungs[rungs["budget"] == rungs["budget"].max()]
    far = longest[longest["distance_to_dataset"] > SAME_STATES * longest["spread"]]
    budget = f"{rungs['budget'].max():g}"
    if far.empty:
        return (f"On every ladder mould, the anneal of {budget} moves per cell (then relaxed) lands "
                "within half of one simulation's scatter of the dataset solver's expected fields: "
                "at this budget the fast solver samples the same states. " + paper_ladder)
    ratio = (far["distance_to_dataset"] / far["spread"]).median()
    return (f"On {len(far)} of {len(longest)} ladder moulds the anneal of {budget} moves per cell "
            f"(then relaxed) differs from the dataset solver's expected fields by more than half a "
            f"simulation's scatter (median distance {ratio:.2g} x the scatter): the dataset "
            "solver's expected fields carry that bias against the slower anneal. " + paper_ladder)


def fidelity_state(row) -> str:
    """A fidelity row's verdict in words: "not resolved from" (its upper bound within the bar,
    SAME_STATES x one simulation's scatter: the same states), "resolved from" (its lower bound
    above 0: a real distance) or "not shown to sample" (neither: the interval reaches 0 and
    passes the bar; more moulds or seeds decide)."""
    if row.distance_hi <= SAME_STATES * row.replica_noise:
        return "not resolved from"
    return "resolved from" if row.distance_lo > 0 else "not shown to sample"


def fidelity_verdict(fidelity: pd.DataFrame) -> str:
    """One sentence: how far the dataset's solver (first row) lies from the paper's CONDOR,
    and the L-BFGS quench beside it."""
    if fidelity.empty:
        return ("Fidelity to the paper's CONDOR: not measured, the product holds no reference "
                "anneals of this scene and seed (src/condor/reference).")
    words = []
    for i, row in enumerate(fidelity.itertuples()):
        ratio = row.distance_hi / row.replica_noise
        state = f"{fidelity_state(row)} it"
        name = f"the dataset's solver ({row.method})" if i == 0 else row.method
        cost = (f" at {row.evaluations_per_mould:,.0f} evaluations a mould"
                if np.isfinite(row.evaluations_per_mould) else "")  # a surrogate evaluates none
        words.append(f"{name} lands {_interval(row.distance, row.distance_lo, row.distance_hi)}"
                     f" from its expected fields (upper bound {ratio:.2f} x one simulation's "
                     f"scatter {row.replica_noise:.3f}; {state}){cost}")
    first = fidelity.iloc[0]
    return (f"Fidelity to the paper's CONDOR ({first['reference']}, {int(first['n_moulds'])} "
            f"test moulds x {int(first['n_seeds'])} seeds): " + "; ".join(words) + ".")


def fidelity_blocks(fidelity: pd.DataFrame) -> list[str]:
    """The fidelity table, or its verdict alone when no reference of this scene exists."""
    if fidelity.empty:
        return [verdict(fidelity_verdict(fidelity))]
    return [table(fidelity, "Fidelity to the paper's CONDOR: each solver's ensemble (the "
                  "dataset's replica seeds) against the reference anneals the product ships, "
                  "distance between expected fields (RMS over the normalised fields, noise "
                  "removed, 95% interval over moulds), one reference simulation's scatter, cost "
                  "in evaluation-equivalents a mould, and the differences of the cell-averaged "
                  "orientations and of the energy per cell (%).", digits=3)]


def _dataset_line(config, summary: pd.DataFrame) -> str:
    ok = summary["state"].eq("ok")
    moulds = summary["mould"].nunique() if "mould" in summary else len(summary)
    replicas = config.simulation["replicas"]
    return (f"Scene {config.scene.name!r} ({config.scene.box:g} l0 box, {config.scene.pixels} px), "
            f"{moulds} moulds (seed {config.seed}), solver {config.solver()[0]!r}; replicas per "
            f"mould: train {replicas['train']}, val {replicas['val']}, test {replicas['test']}"
            + (f" (tether-free test moulds {replicas['test_tether_free']})"
               if replicas.get("test_tether_free") is not None else "") + ". "
            f"{int(ok.sum())} of {len(summary)} simulations finished ok, "
            f"{int(summary['state'].eq('failed').sum())} failed.")


def _failures(summary: pd.DataFrame) -> list[str]:
    failed = summary[summary["state"] == "failed"]
    if failed.empty:
        return [paragraph("No simulation failed.")]
    reasons = failed.assign(reason=failed["status"].astype(str).str.split(":").str[0])
    counts = reasons.groupby(["split", "reason"]).size().reset_index(name="simulations")
    return [table(counts, "Failed simulations by split and reason (recorded, never written "
                          "as samples).")]


# The headline's verdict on the spread map: its 90% intervals are calibrated when they hold
# between these shares of the replicas' pixels.
CALIBRATED_90 = (0.85, 0.95)


def _row(frame: pd.DataFrame, method: str):
    rows = frame[frame["method"] == method]
    return rows.iloc[0] if len(rows) else None


def headline(accuracy_test: pd.DataFrame, statistics_test: pd.DataFrame,
             calibration_test: pd.DataFrame, fidelity: pd.DataFrame,
             method: str) -> tuple[pd.DataFrame, str]:
    """The report's first screen: five rows (question, answer) for `method` on every test mould
    (the field error against the noise ceiling, its time a mould, the calibration of its spread
    map, its largest whole-mould bias) and the dataset solver's distance to the paper's CONDOR;
    and one sentence of verdict."""
    rows, verdicts = [], []
    error, ceiling = _row(accuracy_test, method), _row(accuracy_test, "single simulation")
    if error is None or ceiling is None:
        raise ReportError(f"the every-test-mould table has no row for {method!r} or for "
                          "'single simulation'")
    n = int(error["n_moulds"])
    rows.append(("Error against the expected fields",
                 f"{_interval(error.field_error, error.field_error_lo, error.field_error_hi)} on "
                 f"all {n} test moulds; one simulation (the noise ceiling): "
                 f"{_interval(ceiling.field_error, ceiling.field_error_lo, ceiling.field_error_hi)}"))
    where = {"closer": "closer to the expected organisation than one simulation",
             "farther": "farther from the expected organisation than one simulation",
             "as close": "as close to the expected organisation as one simulation"}[
        _against_ceiling(error, ceiling)]
    cost = ceiling.cpu_s_per_mould / error.cpu_s_per_mould if error.cpu_s_per_mould > 0 else np.nan
    rows.append(("Time a mould", f"{error.cpu_s_per_mould * 1e3:.3g} ms (one thread); one "
                 f"simulation {ceiling.cpu_s_per_mould:.3g} s" +
                 (f" ({cost:,.0f} times the surrogate's)" if np.isfinite(cost) and cost >= 10
                  else f" ({cost:.2g} times the surrogate's)" if np.isfinite(cost) else "")))
    verdicts.append(f"{method} lands {where} on all {n} test moulds, at "
                    f"{error.cpu_s_per_mould * 1e3:.3g} ms a mould")
    calibration = _row(calibration_test, method) if "method" in calibration_test else None
    if calibration is not None and "coverage_90" in calibration:
        c90 = calibration.coverage_90
        rows.append(("Calibration of the spread map",
                     f"its 90% intervals hold {100 * c90:.0f}% [{100 * calibration.coverage_90_lo:.0f}, "
                     f"{100 * calibration.coverage_90_hi:.0f}] of the replicas' pixels (50%: "
                     f"{100 * calibration.coverage_50:.0f}%)"))
        state = ("calibrated" if CALIBRATED_90[0] <= c90 <= CALIBRATED_90[1] else
                 "over-confident" if c90 < CALIBRATED_90[0] else "under-confident")
        verdicts.append(f"its spread map is {state}")
    else:
        rows.append(("Calibration of the spread map", f"{method} predicts no spread"))
    stats = statistics_test[statistics_test["method"] == method].dropna(subset=["bias"])
    if len(stats):
        worst = stats.loc[stats["bias"].abs().idxmax()]
        label = STATISTIC_LABELS.get(worst.statistic, worst.statistic)
        resolved = worst.bias_lo > 0 or worst.bias_hi < 0
        rows.append(("Largest bias (whole-mould statistic)",
                     f"{label} {_percent(worst.bias, worst.bias_lo, worst.bias_hi)} "
                     f"(median of predicted / simulated - 1; "
                     f"{'resolved' if resolved else 'not resolved'} from 0)"))
        verdicts.append(f"its largest bias is {label} {100 * worst.bias:+.1f}%" +
                        ("" if resolved else ", within the noise"))
    if fidelity.empty:
        rows.append(("Distance to the paper's CONDOR", "not measured: the product holds no "
                     "reference anneals of this scene and seed"))
    else:
        first = fidelity.iloc[0]
        answer = (f"the dataset's solver ({first.method}) "
                  f"{_interval(first.distance, first.distance_lo, first.distance_hi)} from the "
                  f"reference anneals' expected fields")
        state = fidelity_state(first)
        verdicts.append(f"the dataset's solver is {state} the paper's CONDOR"
                        + (" (its interval reaches 0 and passes the bar)"
                           if state == "not shown to sample" else ""))
        surrogates = fidelity[fidelity["method"].astype(str).str.startswith("surrogate")]
        for row in surrogates.itertuples():
            name = str(row.method).removeprefix("surrogate ")
            answer += (f"; the surrogate ({name}) "
                       f"{_interval(row.distance, row.distance_lo, row.distance_hi)}")
            verdicts.append(f"{name} lies {row.distance:.3g} from the paper's CONDOR, "
                            + ("within" if row.distance_hi < row.replica_noise else "beyond")
                            + " one simulation's scatter")
        rows.append(("Distance to the paper's CONDOR",
                     f"{answer}; one simulation's scatter {first.replica_noise:.3f} "
                     f"({int(first.n_moulds)} moulds)"))
    frame = pd.DataFrame(rows, columns=["question", "answer"])
    return frame, "Verdict: " + "; ".join(verdicts) + "."


def _headline_table(frame: pd.DataFrame) -> str:
    body = "".join(f"<tr><th>{html.escape(q)}</th><td>{html.escape(a)}</td></tr>"
                   for q, a in frame.itertuples(index=False))
    return f'<table class="headline"><tbody>{body}</tbody></table>'


def _predictors(inp) -> set:
    """The methods scored on every test mould (surrogates and baselines), not the ceiling."""
    return set(_csv(inp, "accuracy_test")["method"]) - {"single simulation"}


def _summary_section(config, inp) -> Section:
    summary = _csv(inp, "dataset_summary")
    accuracy = _csv(inp, "accuracy")
    first = config.surrogate["variants"][0] if config.surrogate["variants"] else None
    blocks = []
    if first is not None:
        every = _csv(inp, "statistics_test")
        calibration = (_csv(inp, "calibration_test") if Path(inp["calibration_test"]).stat()
                       .st_size > 1 else pd.DataFrame())  # empty: no surrogate with a spread
        numbers, words = headline(_csv(inp, "accuracy_test"), every, calibration,
                                  _csv(inp, "fidelity"), first)
        blocks += [_headline_table(numbers), verdict(words)]
    blocks += [paragraph(_dataset_line(config, summary)), *_failures(summary)]
    if first is not None:
        blocks += [table(statistics_table(every, first),
                         f"{first} on every test mould: whole-mould statistics against the "
                         "expected statistics (r against the replica means with their "
                         "finite-replica noise removed, 95% interval, n), the ceiling r a "
                         "perfect predictor reaches against one simulation, the bias (median of "
                         "predicted / simulated - 1), and the paper's r."),
                   verdict(statistics_verdict(every, first))]
    n_study = int(accuracy["n_moulds"].max())
    blocks += [figure(inp["accuracy_chart"], f"Every method on the same {n_study} test moulds "
                      "(the surrogate's figures above are on all test moulds): cost per mould "
                      "against the error against the expected fields (the mean of their "
                      "replicas, with the finite-replica noise removed); bars: 95% bootstrap "
                      "intervals over moulds; line and band: one simulation (the noise "
                      "ceiling)."),
               verdict(f"On the {n_study} moulds every method ran on: " + accuracy_verdict(
                   accuracy[~accuracy["method"].isin(_predictors(inp))]))]
    return Section("summary", "At a glance", blocks)


def _accuracy_section(inp) -> Section:
    accuracy = _csv(inp, "accuracy")
    statistics = _csv(inp, "statistics")
    every = _csv(inp, "statistics_test")
    every_error = _csv(inp, "accuracy_test")
    # One set of figures per question: the predictors (surrogates, baselines) are scored on
    # every test mould, the simulation methods on the study's moulds; the ceiling on both.
    predictors = _predictors(inp)
    columns = ["method", "family", "cpu_s_per_mould", "field_error", "field_error_lo",
               "field_error_hi", "field_error_plain", "n_moulds"]
    main = pd.concat([every_error[columns].assign(moulds="every test mould"),
                      accuracy[~accuracy["method"].isin(predictors)][columns].assign(
                          moulds="the study's moulds")], ignore_index=True)
    per_field = accuracy[~accuracy["method"].isin(predictors)]
    per_field = per_field[["method"] + [c for c in accuracy.columns if c.startswith("error_")]]
    methods = [m for m in dict.fromkeys(statistics["method"]) if m not in predictors]
    return Section("accuracy", "Accuracy against the expected organisation", [
        paragraph("The truth of every figure is a mould's expected fields: the mean over its "
                  "replicas (the same mould simulated with several seeds). Errors are RMS over "
                  "the 8 normalised fields and the pixels, with the replicas' own noise removed "
                  "(condor.measures.estimators); field_error_plain keeps it. Intervals: 95% bootstrap "
                  "over moulds."),
        table(main, "Every method: CPU seconds per mould, field error against the expected "
                    "fields [95% interval], the plain error and the moulds scored (surrogates "
                    "and baselines on every test mould, the simulation methods on the study's "
                    "moulds, one simulation on both).", digits=3),
        folded("Field error per field", [table(per_field, "Simulation methods on the study's "
                                                          "moulds: RMS error per field against the "
                                                          "expected fields (noise removed).",
                                               digits=3)]),
        folded("Whole-mould statistics of the simulation methods (the study's moulds)", [
            table(statistics_table(statistics, m), f"{m}: r against the expected statistics "
                  "(the replica means, their noise removed), "
                  "ceiling, bias, n, the paper's r.") for m in methods]),
        folded("Whole-mould statistics of the surrogates and baselines on every test mould", [
            table(statistics_table(every, m), f"{m} on every test mould: r against the expected "
                  "statistics (the replica means, their noise removed), ceiling, bias, n, the "
                  "paper's r.")
            for m in dict.fromkeys(every["method"])]),
        *_reproducibility_blocks(inp),
    ])


def _reproducibility_blocks(inp) -> list[str]:
    """The surrogate's reproducibility map: calibration against the replicas, and the maps."""
    # On every test mould when the run scored them all (one set of figures per question),
    # else on the study's moulds.
    frames = [_csv(inp, key) for key in ("calibration_test", "calibration")
              if Path(inp[key]).stat().st_size > 1]
    calibration = frames[0] if frames else pd.DataFrame()
    blocks = [paragraph("Will this mould give the same tissue twice? A surrogate with a spread "
                        "head predicts, per pixel and field, how far one simulation scatters "
                        "about the expected fields. Checked against the replicas of the test "
                        "moulds: the share of replica pixels inside the tissue that fall in "
                        "the predicted central 50% and 90% intervals (well calibrated: 0.5 and "
                        "0.9), and the r over moulds between predicted and replica scatter.")]
    if "coverage_90" in calibration.columns:
        shown = pd.DataFrame({
            "method": calibration["method"], "moulds": calibration["n_moulds"],
            "50% interval covers [95%]": [_interval(r.coverage_50, r.coverage_50_lo, r.coverage_50_hi)
                                          for r in calibration.itertuples()],
            "90% interval covers [95%]": [_interval(r.coverage_90, r.coverage_90_lo, r.coverage_90_hi)
                                          for r in calibration.itertuples()],
            "r of mould spread": calibration["spread_r"],
            "predicted / replica spread": calibration["spread_ratio"]})
        blocks.append(table(shown, "Calibration of the predicted spread against the replicas.",
                            digits=3))
    blocks.append(figure(inp["spread_chart"], "The reproducibility map: predicted T and Sx2, "
                                              "their predicted spread, and the standard "
                                              "deviation of the replicas, on test moulds."))
    return blocks


def _simulator_section(inp) -> Section:
    ladder = _csv(inp, "ladder")
    convergence = _csv(inp, "convergence")
    stability = _csv(inp, "stability")
    held = int(stability["as_expected"].sum())
    ladder_cols = [c for c in ("mould", "rung", "runs", "energy_per_cell", "energy_min",
                               "energy_max", "distance_to_dataset", "spread", "accept_pos",
                               "inverted_fraction") if c in ladder.columns]
    conv_cols = [c for c in ("study", "mould", "value", "layers", "n_cells", "cpu_s",
                             "change_P", "change_T", "change_Sx2", "change_Sz2", "noise_P",
                             "noise_T", "noise_Sx2", "justified") if c in convergence.columns]
    return Section("simulator", "Simulator: the anneal ladder, convergence and stability", [
        table(ladder[ladder_cols], "The anneal ladder: each rung (anneal budget in moves per "
              "cell, then relaxed by L-BFGS to max force 1e-5) on test moulds, beside the dataset solver's replicas: energy per "
              "cell (median, range), the distance between the rung's and the dataset solver's "
              "expected fields (RMS, noise removed) and the scatter of one simulation within the "
              "rung.", digits=3),
        verdict(ladder_verdict(ladder)),
        *fidelity_blocks(_csv(inp, "fidelity")),
        figure(inp["convergence_chart"], "Systematic change of the fields (noise removed) "
               "against depth and box size; dashed: half the scatter of one simulation."),
        table(convergence[conv_cols], "Scene convergence: a reduction is justified when its "
              "systematic change stays below half of one simulation's scatter on P, T, Sx2, "
              "Sy2 and Sz2.", digits=3),
        folded(f"Stability cases: {held} of {len(stability)} outcomes as promised", [
            table(stability[[c for c in ("case", "solver", "budget", "expect", "status",
                                         "as_expected", "what") if c in stability.columns]],
                  "Outcome per case and solver: status ('ok', the reason a result is flagged, "
                  "or 'rejected: ...' for input that raised ValueError).", digits=3)]),
    ])


def _surrogate_section(config, inp) -> Section:
    summary = _csv(inp, "surrogate_summary")
    blocks = [table(summary, "The paper's measures on the test split, every variant and "
                             "baseline: mean MAE per field, Pearson r per whole-mould statistic, "
                             "prediction seconds per mould.", digits=3)]
    for path in inp["histories"]:
        history = pd.read_csv(_existing(path, "training history"))
        last = history.tail(1)
        blocks.append(table(last, f"{Path(path).stem}: the last epoch of training "
                                  f"({len(history)} epochs in all).", digits=4))
    blocks.append(folded("Findings measured outside this run (condor.findings: each with "
                         "its experiment folder and commit)", findings_blocks()))
    for folder in map(Path, inp["evaluations"]):  # <evaluation>/<method>/figures
        figures = sorted(folder.glob("*.png"))
        if not figures:
            raise ReportError(f"no evaluation figures in {str(folder)!r}")
        name = folder.parent.name
        if name == "baselines":  # their measures are in the table; their pictures stay on disk
            blocks.append(paragraph(f"The baselines' evaluation figures ({len(figures)}): "
                                    f"{folder}."))
            continue
        blocks.append(folded(f"Evaluation figures: {name}",
                             [figure(p, _evaluation_caption(name, p.stem)) for p in figures]))
    return Section("surrogate", "Surrogate: the paper's measures and figures", blocks)


def findings_blocks() -> list[str]:
    """The findings shipped with the package (condor.findings), each with its question and
    provenance: a sentence, or its table."""
    blocks = []
    for finding in load_findings().values():
        if finding.statement:
            blocks.append(paragraph(f"{finding.question} {finding.sentence()}"))
        else:
            blocks.append(table(finding.frame(), f"{finding.question} Measured by "
                                f"{finding.provenance}.", digits=3))
    return blocks


def _evaluation_caption(name: str, stem: str) -> str:
    if stem.endswith("mae_distribution"):
        what = "distribution of the per-sample MAE of each field on the test moulds"
    elif stem.endswith("statistics"):
        what = "simulated against predicted whole-mould statistics, with Pearson r"
    elif stem.endswith("best") or stem.endswith("worst"):
        what = "the best / worst test moulds for one field: simulation, prediction, difference"
    else:
        what = "evaluation figure"
    return f"{name} ({stem}): {what}."


def design_verdict(summary: pd.DataFrame, objective: str) -> str:
    """The design run in plain words: does the search pay, does the surrogate rank designs."""
    row = summary.iloc[0]
    words = [f"Designing for {objective}: the best confirmed design simulates at "
             f"{row['best_simulated']:.3g} (replica mean)"]
    if "best_baseline" in row and np.isfinite(row.get("best_baseline", np.nan)):
        better = "beats" if row["improvement"] > 0 else "does not beat"
        words[0] += (f", which {better} the best of the {int(row['n_baseline'])} test moulds of "
                     f"the random dataset ({row['best_baseline']:.3g}; improvement "
                     f"{row['improvement']:+.3g})")
    words[0] += "."
    words.append(f"Over the {int(row['n'])} confirmed designs the surrogate's ranking has "
                 f"Spearman rho {row['spearman']:.2f} [{row['spearman_low']:.2f}, "
                 f"{row['spearman_high']:.2f}] against the simulations (the replicas' own "
                 f"ceiling: {row['ceiling_spearman']:.2f}); bias {row['bias']:+.3g}.")
    return " ".join(words)


def _design_section(config, inp) -> Section:
    designs = _csv(inp, "design_table")
    summary = _csv(inp, "design_summary")
    objective = config.design["objective"]
    columns = [c for c in ("design", "role", "predicted_objective", "predicted_spread",
                           "simulated_objective", "simulated_objective_std", "n_ok")
               if c in designs.columns]
    return Section("design", f"Design: {objective}", [
        paragraph(f"The surrogate scored {config.design['budget']} candidate moulds of a "
                  "parametric family (symmetric outlines with tethers, the dataset's area rule "
                  "and fabrication limits) in a CMA-ES search; the best "
                  f"{config.design['top']} and {config.design['random']} random searched "
                  f"designs were simulated {config.design['replicas']} times each. Drawings "
                  "(JSON for condor simulate, SVG and DXF with dimensions) are in results/design."),
        verdict(design_verdict(summary, objective)),
        side_by_side(figure(inp["design_confirmation"], "Predicted against simulated objective "
                            "of the confirmed designs (bars: replica spread); line: the best "
                            "test mould."),
                     figure(inp["design_history"], "The search: best and median predicted "
                            "score against designs evaluated.")),
        figure(inp["design_figure"], "The best designs: mould, predicted fields and the "
                                     "predicted spread of one simulation."),
        folded("Every ranked and confirmed design", [
            table(designs[columns], "Designs best predicted first; simulated columns where "
                  "confirmed.")]),
    ])


def store_statistics(store) -> pd.DataFrame:
    """Median, min, max and total of cells, solver CPU seconds and energy per cell over the ok
    samples of a dataset store."""
    ds = open_store(store)
    ok = ds["status"].values.astype(str) == "ok"
    if not ok.any():
        raise ReportError(f"store {str(store)!r} has no finished sample")
    cells = ds["n_cells"].values[ok].astype(float)
    values = {"cells": cells, "solver CPU seconds": ds["solver_seconds"].values[ok].astype(float),
              "energy per cell": ds["energy"].values[ok].astype(float) / cells,
              "largest residual force": ds["max_force"].values[ok].astype(float)}
    return pd.DataFrame([{"quantity": k, "median": np.nanmedian(v), "min": np.nanmin(v),
                          "max": np.nanmax(v), "total": np.nansum(v) if "seconds" in k else np.nan}
                         for k, v in values.items() if np.isfinite(v).any()])


def _dataset_section(inp, store) -> Section:
    return Section("dataset", "Dataset and moulds", [
        table(store_statistics(store), "Per simulation: cells, solver CPU seconds (one core), "
              "energy per cell and the largest residual force, over the finished samples."),
        table(_csv(inp, "regimes"), "Observed regime shares and tether-removal frequencies per "
              "regime, each beside the paper's (columns *_paper).", digits=3),
        folded("Mould gallery", [figure(inp["gallery"], "Mould gallery: footprints (blue) and "
                                                        "tethers (red), in the box.")]),
        folded("Example samples", [figure(inp["samples"], "Example samples: the mould (grey: "
                                          "mould, black: tethers) and its 8 fields.")]),
    ])


def condor_report(config, inputs, store, out_html) -> Path:
    """Write the workflow report for `config` from `inputs` (a mapping with every key of
    REPORT_INPUTS) and the dataset `store`, to `out_html` (one self-contained file)."""
    inputs = dict(inputs.items())  # a Snakemake Namedlist or a dict
    missing = [k for k in REPORT_INPUTS if k not in inputs]
    if missing:
        raise ReportError(f"report inputs lack {missing}")
    sections = [_summary_section(config, inputs), _accuracy_section(inputs),
                _simulator_section(inputs), _surrogate_section(config, inputs),
                _design_section(config, inputs), _dataset_section(inputs, store)]
    stamp = datetime.datetime.now().isoformat(timespec="seconds")
    meta = (f"condor {__version__}; scene {config.scene.name}; {config.n_moulds} moulds; "
            f"folder {config.results}; written {stamp}")
    return write_report(out_html, "condor report: the surrogate against the simulations",
                        sections, meta)

# --- checking that it renders --------------------------------------------------------------

CHROMIUM_NAMES = ("chromium", "chromium-browser", "google-chrome", "google-chrome-stable")


def find_chromium() -> str | None:
    """Path of a Chromium/Chrome executable on PATH, or None."""
    return next((p for p in map(shutil.which, CHROMIUM_NAMES) if p), None)


def screenshot(html_path, png_path, width: int = 1200, height: int = 4000,
               chromium: str | None = None, timeout: float = 120) -> Path:
    """Render `html_path` in headless Chromium and save a PNG of the top `height` px.
    ValueError when no Chromium is found; RuntimeError when it fails."""
    chromium = chromium or find_chromium()
    if chromium is None:
        raise ValueError(f"no Chromium found on PATH (tried {CHROMIUM_NAMES})")
    html_path, png_path = Path(html_path).resolve(), Path(png_path).resolve()
    _existing(html_path, "report")
    png_path.parent.mkdir(parents=True, exist_ok=True)
    png_path.unlink(missing_ok=True)
    cmd = [chromium, "--headless", "--no-sandbox", "--disable-gpu", "--hide-scrollbars",
           f"--window-size={width},{height}", f"--screenshot={png_path}", html_path.as_uri()]
    proc = subprocess.run(cmd, capture_output=True, text=True, timeout=timeout)
    if proc.returncode != 0 or not png_path.is_file():
        raise RuntimeError(f"{chromium} failed ({proc.returncode}): {proc.stderr[-2000:]}")
    return png_path


def screenshot_coverage(png_path) -> dict:
    """How much of a screenshot is drawn: fraction of non-white pixels overall, and of rows
    holding any non-white pixel (a blank or unstyled page scores near 0)."""
    from PIL import Image

    with Image.open(png_path) as image:
        grey = np.asarray(image.convert("L"), dtype=np.uint8)
    ink = grey < 245
    return {"height": int(grey.shape[0]), "width": int(grey.shape[1]),
            "ink_fraction": float(ink.mean()), "rows_with_ink": float(ink.any(axis=1).mean())}
