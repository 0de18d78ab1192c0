# Config validation and helpers shared by every rule.
from snakemake.utils import validate

from condor import config as condor_config

validate(config, schema="../../config/config.schema.yaml")
condor_config.check_consistency(config)

R = config["results"]
STORE = f"{R}/dataset.zarr"
# The store's root metadata appears (atomically) once the store exists; per-sample writes
# never touch it, so downstream jobs are not re-triggered by them.
STORE_READY = f"{STORE}/zarr.json"
BATCHES = condor_config.batches(config)
BATCH_IDS = [f"{b:04d}" for b in range(len(BATCHES))]
# Software for --software-deployment-method conda (the README venv is the usual route).
CONDA_ENV = "../envs/condor.yaml"
FINAL_TARGETS = []  # each stage file appends the outputs `all` needs


wildcard_constraints:
    batch=r"\d{4}",


def evaluation_tables(method_prefix):
    """The per-method CSV tables `condor.surrogate.evaluate` writes into one folder."""
    return [f"{method_prefix}_{table}.csv" for table in ("mae", "correlations")]


def batch_ids(wildcards):
    return list(BATCHES[int(wildcards.batch)])


localrules:
    all,
    init_store,
    dataset,
