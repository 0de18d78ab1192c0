# Stage 5: the report's own measurements on a few test moulds (speed/accuracy sweep with a
# long-anneal reference, scene convergence, stability cases, cost per mould against error
# for every method), then one self-contained HTML report (and `snakemake --report` figures).
from condor.store import assign_splits

REPORT = config.get("report", {})
REPORT_DIR = f"{R}/report"
_SPLIT = assign_splits(config["n_moulds"], config.get("split", {}).get("test", 24),
                       config.get("split", {}).get("val_fraction", 0.1), config["seed"])
# The first test moulds: unseen by the surrogates, so every method answers the same question.
REPORT_MOULDS = [i for i, s in enumerate(_SPLIT) if s == "test"][: REPORT.get("moulds", 2)]
# The moulds batch file that holds each of them.
MOULD_BATCH = {
    m: f"{R}/moulds/batch_{b:04d}.json"
    for b, ids in enumerate(BATCHES)
    for m in ids
    if m in REPORT_MOULDS
}


wildcard_constraints:
    mould=r"\d+",


rule tradeoff_mould:
    conda:
        CONDA_ENV
    input:
        lambda wildcards: MOULD_BATCH[int(wildcards.mould)],
    output:
        table=f"{REPORT_DIR}/tradeoff/mould_{{mould}}.csv",
        reference=f"{REPORT_DIR}/tradeoff/mould_{{mould}}_reference.npz",
    params:
        settings=REPORT,
    log:
        f"{R}/logs/report/tradeoff_{{mould}}.log",
    threads: 1
    resources:
        runtime=60,
        mem_mb=2000,
    script:
        "../scripts/tradeoff.py"


rule tradeoff:
    conda:
        CONDA_ENV
    input:
        expand(f"{REPORT_DIR}/tradeoff/mould_{{mould}}.csv", mould=REPORT_MOULDS),
    output:
        table=f"{REPORT_DIR}/speed_accuracy.csv",
        summary=f"{REPORT_DIR}/speed_accuracy_summary.csv",
        chart=report(
            f"{REPORT_DIR}/figures/speed_accuracy.png",
            caption="../report/speed_accuracy.rst",
            category="Simulator",
        ),
    log:
        f"{R}/logs/report/tradeoff.log",
    script:
        "../scripts/tradeoff.py"


rule convergence:
    conda:
        CONDA_ENV
    input:
        MOULD_BATCH[REPORT_MOULDS[0]],
    output:
        table=f"{REPORT_DIR}/convergence.csv",
        summary=f"{REPORT_DIR}/convergence_summary.csv",
        chart=report(
            f"{REPORT_DIR}/figures/convergence.png",
            caption="../report/convergence.rst",
            category="Simulator",
        ),
    params:
        settings=REPORT,
        mould=REPORT_MOULDS[0],
    log:
        f"{R}/logs/report/convergence.log",
    threads: 1
    resources:
        runtime=120,
        mem_mb=4000,
    script:
        "../scripts/tradeoff.py"


rule stability:
    conda:
        CONDA_ENV
    input:
        STORE_READY,  # the numba cache is warm before any simulation job
    output:
        report(
            f"{REPORT_DIR}/stability.csv",
            caption="../report/stability.rst",
            category="Simulator",
        ),
    params:
        solvers=REPORT.get("stability_solvers", ["anneal", "minimise", "hybrid"]),
    log:
        f"{R}/logs/report/stability.log",
    threads: 1
    resources:
        runtime=30,
        mem_mb=1000,
    script:
        "../scripts/stability.py"


rule cost_accuracy:
    conda:
        CONDA_ENV
    input:
        tables=expand(f"{REPORT_DIR}/tradeoff/mould_{{mould}}.csv", mould=REPORT_MOULDS),
        references=expand(
            f"{REPORT_DIR}/tradeoff/mould_{{mould}}_reference.npz", mould=REPORT_MOULDS
        ),
        moulds=sorted(set(MOULD_BATCH.values())),
        checkpoints=expand(f"{R}/models/{{variant}}.pt", variant=list(VARIANTS)),
        dataset=rules.dataset.output,
    output:
        table=f"{REPORT_DIR}/cost_accuracy.csv",
        per_mould=f"{REPORT_DIR}/cost_accuracy_per_mould.csv",
        chart=report(
            f"{REPORT_DIR}/figures/cost_accuracy.png",
            caption="../report/cost_accuracy.rst",
            category="Cost against accuracy",
        ),
    params:
        variants=list(VARIANTS),
    log:
        f"{R}/logs/report/cost_accuracy.log",
    threads: 1
    resources:
        runtime=30,
        mem_mb=4000,
    script:
        "../scripts/report_cost.py"


rule report:
    conda:
        CONDA_ENV
    input:
        gallery=f"{R}/figures/mould_gallery.png",
        regimes=f"{R}/figures/mould_regimes.csv",
        samples=rules.sample_figure.output[0],
        dataset_summary=rules.dataset.output[0],
        speed_accuracy=rules.tradeoff.output.table,
        speed_accuracy_summary=rules.tradeoff.output.summary,
        speed_accuracy_chart=rules.tradeoff.output.chart,
        convergence=rules.convergence.output.table,
        convergence_summary=rules.convergence.output.summary,
        convergence_chart=rules.convergence.output.chart,
        stability=rules.stability.output[0],
        cost_accuracy=rules.cost_accuracy.output.table,
        cost_accuracy_chart=rules.cost_accuracy.output.chart,
        surrogate_summary=rules.surrogate_summary.output[0],
        evaluations=expand(f"{EVALUATION}/{{variant}}/figures", variant=list(VARIANTS)),
        baselines=f"{EVALUATION}/baselines/figures",
    output:
        report(
            f"{R}/report.html",
            caption="../report/report.rst",
            category="Report",
        ),
    params:
        variants=list(VARIANTS),
    log:
        f"{R}/logs/report/report.log",
    script:
        "../scripts/report.py"


localrules:
    tradeoff,
    report,


FINAL_TARGETS.extend(rules.report.output)
