"""The workflow end to end on the tiny scene, through the `snakemake` command line.

The finished tiny run is built once per session (`tiny_run`, tests/conftest.py); every other
run here has its own temporary directory (`--directory`), with the repository's Snakefile,
profile and configs.
"""

import base64
import json
import os
import re
import signal
import subprocess
import sys
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


def test_end_to_end_tiny(tiny_run, tiny_copy):
    ds = assert_store_complete(store_of(tiny_run), 16)
    inputs = ds["inputs"].values
    assert inputs.shape == (16 + 6 * 3, 2, 32, 32)  # 6 test moulds (4 paper, 2 lab), 4 replicas each
    assert not (inputs[:, 0] & inputs[:, 1]).any()  # tether pixels are never mould pixels
    assert ds.attrs["scene"]["name"] == "tiny"
    assert set(ds["split"].values.astype(str)) <= {"train", "val", "test"}
    for figure in ("mould_gallery.png", "samples.png"):
        assert (tiny_run / "results" / "figures" / figure).stat().st_size > 5000
    report = (tiny_run / "results" / "report.html").read_text()
    assert report.count("data:image/png;base64,") >= 5  # figures are embedded, not linked
    # both accuracy tables, with every column the readers consume
    evaluation = tiny_run / "results" / "evaluation"
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
    # each mould's geometry in the store, in every replica, is the one its batch's JSON holds
    from condor.data.dataset import mould_geometry
    from condor.stages.build import load_moulds

    batches = sorted((tiny_run / "results" / "moulds").glob("batch_*.json"))
    moulds = [m for path in batches for m in load_moulds(path)]
    assert sorted(m.mould_id for m in moulds) == list(range(16))
    for made in moulds:
        for sample in np.flatnonzero(ds["mould"].values == made.mould_id):
            polygon, tethers = mould_geometry(ds, int(sample))
            assert polygon.equals_exact(made.polygon, 0.0)
            np.testing.assert_array_equal(tethers, made.tethers)
    # Nothing left to do: a second run (on a copy: the run is shared) schedules no job.
    assert "Nothing to be done" in run(tiny_copy, *TINY).stderr
    assert_cli_trains_the_workflows_model(tiny_copy)


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


def incomplete_outputs(workdir):
    """Outputs Snakemake still marks incomplete (.snakemake/incomplete/<b64 path>), as paths
    relative to the working directory."""
    folder = workdir / ".snakemake" / "incomplete"
    paths = set()
    for marker in folder.rglob("*") if folder.exists() else ():
        try:
            paths.add(Path(base64.urlsafe_b64decode(marker.name).decode()).as_posix())
        except (ValueError, UnicodeDecodeError):
            continue
    return paths


def store_chunks(workdir, arrays=("fields", "inputs", "lattice")):
    root = store_of(workdir)
    return {p.relative_to(root): p.read_bytes() for a in arrays for p in sorted((root / a).rglob("*"))
            if p.is_file()}


# A job of a run started with it in PYTHONPATH kills its whole process group (Snakemake and
# its jobs, as a SIGKILL of the run would) at a point the test names, in the run's own code
# path: CONDOR_TEST_KILL = "simulation:N" (once the run's Nth simulation is saved),
# "sample:N" (once its Nth sample is written into the store) or "fields_job:N" (when the run's
# Nth fields job starts writing, before it writes); the run's processes count in
# CONDOR_TEST_KILL_COUNTER. No poll and no race: the kill lands exactly there.
KILL_HOOK = """
import os
import signal

_spec = os.environ.get("CONDOR_TEST_KILL")
if _spec:
    _point, _nth = _spec.split(":")

    def _reached():
        with open(os.environ["CONDOR_TEST_KILL_COUNTER"], "a+") as counter:
            counter.write(f"{os.getpid()}\\n")
            counter.seek(0)
            return len(counter.read().split()) >= int(_nth)

    def _kill():
        os.killpg(os.getpgrp(), signal.SIGKILL)

    if _point == "simulation":
        from condor.model.simulate import SimResult

        _save = SimResult.save

        def _saved(self, path):
            _save(self, path)
            if _reached():
                _kill()

        SimResult.save = _saved
    else:
        import condor.data.store as _store

        _write, _started = _store.write_sample, []

        def _written(*args, **kwargs):
            if _point == "fields_job" and not _started:
                _started.append(True)
                if _reached():
                    _kill()
            result = _write(*args, **kwargs)
            if _point == "sample" and _reached():
                _kill()
            return result

        _store.write_sample = _written
"""


