"""The workflow end to end on the tiny scene, through the `snakemake` command line.

Each test runs in its own temporary directory (`--directory`), with the repository's
Snakefile, profile and configs.
"""

import base64
import json
import os
import re
import signal
import subprocess
import sys
import time
from pathlib import Path

import numpy as np
import pandas as pd
import pytest
import xarray as xr
import yaml

REPO = Path(__file__).resolve().parents[1]
SNAKEMAKE = [sys.executable, "-m", "snakemake"]

pytestmark = pytest.mark.slow


def snakemake_args(workdir, *extra, cores=2):
    return [
        *SNAKEMAKE, "--cores", str(cores), "--snakefile", str(REPO / "Snakefile"),
        "--workflow-profile", str(REPO / "profiles" / "default"),
        "--directory", str(workdir), *extra,
    ]


def overlay(workdir, **config):
    """A config file layered over tiny.yaml (nested values survive, unlike --config)."""
    workdir.mkdir(parents=True, exist_ok=True)
    path = workdir / "overlay.yaml"
    path.write_text(yaml.safe_dump(config))
    return ("--configfile", str(REPO / "config" / "tiny.yaml"), str(path))


def run(workdir, *extra, cores=2, check=True):
    proc = subprocess.run(snakemake_args(workdir, *extra, cores=cores), capture_output=True, text=True)
    if check and proc.returncode != 0:
        raise AssertionError(f"snakemake failed ({proc.returncode}):\n{proc.stderr[-4000:]}")
    return proc


def store_of(workdir):
    return workdir / "results" / "dataset.zarr"


def assert_store_complete(store, n):
    ds = xr.open_zarr(store)
    assert ds.attrs["n_moulds"] == n and ds.sizes["sample"] == sum(ds.attrs["replicas"])
    status = ds["status"].values.astype(str)
    assert (status != "").all(), f"unfinished samples: {np.flatnonzero(status == '')}"
    ok = status == "ok"
    assert ok.sum() >= n - 1, f"too many failures: {dict(zip(*np.unique(status, return_counts=True)))}"
    fields = ds["fields"].values
    assert np.isfinite(fields[ok]).all()
    assert np.isnan(fields[~ok]).all()  # a failed simulation never becomes a sample
    assert (ds["inputs_ready"].values == 1).all()
    assert (ds["n_cells"].values[ok] > 0).all()
    return ds


TINY = ("--configfile", str(REPO / "config" / "tiny.yaml"))


def test_end_to_end_tiny(tmp_path):
    run(tmp_path, *TINY)
    ds = assert_store_complete(store_of(tmp_path), 16)
    inputs = ds["inputs"].values
    assert inputs.shape == (16 + 4 * 3, 2, 32, 32)  # 4 test moulds with 4 replicas each
    assert not (inputs[:, 0] & inputs[:, 1]).any()  # tether pixels are never mould pixels
    assert ds.attrs["scene"]["name"] == "tiny"
    assert set(ds["split"].values.astype(str)) <= {"train", "val", "test"}
    for figure in ("mould_gallery.png", "samples.png"):
        assert (tmp_path / "results" / "figures" / figure).stat().st_size > 5000
    report = (tmp_path / "results" / "report.html").read_text()
    assert report.count("data:image/png;base64,") >= 5  # figures are embedded, not linked
    # both accuracy tables, with every column the readers consume
    evaluation = tmp_path / "results" / "evaluation"
    accuracy = pd.read_csv(evaluation / "accuracy.csv")
    assert {"method", "family", "cpu_s_per_mould", "field_error", "field_error_lo",
            "field_error_hi"} <= set(accuracy.columns)
    assert "single simulation" in set(accuracy["method"])
    statistics = pd.read_csv(evaluation / "statistics.csv")
    assert {"method", "statistic", "r", "r_ceiling", "bias"} <= set(statistics.columns)
    assert set(statistics["n"]) == {3}  # report.moulds of tiny.yaml
    # the predictors on every test mould (4), beside the replicas' own references, and none
    # of the swept simulation methods
    every = pd.read_csv(evaluation / "statistics_test.csv")
    assert set(every["n"]) == {4}
    assert {"unet", "single simulation"} <= set(every["method"]) < set(statistics["method"])
    assert not every["method"].str.contains("anneal").any()
    assert set(pd.read_csv(evaluation / "calibration_test.csv")["n_moulds"]) == {4}
    every_error = pd.read_csv(evaluation / "accuracy_test.csv")
    assert set(every_error["n_moulds"]) == {4}
    assert {"unet", "single simulation"} <= set(every_error["method"])
    assert not every_error["method"].str.contains("anneal").any()
    # the expected fields are the mean of each test mould's replicas
    test = [int(m) for m in ds["replicated"].values]
    mould = test[0]
    samples = np.flatnonzero(ds["mould"].values == mould)
    np.testing.assert_allclose(ds["fields_mean"].values[0],
                               ds["fields"].values[samples].astype(float).mean(axis=0), rtol=1e-5)
    # Nothing left to do: a second run schedules no job.
    assert "Nothing to be done" in run(tmp_path, *TINY).stderr
    assert_cli_trains_the_workflows_model(tmp_path)


def assert_cli_trains_the_workflows_model(workdir):
    """`condor train --variant unet --config <the run's configs>` gives the workflow's
    checkpoint bit for bit: the same settings, data and weights."""
    import torch

    from condor.surrogate.checkpoint import load_checkpoint

    ours = workdir / "cli_unet.pt"
    subprocess.run([sys.executable, "-m", "condor.cli", "train", "--store", str(store_of(workdir)),
                    "--checkpoint", str(ours), "--variant", "unet", "--config",
                    str(REPO / "config" / "config.yaml"), str(REPO / "config" / "tiny.yaml")],
                   check=True, capture_output=True)
    theirs, ours = (load_checkpoint(p) for p in (workdir / "results" / "models" / "unet.pt", ours))
    assert ours["config"] == theirs["config"] and ours["data"] == theirs["data"]
    assert ours["generator"].keys() == theirs["generator"].keys()
    assert all(torch.equal(ours["generator"][k], theirs["generator"][k]) for k in ours["generator"])


