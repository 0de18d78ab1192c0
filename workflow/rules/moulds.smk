# Stage 1: the store, then mould geometry + input channels per batch, and the gallery.


rule init_store:
    conda:
        CONDA_ENV
    input:
        repair("init_store"),
    output:
        STORE_MANIFEST,
    params:
        store=STORE,
    log:
        f"{R}/logs/init_store.log",
    script:
        "../scripts/init_store.py"


rule moulds:
    conda:
        CONDA_ENV
    input:
        manifest=store_first("moulds"),
    output:
        f"{R}/moulds/batch_{{batch}}.json",
    params:
        ids=batch_ids,
        store=STORE,
    log:
        f"{R}/logs/moulds/batch_{{batch}}.log",
    priority: 20
    resources:
        runtime=10,
        mem_mb=1000,
    script:
        "../scripts/moulds.py"


rule gallery:
    conda:
        CONDA_ENV
    input:
        expand(f"{R}/moulds/batch_{{batch}}.json", batch=BATCH_IDS),
    output:
        gallery=f"{R}/figures/mould_gallery.png",
        regimes=f"{R}/figures/mould_regimes.csv",
    params:
        n=CONFIG.moulds["gallery"],
    log:
        f"{R}/logs/gallery.log",
    script:
        "../scripts/gallery.py"


FINAL_TARGETS.extend(rules.gallery.output)
