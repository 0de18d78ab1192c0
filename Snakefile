# condor: mould factory -> CONDOR simulation -> fields -> Zarr store -> surrogate -> report.
#   snakemake --cores 2                                   # embedded default config
#   snakemake --cores 2 --configfile config/tiny.yaml     # a smoke run in a few minutes
from snakemake.utils import min_version

min_version("8.0")


configfile: "config/config.yaml"


include: "workflow/rules/common.smk"
include: "workflow/rules/lock.smk"
include: "workflow/rules/moulds.smk"
include: "workflow/rules/simulate.smk"
include: "workflow/rules/fields.smk"
include: "workflow/rules/surrogate.smk"
include: "workflow/rules/studies.smk"
include: "workflow/rules/design.smk"
include: "workflow/rules/report.smk"


# Each stage file appends what `all` builds to FINAL_TARGETS (defined in common.smk).
rule all:
    input:
        FINAL_TARGETS,
    default_target: True
