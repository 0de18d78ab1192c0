"""The tiny workflow through a real SLURM cluster (issue 31): profiles/slurm submits every job
with sbatch to a single-node cluster on this machine (profiles/slurm/localhost-cluster.sh), and
the store it builds is bit-identical to a local run's. Also the faults a cluster has: a job
cancelled with scancel, a job killed by its time limit, a drained node, and a second submission
on the same results folder.

The cluster needs root (slurmd and munged) and Debian's packages (slurm-wlm, munge; `.ci/run`
installs them). Where it cannot start, these tests FAIL with the reason: never skipped.

Every SLURM job's record (squeue, which keeps finished jobs for MinJobAge = 1 hour) is printed.
"""

import os
import re
import signal
import shutil
import socket
import subprocess
import sys
import time
from pathlib import Path

import pytest
import yaml

from conftest import build_once

REPO = Path(__file__).resolve().parents[1]
CLUSTER = REPO / "profiles" / "slurm" / "localhost-cluster.sh"
TINY = ("--configfile", str(REPO / "config" / "tiny.yaml"))
HOST = socket.gethostname().split(".")[0]
RECORD = "%i|%j|%k|%T|%P|%a|%C|%m|%l|%b|%r|%M"
# The status query: this cluster has no accounting database (no sacct), squeue keeps finished
# jobs an hour. The first status check after 2 s (the plugin's default, 40 s, suits a queue).
SLURM = ("--executor", "slurm", "--workflow-profile", str(REPO / "profiles" / "slurm"),
         "--slurm-status-command", "squeue", "--slurm-init-seconds-before-status-checks", "2")
# A site's account and partition, the way the profile's header advises.
SITE = ("--default-resources", "slurm_account=condor-test", "slurm_partition=compute")
LIMIT_S = 1500  # a deadline only (a run takes 2-5 min): a run that hangs fails, and CI goes on

# not in the default run (pyproject's addopts): `python -m pytest -q -m cluster`, as .ci/run does
pytestmark = [pytest.mark.slow, pytest.mark.cluster]


def sh(*cmd, check=True, timeout=60):
    proc = subprocess.run(cmd, capture_output=True, text=True, timeout=timeout)
    if check and proc.returncode != 0:
        raise AssertionError(f"{' '.join(cmd)} failed ({proc.returncode}): {proc.stderr}")
    return proc.stdout


@pytest.fixture(scope="module")
def cluster():
    """The localhost cluster, started if it is not running; a failure names the cause."""
    if shutil.which("sbatch") is None or shutil.which("slurmd") is None:
        pytest.fail("SLURM is not installed: run `profiles/slurm/localhost-cluster.sh install` "
                    "as root (Debian's slurm-wlm and munge; .ci/run does it)")
    up = subprocess.run(["sinfo", "-h", "-n", HOST, "-o", "%T"], capture_output=True, text=True)
    if up.returncode != 0 or up.stdout.strip() not in ("idle", "mixed", "allocated"):
        if os.geteuid() != 0:
            pytest.fail(f"no SLURM cluster answers on {HOST} (sinfo: {up.stderr.strip() or up.stdout.strip()}) "
                        f"and starting one needs root: sudo {CLUSTER} start")
        start = subprocess.run([str(CLUSTER), "start"], capture_output=True, text=True, timeout=300)
        if start.returncode != 0:
            pytest.fail(f"the SLURM cluster did not start ({CLUSTER} start):\n{start.stderr[-3000:]}")
    partitions = sh("sinfo", "-h", "-o", "%R").split()
    assert "compute" in partitions, f"partition 'compute' missing ({partitions}): restart with {CLUSTER} start"
    return HOST


def snakemake(workdir, *extra):
    return [sys.executable, "-m", "snakemake", "--snakefile", str(REPO / "Snakefile"),
            "--directory", str(workdir), *extra]


def start(workdir, *extra, log):
    """A SLURM run in the background; its whole log goes to `log`."""
    with open(log, "w") as out:  # the child keeps its own copy of the file
        return subprocess.Popen(snakemake(workdir, *SLURM, *extra), stdout=out,
                                stderr=subprocess.STDOUT, start_new_session=True)


def stop(proc):
    """End a run still going: SIGTERM to its session, SIGKILL if it has not ended 30 s later."""
    if proc.poll() is not None:
        return
    os.killpg(proc.pid, signal.SIGTERM)
    try:
        proc.wait(timeout=30)
    except subprocess.TimeoutExpired:
        os.killpg(proc.pid, signal.SIGKILL)
        proc.wait()


def finish(proc, log, timeout=LIMIT_S):
    try:
        proc.wait(timeout=timeout)
    except subprocess.TimeoutExpired:
        stop(proc)
        raise AssertionError(f"the SLURM run did not finish in {timeout} s:\n{tail(log)}")
    return proc.returncode


def tail(log, n=4000):
    return Path(log).read_text()[-n:]


