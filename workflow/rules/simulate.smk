# Stage 2: CONDOR simulation of each mould of a batch (solver and budget from the config).


rule simulate:
    conda:
        CONDA_ENV
    input:
        f"{R}/moulds/batch_{{batch}}.json",
    output:
        directory(f"{R}/sims/batch_{{batch}}"),
    log:
        f"{R}/logs/simulate/batch_{{batch}}.log",
    threads: 1
    resources:
        runtime=60,
        mem_mb=2000,
    script:
        "../scripts/simulate.py"
