"""The workflow's report (`condor_report`): one self-contained HTML page assembled from the
run's output files (named by REPORT_INPUTS): one screen of summary first (the headline and its
verdict, the dataset and its failures, the cost-against-error chart, the surrogate's statistics
beside the paper's), details after. A section whose inputs are missing or empty raises
ReportError instead of showing a placeholder. Its building blocks: condor.report.kit; its
verdict rules: condor.report.verdicts."""

from __future__ import annotations

import datetime
import html
from pathlib import Path

import numpy as np
import pandas as pd

from condor.data.store import open_store
from condor.findings import load_findings
from condor.version import __version__

from .kit import (ReportError, Section, existing_file, figure, folded, paragraph, side_by_side,
                  table, verdict, write_report)
from .verdicts import (accuracy_verdict, design_verdict, fidelity_verdict, headline,
                       interval_text, ladder_verdict, method_statistics, statistics_verdict)

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
    "accuracy_lab": "field error of the surrogates and baselines on the lab test set (CSV)",
    "statistics_lab": "statistics of the surrogates and baselines on the lab test set (CSV)",
    "calibration_lab": "each surrogate's spread map on the lab test set (CSV)",
    "families_lab": "each surrogate family by family on the lab test set (CSV)",
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


def _csv(inputs, key: str) -> pd.DataFrame:
    return pd.read_csv(existing_file(inputs[key], REPORT_INPUTS[key]))


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
                                  _csv(inp, "fidelity"), first, _csv(inp, "accuracy_lab"),
                                  _csv(inp, "families_lab"))
        blocks += [_headline_table(numbers), verdict(words)]
    blocks += [paragraph(_dataset_line(config, summary)), *_failures(summary)]
    if first is not None:
        blocks += [table(method_statistics(every, first),
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
            table(method_statistics(statistics, m), f"{m}: r against the expected statistics "
                  "(the replica means, their noise removed), "
                  "ceiling, bias, n, the paper's r.") for m in methods]),
        folded("Whole-mould statistics of the surrogates and baselines on every test mould", [
            table(method_statistics(every, m), f"{m} on every test mould: r against the expected "
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
            "50% interval covers [95%]": [interval_text(r.coverage_50, r.coverage_50_lo, r.coverage_50_hi)
                                          for r in calibration.itertuples()],
            "90% interval covers [95%]": [interval_text(r.coverage_90, r.coverage_90_lo, r.coverage_90_hi)
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
        history = pd.read_csv(existing_file(path, "training history"))
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


def _lab_section(config, inp) -> Section | None:
    """The lab test set: moulds of the lab families (strips, dog-bones, rings, ...) the run
    trained on other moulds of, scored as the paper test set is, and family by family."""
    errors = _csv(inp, "accuracy_lab")
    if "method" not in errors or errors.empty:
        return None
    families = _csv(inp, "families_lab")
    statistics = _csv(inp, "statistics_lab")
    columns = ["method", "family", "cpu_s_per_mould", "field_error", "field_error_lo",
               "field_error_hi", "field_error_plain", "n_moulds"]
    blocks = [paragraph(
        "The lab test set: moulds of the lab families (condor.moulds.lab: "
        f"{', '.join(config.lab_families())}), drawn as the training's lab moulds are but never "
        "trained on, scored against their own replicas' expected fields as the paper test set "
        "is. How the surrogate does on a family it never saw at all is measured apart, "
        "outside the run: the finding on generalisation among the findings below."),
        table(errors[columns], "Surrogates and baselines on the lab test set: field error "
              "against the expected fields [95% interval] beside one simulation's.", digits=3)]
    if not families.empty:
        blocks.append(table(families, "Family by family: the field error [95% interval] against "
                            "the family's own noise ceiling (one simulation), and the mean "
                            "tension's bias (median of predicted / expected - 1) [95%].",
                            digits=3))
    blocks.append(folded("Whole-mould statistics on the lab test set", [
        table(method_statistics(statistics, m), f"{m} on the lab test set: r against the "
              "expected statistics (noise removed), ceiling, bias, n.")
        for m in dict.fromkeys(statistics["method"])]))
    return Section("lab", "Lab moulds", blocks)


def condor_report(config, inputs, store, out_html) -> Path:
    """Write the workflow report for `config` from `inputs` (a mapping with every key of
    REPORT_INPUTS) and the dataset `store`, to `out_html` (one self-contained file)."""
    inputs = dict(inputs.items())  # a Snakemake Namedlist or a dict
    missing = [k for k in REPORT_INPUTS if k not in inputs]
    if missing:
        raise ReportError(f"report inputs lack {missing}")
    lab = _lab_section(config, inputs)
    sections = [_summary_section(config, inputs), _accuracy_section(inputs),
                *([lab] if lab is not None else []),
                _simulator_section(inputs), _surrogate_section(config, inputs),
                _design_section(config, inputs), _dataset_section(inputs, store)]
    stamp = datetime.datetime.now().isoformat(timespec="seconds")
    meta = (f"condor {__version__}; scene {config.scene.name}; {config.n_moulds} moulds; "
            f"folder {config.results}; written {stamp}")
    return write_report(out_html, "condor report: the surrogate against the simulations",
                        sections, meta)
