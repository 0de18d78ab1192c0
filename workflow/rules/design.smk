# Stage 6: design moulds for one objective with the first surrogate variant, confirm the best
# and a random sample by simulation with replicas, and hand over drawings (condor.stages.design).
DESIGN = f"{R}/design"


rule design:
    conda:
        CONDA_ENV
    input:
        checkpoint=f"{R}/models/{list(VARIANTS)[0]}.pt",
        dataset=rules.dataset.output,
    output:
        table=f"{DESIGN}/designs.csv",
        summary=f"{DESIGN}/summary.csv",
        confirmation=report(
            f"{DESIGN}/figures/confirmation.png",
            caption="../report/design.rst",
            category="Design",
        ),
        history=f"{DESIGN}/figures/search_history.png",
        designs=f"{DESIGN}/figures/designs.png",
    params:
        settings=CONFIG.to_dict()["design"],
        store=STORE,
    log:
        f"{R}/logs/design.log",
    threads: 1
    resources:
        runtime=60,
        mem_mb=4000,
    script:
        "../scripts/design.py"