def run_id(log, deadline):
    """The run's SLURM job name (the plugin names every job of a run with one UUID)."""
    while time.time() < deadline:
        found = re.search(r"^SLURM run ID: (\S+)", Path(log).read_text(), re.M)
        if found:
            return found.group(1)
        time.sleep(0.5)
    raise AssertionError(f"no SLURM run ID in the log:\n{tail(log)}")


def jobs(name):
    """squeue's records of one run's jobs (finished ones included): a list of dicts."""
    keys = ["id", "name", "comment", "state", "partition", "account", "cpus", "memory",
            "time_limit", "tres", "reason", "time"]
    out = sh("squeue", "--states=all", "--noheader", "--name", name, "--format", RECORD)
    return [dict(zip(keys, line.split("|"))) for line in out.splitlines() if line.strip()]


def details(job_id):
    """`scontrol show job`'s fields of one job (what sbatch was asked for)."""
    out = sh("scontrol", "show", "job", "--oneliner", job_id)
    return dict(f.split("=", 1) for f in out.split() if "=" in f)


def megabytes(memory):
    """squeue's memory (e.g. 2000M, 62.50G) in MB."""
    value, unit = float(memory[:-1]), memory[-1]
    return round(value * {"K": 1 / 1024, "M": 1, "G": 1024, "T": 1024**2}[unit])


def record(name):
    """The run's jobs as squeue prints them, for the test's output."""
    return sh("squeue", "--states=all", "--name", name, "--format", RECORD)


def wait_for(what, condition, deadline, log, poll=0.5):
    while time.time() < deadline:
        value = condition()
        if value:
            return value
        time.sleep(poll)
    raise AssertionError(f"timed out waiting for {what}:\n{tail(log)}")


def submitted(log):
    """The (rule, SLURM job id) pairs a run's log says it submitted."""
    return re.findall(r"has been submitted with SLURM jobid (\d+) \(log: .*/slurm_logs/(\w+)/",
                      Path(log).read_text())


def store_files(store):
    return {p.relative_to(store): p.read_bytes() for p in sorted(store.rglob("*")) if p.is_file()}


# What a simulation measured about itself, not data: the solver's CPU seconds differ between
# any two runs (the local reference against itself too).
MEASURED = ("solver_seconds",)


def assert_stores_identical(store, reference):
    """Every file of the store bit-identical to the reference's, the timings aside; returns
    (files compared, files of timings)."""
    mine, theirs = store_files(store), store_files(reference)
    assert mine.keys() == theirs.keys(), f"files differ: {sorted(set(mine) ^ set(theirs))[:10]}"
    timing = [p for p in mine if p.parts[0] in MEASURED]
    differ = [str(p) for p in mine if p.parts[0] not in MEASURED and mine[p] != theirs[p]]
    assert not differ, f"{len(differ)} of {len(mine)} files differ from the local run's, e.g. {differ[:5]}"
    return len(mine) - len(timing), len(timing)


def _build_local(workdir):
    workdir.mkdir()
    proc = subprocess.run(snakemake(workdir, *TINY, "--cores", "2", "dataset"),
                          capture_output=True, text=True, timeout=LIMIT_S)
    assert proc.returncode == 0, proc.stderr[-4000:]


@pytest.fixture(scope="module")
def local_store(tmp_path_factory):
    """The tiny dataset built locally (profiles/default), the reference of every SLURM run:
    built once for the session, whichever xdist worker asks first (the others wait)."""
    return build_once(tmp_path_factory, "slurm_local", _build_local) / "results" / "dataset.zarr"


def show(capsys, title, text):
    with capsys.disabled():  # visible with pytest -q too
        print(f"\n--- {title}\n{text}", flush=True)


