# Stage 5: the report's own measurements on the test moulds: every simulation method swept on
# each study mould (one job each), every method against the expected fields (the accuracy
# tables and the cost-against-error chart), the anneal ladder, the scene convergence study and
# the stability cases.

try:
    STUDY_MOULDS = CONFIG.study_moulds()
except ConfigError as err:
    sys.exit(f"condor: {err}")  # one line, no traceback, nothing run
STUDIES = f"{R}/studies"


rule sweep_mould:
    conda:
        CONDA_ENV
    input:
        lambda wildcards: moulds_of_batch(wildcards.mould),
    output:
        fields=f"{STUDIES}/sweep/mould_{{mould}}.npz",
        table=f"{STUDIES}/sweep/mould_{{mould}}.csv",
    params:
        settings=report_settings("reference_budget", "anneal_budgets"),
    log:
        f"{R}/logs/studies/sweep_{{mould}}.log",
    threads: 1
    resources:
        runtime=60,
        mem_mb=2000,
    script:
        "../scripts/sweep_mould.py"


rule accuracy:
    conda:
        CONDA_ENV
    input:
        sweeps=expand(f"{STUDIES}/sweep/mould_{{mould}}.npz", mould=STUDY_MOULDS),
        checkpoints=expand(f"{R}/models/{{variant}}.pt", variant=list(VARIANTS)),
        dataset=rules.dataset.output,
    output:
        accuracy=f"{EVALUATION}/accuracy.csv",
        statistics=f"{EVALUATION}/statistics.csv",
        calibration=f"{EVALUATION}/calibration.csv",
        statistics_test=f"{EVALUATION}/statistics_test.csv",
        accuracy_test=f"{EVALUATION}/accuracy_test.csv",
        calibration_test=f"{EVALUATION}/calibration_test.csv",
        accuracy_lab=f"{EVALUATION}/accuracy_lab.csv",
        statistics_lab=f"{EVALUATION}/statistics_lab.csv",
        calibration_lab=f"{EVALUATION}/calibration_lab.csv",
        families_lab=f"{EVALUATION}/families_lab.csv",
        chart=report(
            f"{EVALUATION}/figures/cost_accuracy.png",
            caption="../report/cost_accuracy.rst",
            category="Cost against accuracy",
        ),
        spread_chart=f"{EVALUATION}/figures/spread.png",
    params:
        variants=list(VARIANTS),
        settings=report_settings("moulds"),
        store=STORE,
    log:
        f"{R}/logs/studies/accuracy.log",
    threads: 1
    resources:
        runtime=30,
        mem_mb=4000,
    script:
        "../scripts/accuracy.py"


rule ladder:
    conda:
        CONDA_ENV
    input:
        moulds=sorted({moulds_of_batch(m) for m in STUDY_MOULDS}),
        dataset=rules.dataset.output,
    output:
        report(f"{STUDIES}/ladder.csv", caption="../report/ladder.rst", category="Simulator"),
    params:
        settings=report_settings("moulds", "ladder_moulds", "ladder_budgets", "ladder_seeds"),
        store=STORE,
    log:
        f"{R}/logs/studies/ladder.log",
    threads: 1
    resources:
        runtime=240,
        mem_mb=2000,
    script:
        "../scripts/ladder.py"


rule convergence:
    conda:
        CONDA_ENV
    input:
        moulds_of_batch(STUDY_MOULDS[0]),
    output:
        table=f"{STUDIES}/convergence.csv",
        chart=report(
            f"{STUDIES}/figures/convergence.png",
            caption="../report/convergence.rst",
            category="Simulator",
        ),
    params:
        settings=report_settings("convergence_seeds", "convergence_depths",
                                 "convergence_box_scales"),
        mould=STUDY_MOULDS[0],
    log:
        f"{R}/logs/studies/convergence.log",
    threads: 1
    resources:
        runtime=120,
        mem_mb=4000,
    script:
        "../scripts/convergence.py"


rule stability:
    conda:
        CONDA_ENV
    input:
        store_first("stability"),  # the numba cache is warm before any simulation job
    output:
        report(f"{STUDIES}/stability.csv", caption="../report/stability.rst", category="Simulator"),
    params:
        solvers=list(CONFIG.report["stability_solvers"]),
    log:
        f"{R}/logs/studies/stability.log",
    threads: 1
    resources:
        runtime=30,
        mem_mb=1000,
    script:
        "../scripts/stability.py"


rule fidelity:
    conda:
        CONDA_ENV
    input:
        manifest=store_first("fidelity"),  # the numba cache is warm before any simulation job
        checkpoints=expand(f"{R}/models/{{variant}}.pt", variant=list(VARIANTS)),
    output:
        report(f"{STUDIES}/fidelity.csv", caption="../report/fidelity.rst", category="Simulator"),
    params:
        variants=list(VARIANTS),
    log:
        f"{R}/logs/studies/fidelity.log",
    threads: 1
    resources:
        runtime=60,
        mem_mb=2000,
    script:
        "../scripts/fidelity.py"
