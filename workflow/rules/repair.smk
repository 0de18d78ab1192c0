# The repair markers of common.smk's `repair()`: an empty file whose fresh name makes
# Snakemake rerun the one job that needs it (see common.smk).


rule repair_marker:
    output:
        temp(f"{R}/.repair/{{name}}"),
    log:
        f"{R}/logs/repair/{{name}}.log",
    conda:
        CONDA_ENV
    shell:
        "touch {output} 2> {log}"
