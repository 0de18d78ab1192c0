# Stage 6: one self-contained HTML report (condor.report; `snakemake --report` also builds
# Snakemake's own report from the figures marked in the rules).


def report_inputs(wildcards):
    """Every file the report reads, by the key condor.report.REPORT_INPUTS names it with."""
    return {
        "dataset_summary": rules.dataset.output[0],
        "regimes": rules.gallery.output.regimes,
        "gallery": rules.gallery.output.gallery,
        "samples": rules.sample_figure.output[0],
        "accuracy": rules.accuracy.output.accuracy,
        "statistics": rules.accuracy.output.statistics,
        "accuracy_chart": rules.accuracy.output.chart,
        "ladder": rules.ladder.output[0],
        "convergence": rules.convergence.output.table,
        "convergence_chart": rules.convergence.output.chart,
        "stability": rules.stability.output[0],
        "surrogate_summary": rules.surrogate_summary.output[0],
        "evaluations": [*expand(f"{EVALUATION}/{{variant}}/figures", variant=list(VARIANTS)),
                        f"{EVALUATION}/baselines/figures"],
        "histories": expand(f"{R}/models/{{variant}}_history.csv", variant=list(VARIANTS)),
    }


rule report:
    conda:
        CONDA_ENV
    input:
        unpack(report_inputs),
    output:
        report(f"{R}/report.html", caption="../report/report.rst", category="Report"),
    params:
        store=STORE,
    log:
        f"{R}/logs/report.log",
    script:
        "../scripts/report.py"


localrules:
    report,


FINAL_TARGETS.extend(rules.report.output)
