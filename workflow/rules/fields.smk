# Stage 3: rasterise each simulation into the 8 fields and write the finished samples; then
# the finished dataset (expected fields of replicated moulds, the per-sample table).


rule fields:
    conda:
        CONDA_ENV
    input:
        sims=f"{R}/sims/batch_{{batch}}",
        moulds=f"{R}/moulds/batch_{{batch}}.json",
        manifest=store_first("fields"),
        repair=repair("fields"),
    output:
        f"{R}/fields/batch_{{batch}}.json",
    params:
        store=STORE,
    log:
        f"{R}/logs/fields/batch_{{batch}}.log",
    priority: 20
    resources:
        runtime=10,
        mem_mb=2000,
    script:
        "../scripts/fields.py"


rule dataset:
    conda:
        CONDA_ENV
    input:
        batches=expand(f"{R}/fields/batch_{{batch}}.json", batch=BATCH_IDS),
        repair=repair("dataset"),
    output:
        f"{R}/dataset_summary.csv",
    params:
        store=STORE,
    log:
        f"{R}/logs/dataset.log",
    priority: 20  # training waits on it (a priority does not pass to a job's inputs)
    script:
        "../scripts/dataset.py"


rule sample_figure:
    conda:
        CONDA_ENV
    input:
        f"{R}/dataset_summary.csv",
    output:
        f"{R}/figures/samples.png",
    params:
        store=STORE,
    log:
        f"{R}/logs/sample_figure.log",
    script:
        "../scripts/sample_figure.py"


FINAL_TARGETS.extend([*rules.dataset.output, *rules.sample_figure.output])


rule dataset_card:
    conda:
        CONDA_ENV
    input:
        rules.dataset.output,
    output:
        f"{R}/README.md",
    params:
        store=STORE,
    log:
        f"{R}/logs/dataset_card.log",
    script:
        "../scripts/dataset_card.py"


FINAL_TARGETS.extend(rules.dataset_card.output)
