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


# The learning curves that chose the default surrogate's size are measured outside the workflow
# (benchmarks/bench_surrogate_curves.py: many trainings) and committed as small tables; the
# report shows them beside this run's own figures.
CURVE_TABLES = Path(workflow.basedir) / "docs" / "data"
LEARNING_CURVES = {  # keyed <curve>_curve: Snakemake reserves some input names ("size")
    f"{name}_curve": str(path)
    for name in ("data", "size", "epochs")
    if (path := CURVE_TABLES / f"surrogate_curve_{name}.csv").exists()
}
# The paired recipe study that set the default's training and the inputs study that set what
# it reads (docs/surrogate.md), as tables.
RECIPE_TABLES = [
    str(path)
    for name in ("recipes", "recipes_paired", "inputs", "inputs_paired", "tension", "tension_paired",
                 "weights", "weights_paired", "optimiser", "optimiser_paired", "mechanics",
                 "mechanics_paired", "pooled")
    if (path := CURVE_TABLES / f"surrogate_{name}.csv").exists()
]


rule learning_curves:
    conda:
        CONDA_ENV
    input:
        **LEARNING_CURVES,
    output:
        f"{R}/figures/learning_curves.png",
    log:
        f"{R}/logs/learning_curves.log",
    script:
        "../scripts/learning_curves.py"


localrules:
    learning_curves,
