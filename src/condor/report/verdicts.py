"""The report's verdict rules: each table of the run in plain words, read against the quality
bars of condor.measures.bars (the surrogate against the noise ceiling, its whole-mould
statistics, the anneal ladder, the dataset solver's distance to the paper's CONDOR, the design
run), and the headline that opens the report (`headline`)."""

from __future__ import annotations

import numpy as np
import pandas as pd

from condor.findings import load_findings, more_moulds_sentence
from condor.measures.bars import CALIBRATED_90, MAX_BIAS, MIN_R, R_CEILING_SLACK, SAME_STATES

from .kit import ReportError

# Statistics as the report names them: condor's by their names (as condor predict prints
# them; the paper's name beside the two it shares), the paper's in words (docs/fields.md,
# "Whole-mould statistics", defines each once).
STATISTIC_LABELS = {"alignment": "alignment", "alignment_x": "alignment_x",
                    "mean_tension": "mean_tension (paper: mean T normalised)",
                    "tissue_area": "tissue_area (paper: N(P > 0.2))",
                    "mean_P": "mean P (paper)", "n_P_gt_0.2": "N(P > 0.2) (paper)",
                    "mean_T": "mean T (paper)", "mean_T_norm": "mean T normalised (paper)",
                    "mean_Sx2": "mean Sx2 (paper)", "mean_Sx2_norm": "mean Sx2 normalised (paper)",
                    "mean_Sy2": "mean Sy2 (paper)", "mean_Sy2_norm": "mean Sy2 normalised (paper)"}


def against_ceiling(row, ceiling) -> str:
    """'closer', 'farther' or 'as close': a field error's 95% interval against the noise
    ceiling's (one simulation's), resolved only when the intervals do not overlap."""
    if row.field_error_hi < ceiling.field_error_lo:
        return "closer"
    if row.field_error_lo > ceiling.field_error_hi:
        return "farther"
    return "as close"


def interval_text(value, lo, hi, digits: int = 3) -> str:
    if not np.isfinite(value):
        return ""
    return f"{value:.{digits}g} [{lo:.{digits}g}, {hi:.{digits}g}]"


def percent_text(value, lo, hi) -> str:
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
                             "the intervals"}[against_ceiling(row, c)]
        words.append(f"The surrogate {row.method} ({interval_text(row.field_error, row.field_error_lo, row.field_error_hi)}, "
                     f"{row.cpu_s_per_mould * 1e3:.3g} ms per mould) is {where}.")
    anneals = accuracy[accuracy["family"] == "anneal"]
    unconverged = [r.method for r in anneals.itertuples() if r.field_error_lo > c.field_error_hi]
    if unconverged:
        words.append(f"Unconverged anneals ({', '.join(unconverged)}) are farther than the "
                     "ceiling beyond their intervals.")
    return " ".join(words)


def method_statistics(statistics: pd.DataFrame, method: str) -> pd.DataFrame:
    """One method's statistics: r [interval] against the expected statistic, r against the
    replica mean as it is, ceiling, bias [interval], n, the paper's r."""
    rows = statistics[statistics["method"] == method]
    plain = rows["r_plain"].to_numpy() if "r_plain" in rows else np.full(len(rows), np.nan)
    return pd.DataFrame({
        "statistic": [STATISTIC_LABELS.get(s, s) for s in rows["statistic"]],
        "r [95%]": [interval_text(r.r, r.r_lo, r.r_hi) for r in rows.itertuples()],
        "r, replica noise kept": plain,
        "ceiling r": rows["r_ceiling"].to_numpy(),
        "bias [95%]": [percent_text(r.bias, r.bias_lo, r.bias_hi) for r in rows.itertuples()],
        "n": rows["n"].to_numpy(),
        "paper r": [f"{'=' if r.paper_relation == '=' else '>'} {r.paper_r:g}"
                    if np.isfinite(r.paper_r) else "not the paper's" for r in rows.itertuples()],
    })


# The whole-mould statistics of the orientation, which the training-set study outside the run
# (condor.findings "more_moulds") measured against the number of training moulds.
ORIENTATION_STATISTICS = {"mean_Sx2", "mean_Sx2_norm", "mean_Sy2", "mean_Sy2_norm", "alignment",
                          "alignment_x"}


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
                "anneals of this scene and seed (src/condor/paper_reference).")
    words = []
    for i, row in enumerate(fidelity.itertuples()):
        ratio = row.distance_hi / row.replica_noise
        state = f"{fidelity_state(row)} it"
        name = f"the dataset's solver ({row.method})" if i == 0 else row.method
        cost = (f" at {row.evaluations_per_mould:,.0f} evaluations a mould"
                if np.isfinite(row.evaluations_per_mould) else "")  # a surrogate evaluates none
        words.append(f"{name} lands {interval_text(row.distance, row.distance_lo, row.distance_hi)}"
                     f" from its expected fields (upper bound {ratio:.2f} x one simulation's "
                     f"scatter {row.replica_noise:.3f}; {state}){cost}")
    first = fidelity.iloc[0]
    return (f"Fidelity to the paper's CONDOR ({first['reference']}, {int(first['n_moulds'])} "
            f"test moulds x {int(first['n_seeds'])} seeds): " + "; ".join(words) + ".")


def method_row(frame: pd.DataFrame, method: str):
    rows = frame[frame["method"] == method]
    return rows.iloc[0] if len(rows) else None