def test_tiny_workflow_through_slurm(cluster, local_store, tmp_path, capsys):
    """The whole tiny workflow to the report through sbatch, with the site's account and
    partition; while it runs, a second submission is refused and the node is drained and
    brought back. The store is bit-identical to the local run's."""
    log = tmp_path / "slurm.log"
    proc = start(tmp_path, *TINY, *SITE, log=log)
    try:
        deadline = time.time() + LIMIT_S
        name = run_id(log, deadline)
        # A second submission on the same results folder is refused by condor's lock.
        wait_for("the run's lock", (tmp_path / "results" / ".condor.lock").exists, deadline, log)
        second = subprocess.run(snakemake(tmp_path, *SLURM, *TINY, *SITE), capture_output=True,
                                text=True, timeout=600)
        assert second.returncode != 0
        assert "is in use by another run" in second.stderr + second.stdout
        # Drain the node while a job runs: the jobs submitted meanwhile wait, then run.
        wait_for("a running SLURM job", lambda: any(j["state"] == "RUNNING" for j in jobs(name)),
                 deadline, log)
        sh("scontrol", "update", f"NodeName={cluster}", "State=DRAIN", "Reason=condor-test")
        try:
            pending = wait_for("a job held by the drained node",
                               lambda: [j for j in jobs(name) if j["state"] == "PENDING"],
                               deadline, log, poll=1)
            drained = sh("sinfo", "-h", "-n", cluster, "-o", "%T").strip()
            show(capsys, f"node {cluster} {drained}; held jobs", record(name))
        finally:
            sh("scontrol", "update", f"NodeName={cluster}", "State=RESUME")
        assert drained in ("drained", "draining") and pending
        assert finish(proc, log) == 0, tail(log)
    finally:
        stop(proc)
    records = jobs(name)
    show(capsys, f"squeue --states=all --name {name}  (full log: {log})", record(name))
    assert (tmp_path / "results" / "report.html").stat().st_size > 10_000
    n, timings = assert_stores_identical(tmp_path / "results" / "dataset.zarr", local_store)
    show(capsys, "store", f"{n} files bit-identical to the local run's (and {timings} of solver timings)")
    # What each job was submitted with: the site's account and partition on every job, and the
    # profile's per-rule resources (not replaced by --default-resources).
    assert records and all(j["state"] == "COMPLETED" for j in records), records
    assert {j["partition"] for j in records} == {"compute"}
    assert {j["account"] for j in records} == {"condor-test"}
    profile = yaml.safe_load((REPO / "profiles" / "slurm" / "config.yaml").read_text())
    by_rule = {j["comment"]: j for j in records}
    train = profile["set-resources"]["train"]
    asked = details(by_rule["rule_train_wildcards_unet"]["id"])
    show(capsys, "the training job (scontrol show job)",
         " ".join(f"{k}={asked[k]}" for k in ("TresPerJob", "NumCPUs", "MinMemoryNode", "TimeLimit")))
    assert asked["TresPerJob"] == f"gres:gpu:{train['gpu']}"  # sbatch --gpus=1
    assert int(asked["NumCPUs"]) == train["cpus_per_task"]
    assert megabytes(by_rule["rule_train_wildcards_unet"]["memory"]) == train["mem_mb"]
    assert by_rule["rule_train_wildcards_unet"]["time_limit"] == "1-00:00:00" and train["runtime"] == 1440
    for rule in ("evaluate_baselines", "accuracy", "design"):
        res = profile["set-resources"][rule]
        assert megabytes(by_rule[f"rule_{rule}"]["memory"]) == res["mem_mb"], by_rule[f"rule_{rule}"]
        assert "TresPerJob" not in details(by_rule[f"rule_{rule}"]["id"])  # no GPU unless asked
    # the batch steps (moulds, simulate, fields) ran as group jobs, not one job each
    assert any(c.startswith("rule_batch_") for c in by_rule) and "rule_simulate" not in by_rule


def test_cancelled_and_timed_out_jobs_then_rerun(cluster, local_store, tmp_path, capsys):
    """One batch job cancelled with scancel while it runs, another killed by its time limit
    (hung: stopped, then its limit lowered to a minute). The run fails; the rerun submits only
    the killed batches and its store is bit-identical to the local run's."""
    extra = (*TINY, "--retries", "0", "dataset")  # one batch per job (the profile)
    log = tmp_path / "first.log"
    proc = start(tmp_path, *extra, log=log)
    try:
        deadline = time.time() + LIMIT_S
        name = run_id(log, deadline)
        running = wait_for(
            "two running batch jobs",
            lambda: (lambda r: r if len(r) >= 2 else None)(
                [j for j in jobs(name) if j["state"] == "RUNNING" and j["comment"].startswith("rule_batch_")]),
            deadline, log, poll=0.2)
        cancelled, hung = running[0]["id"], running[1]["id"]
        sh("scancel", cancelled)
        for line in sh("scontrol", "listpids", hung).splitlines()[1:]:
            try:
                os.kill(int(line.split()[0]), signal.SIGSTOP)
            except (ProcessLookupError, ValueError):
                pass
        sh("scontrol", "update", f"JobId={hung}", "TimeLimit=1")
        assert finish(proc, log) != 0, "the run succeeded although two of its jobs were killed"
    finally:
        stop(proc)
    states = {j["id"]: j["state"] for j in jobs(name)}
    show(capsys, f"first run: squeue --states=all --name {name}", record(name))
    assert states[cancelled] == "CANCELLED" and states[hung] == "TIMEOUT", states
    # the workflow's log shows each job's end as SLURM wrote it
    text = log.read_text()
    assert f"*** JOB {cancelled} ON {cluster} CANCELLED AT" in text, tail(log)
    assert re.search(rf"\*\*\* JOB {hung} ON {cluster} CANCELLED AT \S+ DUE TO TIME LIMIT", text), tail(log)

    rerun_log = tmp_path / "rerun.log"
    proc = start(tmp_path, *extra, log=rerun_log)
    assert finish(proc, rerun_log) == 0, tail(rerun_log)
    rerun = run_id(rerun_log, time.time() + 10)
    show(capsys, f"rerun: squeue --states=all --name {rerun}", record(rerun))
    batches = [rule for _, rule in submitted(rerun_log) if rule.startswith("group_batch")]
    assert len(batches) == 2, f"the rerun submitted {len(batches)} batch jobs, not the 2 killed ones"
    n, timings = assert_stores_identical(tmp_path / "results" / "dataset.zarr", local_store)
    show(capsys, "store after the rerun",
         f"{n} files bit-identical to the local run's (and {timings} of solver timings)")