def test_same_config_gives_identical_fields(tmp_path):
    first, second = tmp_path / "a", tmp_path / "b"
    for workdir in (first, second):
        run(workdir, *overlay(workdir, n_moulds=4, batch_size=2, split={"test": 1}), "--until", "dataset")
    a, b = (xr.open_zarr(store_of(w)) for w in (first, second))
    assert np.array_equal(a["fields"].values, b["fields"].values, equal_nan=True)
    assert np.array_equal(a["inputs"].values, b["inputs"].values)
    # byte-identical chunks, not just equal values
    for chunk in sorted((store_of(first) / "fields").rglob("c/*/*/*/*")):
        twin = store_of(second) / chunk.relative_to(store_of(first))
        assert chunk.read_bytes() == twin.read_bytes()


def incomplete_outputs(workdir):
    """Names of outputs Snakemake still marks incomplete (.snakemake/incomplete/<b64 path>)."""
    folder = workdir / ".snakemake" / "incomplete"
    names = set()
    for marker in folder.rglob("*") if folder.exists() else ():
        try:
            names.add(Path(base64.urlsafe_b64decode(marker.name).decode()).name)
        except (ValueError, UnicodeDecodeError):
            continue
    return names


def test_kill_and_resume(tmp_path):
    """SIGKILL the workflow part-way several times; the rerun completes every sample and
    leaves batches that had finished before the kills untouched."""
    extra = (*overlay(tmp_path, n_moulds=16, batch_size=2, split={"test": 2}), "--until", "dataset")
    done_dir = tmp_path / "results" / "fields"
    finished_before: dict[str, float] = {}
    for kill in range(3):
        proc = subprocess.Popen(snakemake_args(tmp_path, *extra, cores=1), stdout=subprocess.DEVNULL,
                                stderr=subprocess.DEVNULL, start_new_session=True)
        deadline = time.time() + 240
        target = len(finished_before) + 1
        while time.time() < deadline and proc.poll() is None:
            finished = {m.name for m in done_dir.glob("*.json")} - incomplete_outputs(tmp_path)
            if len(finished) >= target:
                break
            time.sleep(0.2)
        time.sleep(0.3 * kill)  # land the kill at different points of a job
        os.killpg(proc.pid, signal.SIGKILL)
        proc.wait()
        in_flight = incomplete_outputs(tmp_path)
        for marker in done_dir.glob("*.json"):
            # A job killed after writing its output but before Snakemake recorded it as
            # complete is legitimately redone; every other finished batch must be kept.
            if marker.name not in in_flight:
                finished_before.setdefault(marker.name, marker.stat().st_mtime_ns)
    assert finished_before, "the workflow finished no batch before being killed"
    assert len(finished_before) < 8, "the kills came too late to interrupt anything"
    proc = run(tmp_path, *extra)
    assert_store_complete(store_of(tmp_path), 16)
    for name, mtime in finished_before.items():
        assert (done_dir / name).stat().st_mtime_ns == mtime, f"{name} was recomputed"
    # the rerun only ran the missing batches
    rerun_jobs = len(re.findall(r"^(?:local)?rule fields:", proc.stderr, re.M))
    assert rerun_jobs == 8 - len(finished_before)
    summary = {}
    for marker in done_dir.glob("*.json"):
        summary.update(json.loads(marker.read_text()))
    moulds = sorted({int(k.split("/")[0]) for k in summary})
    assert moulds == list(range(16))  # none missing, none duplicated


def test_bad_config_stops_with_named_key(tmp_path):
    proc = run(tmp_path, *TINY, "-n", "--config", "n_moulds=-3", check=False)
    assert proc.returncode != 0
    assert "n_moulds" in proc.stderr + proc.stdout
    proc = run(tmp_path, *TINY, "-n", "--config", "solvr=anneal", check=False)
    assert proc.returncode != 0
    assert "solvr" in proc.stderr + proc.stdout
    assert not store_of(tmp_path).exists()


@pytest.mark.parametrize("change, named, why", [
    ({"scene_overrides": {"box": 100000}}, "config key scene_overrides/box = 100000: ",
     "the limit is 200,000 a mould"),
    ({"simulation": {"replicas": {"test": 1}}}, "config key simulation/replicas/test: 1 ",
     "4 or more replicas"),
])
def test_a_config_that_would_fail_late_stops_before_any_job(tmp_path, change, named, why):
    """Issue 33, items 10 and 11: one line naming the key, before the DAG (`-n` shows it)."""
    proc = run(tmp_path, *overlay(tmp_path, **change), "-n", check=False)
    assert proc.returncode != 0 and "Traceback" not in proc.stderr
    lines = [line for line in proc.stderr.splitlines() if line.startswith("condor: ")]
    assert len(lines) == 1 and named in lines[0] and why in lines[0]
    assert not (tmp_path / "results").exists()


def test_lint_is_clean():
    proc = subprocess.run([*SNAKEMAKE, "--lint", "--snakefile", str(REPO / "Snakefile")], cwd=REPO,
                          capture_output=True, text=True)
    assert proc.returncode == 0, proc.stderr[-2000:]
    assert "Lints for" not in proc.stdout + proc.stderr, (proc.stdout + proc.stderr)[-3000:]