_WHERE = {"closer": "closer to the expected organisation than one simulation",
          "farther": "farther from the expected organisation than one simulation",
          "as close": "as close to the expected organisation as one simulation"}


def lab_row(accuracy_lab: pd.DataFrame, families_lab: pd.DataFrame,
            method: str) -> tuple[tuple[str, str], str] | None:
    """The lab test set's headline row (question, answer) and verdict for `method`: its error
    against the noise ceiling over the lab moulds, and its worst family; None when the run has
    no lab test set."""
    error = method_row(accuracy_lab, method) if "method" in accuracy_lab else None
    ceiling = method_row(accuracy_lab, "single simulation") if error is not None else None
    if error is None or ceiling is None:
        return None
    n = int(error["n_moulds"])
    answer = (f"{interval_text(error.field_error, error.field_error_lo, error.field_error_hi)} on "
              f"{n} lab test moulds; one simulation: "
              f"{interval_text(ceiling.field_error, ceiling.field_error_lo, ceiling.field_error_hi)}")
    mine = families_lab[families_lab["method"] == method] if "method" in families_lab else None
    if mine is not None and len(mine):
        ratio = mine["error"] / mine["noise_ceiling"]
        worst = mine.loc[ratio.idxmax()]
        answer += (f"; {len(mine)} families, the hardest {worst.family} "
                   f"{worst.error:.3g} against its ceiling {worst.noise_ceiling:.3g}, mean "
                   f"tension biased {100 * worst.tension_bias:+.1f}%")
    where = _WHERE[against_ceiling(error, ceiling)]
    return ("Error on lab moulds (strips, dog-bones, rings, frames...)", answer), \
        f"on the lab test set it lands {where}"


def headline(accuracy_test: pd.DataFrame, statistics_test: pd.DataFrame,
             calibration_test: pd.DataFrame, fidelity: pd.DataFrame,
             method: str, accuracy_lab: pd.DataFrame | None = None,
             families_lab: pd.DataFrame | None = None) -> tuple[pd.DataFrame, str]:
    """The report's first screen: rows (question, answer) for `method` on the paper test set
    (the field error against the noise ceiling, its time a mould, the calibration of its spread
    map, its largest whole-mould bias), on the lab test set when there is one (`lab_row`), and
    the dataset solver's distance to the paper's CONDOR; and one sentence of verdict."""
    rows, verdicts = [], []
    error, ceiling = method_row(accuracy_test, method), method_row(accuracy_test, "single simulation")
    if error is None or ceiling is None:
        raise ReportError(f"the every-test-mould table has no row for {method!r} or for "
                          "'single simulation'")
    n = int(error["n_moulds"])
    rows.append(("Error against the expected fields",
                 f"{interval_text(error.field_error, error.field_error_lo, error.field_error_hi)} on "
                 f"the {n} paper test moulds; one simulation (the noise ceiling): "
                 f"{interval_text(ceiling.field_error, ceiling.field_error_lo, ceiling.field_error_hi)}"))
    where = _WHERE[against_ceiling(error, ceiling)]
    cost = ceiling.cpu_s_per_mould / error.cpu_s_per_mould if error.cpu_s_per_mould > 0 else np.nan
    rows.append(("Time a mould", f"{error.cpu_s_per_mould * 1e3:.3g} ms (one thread); one "
                 f"simulation {ceiling.cpu_s_per_mould:.3g} s" +
                 (f" ({cost:,.0f} times the surrogate's)" if np.isfinite(cost) and cost >= 10
                  else f" ({cost:.2g} times the surrogate's)" if np.isfinite(cost) else "")))
    verdicts.append(f"{method} lands {where} on the {n} paper test moulds, at "
                    f"{error.cpu_s_per_mould * 1e3:.3g} ms a mould")
    lab = (lab_row(accuracy_lab, families_lab if families_lab is not None else pd.DataFrame(),
                   method) if accuracy_lab is not None else None)
    if lab is not None:
        rows.append(lab[0])
        verdicts.append(lab[1])
    calibration = method_row(calibration_test, method) if "method" in calibration_test else None
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
                     f"{label} {percent_text(worst.bias, worst.bias_lo, worst.bias_hi)} "
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
                  f"{interval_text(first.distance, first.distance_lo, first.distance_hi)} from the "
                  f"reference anneals' expected fields")
        state = fidelity_state(first)
        verdicts.append(f"the dataset's solver is {state} the paper's CONDOR"
                        + (" (its interval reaches 0 and passes the bar)"
                           if state == "not shown to sample" else ""))
        surrogates = fidelity[fidelity["method"].astype(str).str.startswith("surrogate")]
        for row in surrogates.itertuples():
            name = str(row.method).removeprefix("surrogate ")
            answer += (f"; the surrogate ({name}) "
                       f"{interval_text(row.distance, row.distance_lo, row.distance_hi)}")
            verdicts.append(f"{name} lies {row.distance:.3g} from the paper's CONDOR, "
                            + ("within" if row.distance_hi < row.replica_noise else "beyond")
                            + " one simulation's scatter")
        rows.append(("Distance to the paper's CONDOR",
                     f"{answer}; one simulation's scatter {first.replica_noise:.3f} "
                     f"({int(first.n_moulds)} moulds)"))
    frame = pd.DataFrame(rows, columns=["question", "answer"])
    return frame, "Verdict: " + "; ".join(verdicts) + "."


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
