"""The run's report as one self-contained HTML file (pure library: no Snakemake).

Building blocks (`figure`, `table`, `paragraph`, `Section`, `render`) make any report: PNGs
are embedded as base64 data URIs, tables come from CSV files or DataFrames, every figure and
table has a caption, and a table of contents links the sections. `condor_report` assembles
the workflow's report from its output files (`ReportInputs`); a section whose inputs are
missing or empty raises ReportError instead of showing a placeholder.
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

CSS = """
body{font-family:system-ui,sans-serif;max-width:1150px;margin:2em auto;padding:0 1em;color:#222}
h1{font-size:1.6em}h2{border-bottom:1px solid #ccc;padding-bottom:.2em;margin-top:2em}
figure{margin:1.2em 0}figure img{max-width:100%;border:1px solid #eee}
figcaption,caption{font-size:.9em;color:#444;text-align:left;margin:.3em 0}
table{border-collapse:collapse;font-size:.85em;margin:.8em 0}
td,th{border:1px solid #ddd;padding:.2em .5em;text-align:right}th{background:#f4f4f4}
td:first-child,th:first-child{text-align:left}nav li{margin:.15em 0}
.scroll{overflow-x:auto}
.meta{color:#666;font-size:.85em}
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
    data = base64.b64encode(path.read_bytes()).decode("ascii")
    alt = html.escape(alt or path.stem)
    return (f'<figure><img alt="{alt}" src="data:image/png;base64,{data}">'
            f"<figcaption>{html.escape(caption)}</figcaption></figure>")


def _format(value, digits: int) -> str:
    if isinstance(value, (float, np.floating)):
        if not np.isfinite(value):
            return "" if np.isnan(value) else str(value)
        return f"{value:.{digits}g}"
    return html.escape(str(value))


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
    toc = "".join(f'<li><a href="#{html.escape(s.id)}">{html.escape(s.title)}</a></li>'
                  for s in sections)
    body = "".join(f'<section id="{html.escape(s.id)}"><h2>{html.escape(s.title)}</h2>'
                   + "".join(s.blocks) + "</section>" for s in sections)
    return (f'<!DOCTYPE html><html lang="en"><head><meta charset="utf-8">'
            f"<title>{html.escape(title)}</title><style>{CSS}</style></head><body>"
            f"<h1>{html.escape(title)}</h1><p class=\"meta\">{html.escape(meta)}</p>"
            f"<nav><h2>Contents</h2><ol>{toc}</ol></nav>{body}</body></html>")


def write_report(path, title: str, sections: list[Section], meta: str = "") -> Path:
    path = Path(path)
    path.parent.mkdir(parents=True, exist_ok=True)
    path.write_text(render(title, sections, meta), encoding="utf-8")
    return path


# --- the workflow's report ---------------------------------------------------------------

@dataclass
class ReportInputs:
    """The workflow outputs the report shows (paths). `evaluations`: {variant: folder of
    rule evaluate (summary.csv, <variant>_<mode>_correlations.csv, figures/)}, plus
    "baselines"."""

    gallery: Path
    regimes: Path
    samples: Path
    dataset_summary: Path
    speed_accuracy: Path
    speed_accuracy_summary: Path
    speed_accuracy_chart: Path
    convergence: Path
    convergence_summary: Path
    convergence_chart: Path
    stability: Path
    cost_accuracy: Path
    cost_accuracy_chart: Path
    surrogate_summary: Path
    evaluations: dict = field(default_factory=dict)
    store: Path | None = None


def _dataset_section(inp: ReportInputs, config: dict) -> Section:
    summary = pd.read_csv(_existing(inp.dataset_summary, "dataset summary"))
    status = summary["status"].fillna("missing").astype(str)
    counts = summary.assign(status=status).groupby(["split", "status"]).size()
    scene = config.get("scene")
    text = (f"Scene {scene!r}, {config.get('n_moulds')} moulds (seed {config.get('seed')}), "
            f"solver {config.get('simulation', {}).get('solver', 'hybrid')!r}; "
            f"{int((status == 'ok').sum())} samples finished ok.")
    blocks = [paragraph(text), table(counts.reset_index(name="samples"),
                                     "Samples by split and simulation status.")]
    if inp.store is not None:
        blocks.append(table(store_statistics(inp.store), "Per-sample cells, solver CPU "
                            "seconds (one core) and energy per cell over the finished samples."))
    return Section("dataset", "Dataset", blocks)


def store_statistics(store) -> pd.DataFrame:
    """Median, min, max and total of cells, solver seconds and energy per cell over the ok
    samples of a dataset store."""
    from condor.store import open_dataset

    ds = open_dataset(store)
    ok = ds["status"].values.astype(str) == "ok"
    if not ok.any():
        raise ReportError(f"store {str(store)!r} has no finished sample")
    cells = ds["n_cells"].values[ok].astype(float)
    values = {"cells": cells, "solver CPU seconds": ds["solver_seconds"].values[ok].astype(float),
              "energy per cell": ds["energy"].values[ok].astype(float) / cells}
    return pd.DataFrame([{"quantity": k, "median": np.median(v), "min": v.min(), "max": v.max(),
                          "total": v.sum() if "seconds" in k else np.nan}
                         for k, v in values.items()])


def _moulds_section(inp: ReportInputs) -> Section:
    return Section("moulds", "Moulds", [
        figure(inp.gallery, "Mould gallery: footprints (grey) and tethers (dark), in the box."),
        table(pd.read_csv(_existing(inp.regimes, "regime table")),
              "Observed regime shares and tether-removal frequencies per regime, each beside "
              "the paper's (columns *_paper; the paper's table, rows renormalised).", digits=3),
    ])


def _samples_section(inp: ReportInputs) -> Section:
    return Section("samples", "Example samples", [
        figure(inp.samples, "Example samples from the store: the mould (grey: mould, black: "
                            "tethers) and its 8 fields P, T, Sx2, Sy2, Sz2, SxSy, SxSz, SySz."),
    ])


def _simulator_section(inp: ReportInputs) -> Section:
    sweep = pd.read_csv(_existing(inp.speed_accuracy, "speed/accuracy table"))
    text = (f"{sweep['mould'].nunique()} test moulds, each simulated by every method and by "
            "two references: the long anneal followed by FIRE to force 1e-5 (the reference "
            "every error is measured against) and the minimiser from the lattice to the same "
            "tolerance (its distance to the reference is the floor between two converged "
            "states). CPU seconds on one core.")
    return Section("simulator", "Simulator: speed against accuracy", [
        paragraph(text),
        figure(inp.speed_accuracy_chart, "Energy per cell above the lowest found (left) and "
               "field MAE against the long-anneal reference (right) against CPU seconds, for "
               "anneal budgets (moves per cell), the minimiser, the hybrid and looser tolerances."),
        table(inp.speed_accuracy_summary, "Medians over moulds per method: CPU seconds, energy "
              "above the best found (rel_energy) and above the reference (rel_energy_ref), "
              "field MAE against the reference.",
              columns=["role", "method", "runs", "n_cells", "seconds", "rel_energy",
                       "rel_energy_ref", "field_mae", "ok"]),
    ])


def _convergence_section(inp: ReportInputs) -> Section:
    summary = pd.read_csv(_existing(inp.convergence_summary, "convergence summary"))
    columns = [c for c in ["study", "value", "baseline", "n_cells", "seconds", "rel_P", "rel_T",
                           "rel_Sx2", "rel_Sz2", "rel_mean", "noise", "within_noise"]
               if c in summary.columns]
    return Section("convergence", "Scene convergence study", [
        paragraph("How much the fields change with the mould depth (number of FCC layers) and "
                  "with the box size, compared with the change from re-simulating the same "
                  "configuration with another seed (the noise; baseline rows)."),
        figure(inp.convergence_chart, "Relative MAE of the fields (per channel, normalised "
               "per cell) against the deepest / largest configuration; dashed lines: the same "
               "configuration simulated with another seed."),
        table(summary, "Median relative MAE per study and value; within_noise: the change is "
              "at most 1.25 x the seed-to-seed noise.", columns=columns, digits=3),
    ])


def _surrogate_section(inp: ReportInputs) -> Section:
    summary = pd.read_csv(_existing(inp.surrogate_summary, "surrogate summary"))
    blocks = [table(summary, "Every surrogate variant and baseline on the test split: mean MAE "
                             "per field, Pearson r per whole-mould statistic, prediction "
                             "seconds per mould.", digits=3)]
    for name, folder in inp.evaluations.items():
        folder = Path(folder)
        for path in sorted(folder.glob("*_correlations.csv")):
            method = path.name.removesuffix("_correlations.csv")
            blocks.append(table(path, f"{method}: Pearson r of simulated against predicted "
                                      "whole-mould statistics on the test moulds, beside the "
                                      "paper's (= 0.881 for mean density, > 0.98 otherwise).",
                                digits=3))
        figures = sorted((folder / "figures").glob("*.png"))
        if not figures:
            raise ReportError(f"no evaluation figures in {str(folder / 'figures')!r}")
        for path in figures:
            blocks.append(figure(path, _evaluation_caption(name, path.stem)))
    return Section("surrogate", "Surrogate evaluation", blocks)


def _evaluation_caption(name: str, stem: str) -> str:
    if stem.endswith("mae_distribution"):
        what = "distribution of the per-sample MAE of each field on the test moulds"
    elif stem.endswith("statistics"):
        what = "simulated against predicted whole-mould statistics, with Pearson r"
    elif stem.endswith("best") or stem.endswith("worst"):
        what = ("the best / worst test moulds for one field: simulation, prediction, "
                "difference")
    else:
        what = "evaluation figure"
    return f"{name} ({stem}): {what}."


def _cost_section(inp: ReportInputs) -> Section:
    table_df = pd.read_csv(_existing(inp.cost_accuracy, "cost/accuracy table"))
    return Section("cost", "Cost per mould against error, every method", [
        paragraph("Every way of answering 'what fields does this mould give' on the same test "
                  "moulds, against the same long-anneal reference: the long anneal itself, "
                  "short anneals, the minimiser, the hybrid, each surrogate variant and the "
                  "baselines. Cost: CPU seconds per mould on one core (surrogates: one torch "
                  "thread, one mould per call). Shaded: the paper's 24-36 core-hours per "
                  "simulation; dashed: its ~0.1 s per prediction."),
        figure(inp.cost_accuracy_chart, "Median field MAE (normalised fields, mean over the 8 "
               "channels) against median CPU seconds per mould; bars: range over moulds."),
        table(table_df, "Per method: moulds, median (min, max) CPU seconds per mould and field "
                        "MAE against the reference.", digits=3),
    ])


def _stability_section(inp: ReportInputs) -> Section:
    df = pd.read_csv(_existing(inp.stability, "stability table"))
    columns = [c for c in ["case", "solver", "budget", "expect", "status", "as_expected", "what"]
               if c in df.columns]
    held = int(df["as_expected"].sum()) if "as_expected" in df else 0
    return Section("stability", "Stability: failure cases and what each method does", [
        paragraph(f"Each hard input the tests construct, run with every solver: {held} of "
                  f"{len(df)} outcomes as the design promises (a flagged status, a rejected "
                  "input with a message, or a valid result)."),
        table(df, "Outcome per case and solver: status ('ok', the reason the result is "
                  "flagged, or 'rejected: ...' for input that raised ValueError) and what "
                  "happened.", columns=columns, digits=3),
    ])


def condor_sections(inp: ReportInputs, config: dict) -> list[Section]:
    """The workflow report's sections, in order."""
    return [_dataset_section(inp, config), _moulds_section(inp), _samples_section(inp),
            _simulator_section(inp), _convergence_section(inp), _surrogate_section(inp),
            _cost_section(inp), _stability_section(inp)]


def condor_report(inp: ReportInputs, config: dict, out_html) -> Path:
    """Write the workflow report for `config` to `out_html` (one self-contained file)."""
    from condor import __version__

    stamp = datetime.datetime.now().isoformat(timespec="seconds")
    meta = (f"condor {__version__}; scene {config.get('scene')}; {config.get('n_moulds')} moulds; "
            f"results {config.get('results', 'results')}; written {stamp}")
    return write_report(out_html, "condor: dataset, simulator and surrogate report",
                        condor_sections(inp, config), meta)


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
