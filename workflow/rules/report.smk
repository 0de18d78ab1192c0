# Stage 6: one self-contained HTML report (condor.report; `snakemake --report` also builds
# Snakemake's own report from the figures marked in the rules).


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
