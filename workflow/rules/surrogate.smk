# Stage 4: train each surrogate variant named in surrogate.variants, evaluate it on the test
# split, evaluate the baselines once, and gather one summary table.
from condor.surrogate.variants import workflow_variants

VARIANTS = workflow_variants(CONFIG)  # {name: settings}
EVALUATION = f"{R}/evaluation"


wildcard_constraints:
    variant="|".join(VARIANTS) or "(?!)",


rule train:
    conda:
        CONDA_ENV
    input:
        rules.dataset.output,
    output:
        checkpoint=f"{R}/models/{{variant}}.pt",
        history=f"{R}/models/{{variant}}_history.csv",
    params:
        settings=lambda wildcards: VARIANTS[wildcards.variant],
        device=CONFIG.surrogate["device"],
        store=STORE,
    log:
        f"{R}/logs/train/{{variant}}.log",
    priority: 10  # before the studies: it holds every core, they can share them after
    threads: CONFIG.surrogate["threads"]
    resources:
        runtime=24 * 60,
        mem_mb=8000,
        gpu=CONFIG.surrogate["gpus"],
    script:
        "../scripts/train.py"


rule evaluate:
    conda:
        CONDA_ENV
    input:
        checkpoint=f"{R}/models/{{variant}}.pt",
        dataset=rules.dataset.output,
    output:
        summary=f"{EVALUATION}/{{variant}}/summary.csv",
        tables=[t for mode in CONFIG.surrogate["eval_modes"]
                for t in evaluation_tables(f"{EVALUATION}/{{variant}}/{{variant}}_{mode}")],
        figures=report(
            directory(f"{EVALUATION}/{{variant}}/figures"),
            patterns=["{name}.png"],
            caption="../report/surrogate_evaluation.rst",
            category="Surrogate",
            subcategory="{variant}",
        ),
    params:
        modes=list(CONFIG.surrogate["eval_modes"]),
        device=CONFIG.surrogate["device"],
        store=STORE,
    log:
        f"{R}/logs/evaluate/{{variant}}.log",
    threads: CONFIG.surrogate["threads"]
    resources:
        runtime=60,
        mem_mb=8000,
        gpu=CONFIG.surrogate["gpus"],
    script:
        "../scripts/evaluate.py"


rule evaluate_baselines:
    conda:
        CONDA_ENV
    input:
        rules.dataset.output,
    output:
        summary=f"{EVALUATION}/baselines/summary.csv",
        tables=[t for method in ("masked_mean", "mould_blur")
                for t in evaluation_tables(f"{EVALUATION}/baselines/{method}")],
        figures=report(
            directory(f"{EVALUATION}/baselines/figures"),
            patterns=["{name}.png"],
            caption="../report/surrogate_baselines.rst",
            category="Surrogate",
            subcategory="baselines",
        ),
    params:
        store=STORE,
    log:
        f"{R}/logs/evaluate/baselines.log",
    resources:
        runtime=30,
        mem_mb=4000,
    script:
        "../scripts/evaluate_baselines.py"


rule surrogate_summary:
    conda:
        CONDA_ENV
    input:
        expand(f"{EVALUATION}/{{variant}}/summary.csv", variant=list(VARIANTS)),
        f"{EVALUATION}/baselines/summary.csv",
    output:
        report(
            f"{EVALUATION}/summary.csv",
            caption="../report/surrogate_summary.rst",
            category="Surrogate",
        ),
    log:
        f"{R}/logs/evaluate/summary.log",
    script:
        "../scripts/surrogate_summary.py"


localrules:
    surrogate_summary,


FINAL_TARGETS.extend(
    [
        *rules.surrogate_summary.output,
        *expand(f"{R}/models/{{variant}}_history.csv", variant=list(VARIANTS)),
    ]
)
