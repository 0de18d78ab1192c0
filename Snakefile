# condor: mould factory -> CONDOR simulation -> fields -> Zarr store -> surrogate -> report.
#   snakemake --cores 2                                   # embedded default config
#   snakemake --cores 2 --configfile config/tiny.yaml     # a smoke run in a few minutes
import sys
from pathlib import Path

from snakemake.utils import min_version

from condor.config import ConfigError, read_config_file

min_version("8.0")

# The embedded default config, read by condor first: a missing or broken file is one line
# that names it (and a YAML mistake's line). The --configfile files are read by Snakemake
# before this file runs, and their mistakes are its to report.
EMBEDDED_CONFIG = "config/config.yaml"
if Path(EMBEDDED_CONFIG).exists() or not workflow.overwrite_configfiles:
    try:
        read_config_file(EMBEDDED_CONFIG)
    except ConfigError as err:
        sys.exit(f"condor: {err}" + ("" if Path(EMBEDDED_CONFIG).exists() else
                                     " (the workflow's default; run snakemake in the folder "
                                     "that holds it, or give --configfile)"))


configfile: EMBEDDED_CONFIG


include: "workflow/rules/common.smk"
include: "workflow/rules/lock.smk"
include: "workflow/rules/repair.smk"
include: "workflow/rules/moulds.smk"
include: "workflow/rules/simulate.smk"
include: "workflow/rules/fields.smk"
include: "workflow/rules/surrogate.smk"
include: "workflow/rules/studies.smk"
include: "workflow/rules/design.smk"
include: "workflow/rules/report.smk"


# Each stage file appends what `all` builds to FINAL_TARGETS (defined in common.smk), and
# `all` asks for every other output too but the per-batch files (every_output): whatever is
# deleted is built again.
rule all:
    input:
        FINAL_TARGETS,
        every_output(),
    default_target: True