def killed_run(workdir, point: str, *extra) -> subprocess.CompletedProcess:
    """A run whose jobs SIGKILL it at `point` (KILL_HOOK); AssertionError if it ends first."""
    hook = workdir / "kill_hook" / point.replace(":", "_")
    hook.mkdir(parents=True)
    (hook / "sitecustomize.py").write_text(KILL_HOOK)
    env = {**os.environ, "CONDOR_TEST_KILL": point,
           "CONDOR_TEST_KILL_COUNTER": str(hook / "counter"),
           "PYTHONPATH": os.pathsep.join(filter(None, [str(hook), os.environ.get("PYTHONPATH")]))}
    proc = subprocess.run(snakemake_args(workdir, *extra, cores=1), capture_output=True,
                          text=True, env=env, start_new_session=True)
    assert proc.returncode == -signal.SIGKILL, \
        f"the run was not killed at {point} ({proc.returncode}):\n{proc.stderr[-3000:]}"
    return proc


def test_kill_and_resume_gives_the_uninterrupted_store(request, tmp_path):
    """SIGKILL the dataset stage at three points: part-way through a batch's simulations (the
    run's first simulation saved), part-way through a batch's writes into the store (its first
    sample written), and just after a batch finished (as the run's second fields job starts).
    The rerun completes every sample, leaves the batches that had finished untouched, and
    gives the same store, chunk for chunk, as the uninterrupted run of the same config
    (`tiny_run`, built in another folder)."""
    extra = (*TINY, "--until", "dataset")
    results = tmp_path / "results"
    n_batches = 4  # tiny.yaml: 16 moulds, 4 a batch
    finished_before: dict[str, int] = {}
    for point in ("simulation:1", "sample:1", "fields_job:2"):
        killed_run(tmp_path, point, *extra)
        in_flight = {Path(p).name for p in incomplete_outputs(tmp_path) if "/fields/" in p}
        for marker in (results / "fields").glob("*.json"):
            # A job killed after writing its output but before Snakemake recorded it as
            # complete is legitimately redone; every other finished batch must be kept.
            if marker.name not in in_flight:
                finished_before.setdefault(marker.name, marker.stat().st_mtime_ns)
    assert 0 < len(finished_before) < n_batches
    proc = run(tmp_path, *extra)
    assert_store_complete(store_of(tmp_path), 16)
    for name, mtime in finished_before.items():
        assert (results / "fields" / name).stat().st_mtime_ns == mtime, f"{name} was recomputed"
    # the rerun only ran the missing batches
    rerun_jobs = len(re.findall(r"^(?:local)?rule fields:", proc.stderr, re.M))
    assert rerun_jobs == n_batches - len(finished_before)
    summary = {}
    for marker in (results / "fields").glob("*.json"):
        summary.update(json.loads(marker.read_text()))
    moulds = sorted({int(k.split("/")[0]) for k in summary})
    assert moulds == list(range(16))  # none missing, none duplicated
    # the same config gives the same data, byte for byte, killed or not, in another folder
    # (the shared run asked for only now: this test need not wait for it to start)
    tiny_run = request.getfixturevalue("tiny_run")
    resumed, uninterrupted = store_chunks(tmp_path), store_chunks(tiny_run)
    assert resumed.keys() == uninterrupted.keys()
    assert all(resumed[k] == uninterrupted[k] for k in uninterrupted)


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
    # issue 44, probe 7: the accuracy study silently swept 4 moulds of the 9 asked for
    ({"report": {"moulds": 9}}, "config key report/moulds: 9, ",
     "the test set holds 6 moulds"),
    ({"report": {"ladder_moulds": 4}}, "config key report/ladder_moulds: 4, ",
     "report/moulds = 3"),
])
def test_a_config_that_would_fail_late_stops_before_any_job(tmp_path, change, named, why):
    """Issue 33, items 10 and 11, and a value that cannot be honoured (issue 44): one line
    naming the key, before the DAG (`-n` shows it)."""
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
