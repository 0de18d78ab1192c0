"""The SLURM workflow profile (profiles/slurm): resources for every rule, batching, and a dry
run of the paper-scale config through the SLURM executor plugin (skipped without it)."""

import importlib.util
import math
import re
import subprocess
import sys
from pathlib import Path

import pytest
import yaml

REPO = Path(__file__).resolve().parents[1]
PROFILE = REPO / "profiles" / "slurm" / "config.yaml"


def rule_names():
    names = []
    for smk in sorted((REPO / "workflow" / "rules").glob("*.smk")):
        names += re.findall(r"^rule (\w+):", smk.read_text(), re.M)
    return names


def local_rules():
    """Rules named in the workflow's `localrules:` blocks (they run beside Snakemake)."""
    names = {"all"}
    for smk in sorted((REPO / "workflow" / "rules").glob("*.smk")):
        for block in re.findall(r"^localrules:\n((?:[ \t]+\w+,?\n)+)", smk.read_text(), re.M):
            names |= set(re.findall(r"\w+", block))
    return names


@pytest.fixture(scope="module")
def profile():
    return yaml.safe_load(PROFILE.read_text())


def test_every_job_rule_has_runtime_memory_and_cores(profile):
    local = local_rules()
    assert {"init_store", "report"} <= local
    resources = profile["set-resources"]
    missing = [r for r in rule_names() if r not in local and r not in resources]
    assert not missing, f"rules without resources in {PROFILE}: {missing}"
    assert not set(resources) - set(rule_names()), "resources for rules that do not exist"
    for rule, res in resources.items():
        assert {"runtime", "mem_mb", "cpus_per_task"} <= set(res), rule
        assert res["runtime"] > 0 and res["mem_mb"] > 0 and res["cpus_per_task"] >= 1
    assert resources["train"].get("gpu", 0) >= 1
    assert profile["executor"] == "slurm"


def test_short_batch_steps_are_grouped(profile):
    groups = profile["groups"]
    assert groups["moulds"] == groups["simulate"] == groups["fields"]
    # One batch per job: the SLURM executor runs a group job's rules one at a time but asks
    # for the cores of every batch in it (profiles/slurm/config.yaml, docs/scale.md).
    assert profile["group-components"][groups["simulate"]] == 1


@pytest.mark.slow
@pytest.mark.skipif(importlib.util.find_spec("snakemake_executor_plugin_slurm") is None,
                    reason="snakemake-executor-plugin-slurm not installed (pip install -e '.[slurm]')")
def test_paper_config_dry_run_through_slurm(tmp_path, profile):
    cmd = [sys.executable, "-m", "snakemake", "-n", "--executor", "slurm",
           "--workflow-profile", str(REPO / "profiles" / "slurm"),
           "--configfile", str(REPO / "config" / "paper.yaml"),
           "--snakefile", str(REPO / "Snakefile"), "--directory", str(tmp_path)]
    proc = subprocess.run(cmd, capture_output=True, text=True, timeout=600)
    out = proc.stdout + proc.stderr
    assert proc.returncode == 0, out[-4000:]
    paper = yaml.safe_load((REPO / "config" / "paper.yaml").read_text())
    n_batches = math.ceil(paper["n_moulds"] / paper["batch_size"])
    counts = dict(re.findall(r"^(\w+)\s+(\d+)$", out, re.M))
    for rule in ("moulds", "simulate", "fields"):
        assert int(counts[rule]) == n_batches
    assert int(counts["report"]) == 1
    components = profile["group-components"][profile["groups"]["simulate"]]
    assert out.count("Group job batch") == math.ceil(n_batches / components)
    assert "gpu=1" in out  # the training job asks SLURM for a GPU
    assert not (tmp_path / "results").exists()  # a dry run writes nothing
