# Stage 2: CONDOR simulation of every replica of every mould of a batch.


rule simulate:
    conda:
        CONDA_ENV
    input:
        moulds=f"{R}/moulds/batch_{{batch}}.json",
        repair=repair("simulate"),
    output:
        directory(f"{R}/sims/batch_{{batch}}"),
    log:
        f"{R}/logs/simulate/batch_{{batch}}.log",
    # the critical path first (dataset, then training); the studies fill the cores after
    priority: 20
    threads: 1
    resources:
        runtime=60,
        mem_mb=2000,
    script:
        "../scripts/simulate.py"
