"""Nothing lost, nothing mixed: the workflow and the CLI under a careless user's mistakes.

Each test copies the session's finished tiny run (`tiny_run`, tests/conftest.py: 16 moulds in
4 batches of 4; test moulds 4, 6, 7 and 9 with 4 replicas, samples 16-27) and makes one
mistake on the copy."""

import os
import shutil
import signal
import subprocess
import time
from pathlib import Path

import numpy as np
import pytest
import xarray as xr

from condor.data.store_check import check_store
from conftest import condor_cli
from test_cli_surrogate import _without_write_permission
from test_workflow import REPO, TINY, run, snakemake_args

pytestmark = pytest.mark.slow

# The tiny scene, cut down, for runs of their own: 8 moulds in 4 batches, 2 test moulds of 4
# replicas (the fewest the studies take: condor.studies.recipes.MIN_REPLICAS).
SMALL = {"n_moulds": 8, "batch_size": 2, "split": {"test": 2},
         "simulation": {"replicas": {"test": 4}}}


def small_args(workdir, *extra):
    import yaml

    workdir.mkdir(parents=True, exist_ok=True)
    (workdir / "small.yaml").write_text(yaml.safe_dump(SMALL))
    return ("--configfile", str(REPO / "config" / "tiny.yaml"), str(workdir / "small.yaml"),
            *extra)


@pytest.fixture
def folder(tiny_copy):
    """A private copy of the finished tiny run (mtimes kept, so nothing looks stale)."""
    return tiny_copy


def tiny_args(*extra):
    return (*TINY, *extra)


def store(workdir):
    return workdir / "results" / "dataset.zarr"


def fields_of(workdir):
    return xr.open_zarr(store(workdir))["fields"].values


def test_forcerun_init_store_keeps_every_sample(folder):
    before = fields_of(folder)
    run(folder, *tiny_args("--until", "dataset", "--forcerun", "init_store"))
    assert (check_store(store(folder))["state"] == "ok").all()
    np.testing.assert_array_equal(fields_of(folder), before)


def test_store_created_but_not_recorded_is_kept(folder):
    """The window between the store's creation and init_store's completion (a kill there):
    the store exists, the job's output does not. The rerun keeps the store and finishes."""
    before = fields_of(folder)
    (folder / "results" / "dataset.json").unlink()
    proc = run(folder, "results/dataset.json", *TINY)
    assert "rule init_store" in proc.stderr and (folder / "results" / "dataset.json").is_file()
    np.testing.assert_array_equal(fields_of(folder), before)


@pytest.mark.parametrize("change", ["seed=7", "n_moulds=10", "simulation={'solver': 'anneal'}"])
def test_a_changed_data_key_stops_before_anything_runs(folder, change):
    proc = run(folder, *tiny_args("-n", "--config", change), check=False)
    out = proc.stdout + proc.stderr
    assert proc.returncode != 0 and "Nothing to be done" not in out
    key = change.split("=")[0] if "solver" not in change else "solver"
    assert key in out and "results" in out and "Traceback" not in out


def test_tiny_then_default_into_the_same_folder_stops(folder):
    proc = run(folder, "-n", "--configfile", str(REPO / "config" / "config.yaml"), check=False)
    assert proc.returncode != 0 and "scene" in proc.stderr


def test_an_interrupted_store_is_never_mixed_with_another_seed(tmp_path):
    args = small_args(tmp_path, "--until", "dataset")
    run(tmp_path, *args[:3], "--until", "moulds")  # stopped after the first stage
    seeds = xr.open_zarr(store(tmp_path))["seed"].values.copy()
    proc = run(tmp_path, *args, "--config", "seed=7", check=False)
    assert proc.returncode != 0 and "seed" in proc.stderr
    np.testing.assert_array_equal(xr.open_zarr(store(tmp_path))["seed"].values, seeds)


def test_a_deleted_fields_chunk_is_found_and_repaired(folder):
    before = fields_of(folder)
    chunk = store(folder) / "fields" / "c" / "3"
    shutil.rmtree(chunk)
    check = condor_cli("check-store", store(folder))
    assert check.returncode == 1 and "corrupt: 3" in check.stdout
    proc = run(folder, *tiny_args("--until", "dataset"))
    assert proc.stderr.count("rule fields:") == 1  # only the batch that lost it
    assert (check_store(store(folder))["state"] == "ok").all()
    np.testing.assert_array_equal(fields_of(folder), before)


def test_a_deleted_simulation_and_status_chunk_are_repaired(folder):
    before = fields_of(folder)
    (store(folder) / "status" / "c" / "2").unlink()  # a 1-d array's chunk is a file
    for sim in (folder / "results" / "sims" / "batch_0000").glob("*.npz"):
        sim.unlink()
    proc = run(folder, *tiny_args("--until", "dataset"))
    assert proc.stderr.count("rule simulate:") == 1 and proc.stderr.count("rule fields:") == 1
    assert (check_store(store(folder))["state"] == "ok").all()
    np.testing.assert_array_equal(fields_of(folder), before)


def test_a_second_run_on_the_same_folder_stops_at_once(folder):
    (folder / "results" / "dataset_summary.csv").unlink()  # leave work to do
    lock = folder / "results" / ".condor.lock"
    first = subprocess.Popen(snakemake_args(folder, *tiny_args("--until", "sample_figure"),
                                            cores=1),
                             stdout=subprocess.DEVNULL, stderr=subprocess.DEVNULL,
                             start_new_session=True)
    try:
        # no deadline, so no dependence on the machine's speed: the first run takes the lock
        # before any work, or ends without it (then the assertion says so)
        while not lock.exists() and first.poll() is None:
            time.sleep(0.1)
        assert lock.exists(), f"the first run ended ({first.returncode}) without the lock"
        os.killpg(first.pid, signal.SIGSTOP)  # held mid-run, however little work was left
        second = run(folder, *tiny_args("--until", "sample_figure"), check=False)
        assert second.returncode != 0 and "in use by another run" in second.stderr
    finally:
        os.killpg(first.pid, signal.SIGKILL)  # a kill leaves the lock file behind ...
        first.wait()
    assert lock.exists()
    run(folder, *tiny_args("--until", "sample_figure"))  # ... found stale, taken over
    assert not lock.exists()


def test_a_results_path_that_is_a_file_is_one_line(tmp_path):
    (tmp_path / "results").write_text("oops")
    proc = run(tmp_path, *small_args(tmp_path, "-n"), check=False)
    assert proc.returncode != 0 and "is a file" in proc.stderr and "Traceback" not in proc.stderr


def test_a_misspelt_key_is_one_line_without_the_schema(tmp_path):
    proc = run(tmp_path, *small_args(tmp_path, "-n", "--config", "solvr=anneal"), check=False)
    assert proc.returncode != 0 and "solvr" in proc.stderr
    assert "default:" not in proc.stderr and "description" not in proc.stderr  # no schema dump
    assert len(proc.stderr.splitlines()) < 5


def condor(*args, cwd):
    return condor_cli(*args, cwd=cwd)


def test_predict_never_replaces_a_dataset_store(folder, tmp_path):
    """`condor predict --out <store>` leaves the store intact, --force or not."""
    before = fields_of(folder)
    fake_checkpoint = tmp_path / "m.pt"
    fake_checkpoint.write_text("x")
    mould = next((folder / "results" / "moulds").glob("*.json"))
    for extra in ((), ("--force",)):
        proc = condor("predict", mould, "--checkpoint", fake_checkpoint, "--out", store(folder),
                      *extra, cwd=tmp_path)
        assert proc.returncode == 2 and "dataset store" in proc.stderr
    np.testing.assert_array_equal(fields_of(folder), before)
    assert (check_store(store(folder))["state"] == "ok").all()


def test_rasterise_uses_the_simulations_own_scene(folder, tmp_path):
    sim = next((folder / "results" / "sims" / "batch_0000").glob("*.npz"))
    proc = condor("rasterise", sim, "--out", tmp_path / "f.npy", cwd=tmp_path)
    assert proc.returncode == 0, proc.stderr
    fields = np.load(tmp_path / "f.npy")
    assert fields.shape == (8, 32, 32)  # the tiny scene's grid, not the default's 64 px
    proc = condor("rasterise", sim, "--scene", "default", "--out", tmp_path / "g.npy", cwd=tmp_path)
    assert proc.returncode == 2 and "tiny" in proc.stderr
    truncated = tmp_path / "t.npz"
    truncated.write_bytes(sim.read_bytes()[:300])
    proc = condor("rasterise", truncated, "--out", tmp_path / "h.npy", cwd=tmp_path)
    assert proc.returncode == 2 and "t.npz" in proc.stderr and "Traceback" not in proc.stderr


# --- damage the checks must find, and the next run repair bit for bit --------------------------


def store_files(workdir):
    """Every file of the store, by path: a repair must give back the same bytes."""
    root = store(workdir)
    return {p.relative_to(root): p.read_bytes() for p in sorted(root.rglob("*")) if p.is_file()}


def check_store_cli(workdir, *extra):
    return condor_cli("check-store", store(workdir), *extra)


def jobs(proc):
    """How many jobs of each rule a run ran."""
    names = [line.split()[-1].rstrip(":") for line in proc.stderr.splitlines()
             if line.startswith(("rule ", "localrule "))]
    return {name: names.count(name) for name in names}


def damage(workdir, chunk, how):
    path = store(workdir) / chunk
    data = path.read_bytes()
    if how == "delete":
        path.unlink()
    elif how == "truncate":
        path.write_bytes(data[: len(data) // 2])
    else:  # flip a bit of the checksum: the frame stays whole, only decoding finds it
        path.write_bytes(data[:-1] + bytes([data[-1] ^ 0x01]))


@pytest.mark.parametrize("chunk, how", [
    ("fields/c/3/0/0/0", "delete"),   # the file, not the folder c/3
    ("fields/c/17/0/0/0", "truncate"),  # a replica's (mould 4's third)
    ("inputs/c/2/0/0/0", "delete"),   # else the sample reads as a blank mould
    ("lattice/c/5/0/0/0", "delete"),
    ("outline_x/c/6/0", "truncate"),  # the mould's geometry: written again from its JSON
])
def test_a_deleted_or_truncated_chunk_file_is_found_and_repaired(folder, chunk, how):
    before = store_files(folder)
    array, sample = chunk.split("/")[0], int(chunk.split("/")[2])
    damage(folder, chunk, how)
    check = check_store_cli(folder)
    assert check.returncode == 1 and f"corrupt: {sample}" in check.stdout
    assert f"sample {sample} " in check.stdout and f"array {array}:" in check.stdout
    proc = run(folder, *tiny_args("--until", "dataset"))
    # the batch's fields job writes the lost chunk again, lost inputs from the batch's moulds
    # JSON: no simulation reruns (their timings would differ)
    assert jobs(proc) == {"fields": 1, "dataset": 1}
    assert store_files(folder) == before


@pytest.mark.parametrize("chunks", [
    ("fields_mean/c/1/0/0/0", "split/c/1", "mould/c/14"),
    ("n_replicas_ok/c/0", "field/c/0", "replica/c/19"),
])
def test_damaged_derived_and_layout_arrays_are_found_and_repaired(folder, chunks):
    """Else the evaluation's MAE changes, training drops a mould, reading them raises."""
    before = store_files(folder)
    for chunk in chunks:
        damage(folder, chunk, "delete")
    check = check_store_cli(folder)
    assert check.returncode == 1
    for chunk in chunks:
        array = chunk.split("/")[0]
        assert (f"array {array}:" if array != "n_replicas_ok" else "not written") in check.stdout
    proc = run(folder, *tiny_args("--until", "dataset"))
    assert jobs(proc) == {"dataset": 1}
    assert store_files(folder) == before


def test_corrupt_chunks_deep_finds_are_set_aside_and_repaired(folder):
    before = store_files(folder)
    for chunk in ("fields/c/3/0/0/0", "energy/c/19", "fields_mean/c/0/0/0/0"):
        damage(folder, chunk, "flip")
    assert check_store_cli(folder).returncode == 0  # the frames are whole: only decoding sees it
    check = check_store_cli(folder, "--deep")
    assert check.returncode == 1 and "Traceback" not in check.stderr
    for where in ("sample 3 (mould 3 replica 0), array fields",
                  "sample 19 (mould 5 replica 1), array energy", "mould 4, array fields_mean"):
        assert where in check.stdout
    assert "moved the damaged chunk files" in check.stdout
    assert (folder / "results" / "dataset.zarr.damaged" / "fields" / "c" / "3").is_dir()
    proc = run(folder, *tiny_args("--until", "dataset"))
    assert jobs(proc) == {"fields": 2, "dataset": 1}
    assert store_files(folder) == before
    assert check_store_cli(folder, "--deep").returncode == 0


def test_a_corrupt_inputs_ready_flag_is_written_again_and_the_summary_kept(folder):
    summary = folder / "results" / "dataset_summary.csv"
    before, table = store_files(folder), summary.read_text()
    damage(folder, "inputs_ready/c/4", "flip")
    proc = run(folder, *tiny_args("--until", "dataset"))
    assert jobs(proc) == {"fields": 1, "dataset": 1}
    assert store_files(folder) == before and summary.read_text() == table
    assert jobs(run(folder, *tiny_args("--until", "dataset"))) == {}  # no loop


@pytest.mark.parametrize("read_only", ["results", "results/figures"])
def test_a_read_only_results_folder_is_one_line(folder, read_only):
    """Issue 33, item 12: the lock, or a job removing its old output, met a PermissionError
    and printed its stack frames."""
    (folder / "results" / "report.html").unlink()  # leave work to do
    (folder / "results" / "figures" / "mould_gallery.png").unlink()
    target = folder / read_only
    target.chmod(0o555)
    try:
        prefix = _without_write_permission(target)
        proc = subprocess.run([*prefix, *snakemake_args(folder, *TINY)], capture_output=True,
                              text=True)
    finally:
        target.chmod(0o755)
    assert proc.returncode != 0 and "Traceback" not in proc.stderr
    lines = [line for line in proc.stderr.splitlines() if line.startswith("condor: ")]
    assert len(lines) == 1 and "cannot be written" in lines[0] and read_only in lines[0]
    assert not (folder / "results" / "report.html").exists()
    assert not (folder / "results" / ".condor.lock").exists()


def test_training_on_a_corrupt_chunk_names_the_sample_and_the_array(folder, tmp_path):
    """Issue 33, item 7: a checksum error with neither the sample nor the array named."""
    damage(folder, "fields/c/3/0/0/0", "flip")
    for argv in (["train", "--store", store(folder), "--checkpoint", tmp_path / "m.pt",
                  "--epochs", "1", "--base", "8", "--threads", "1"],
                 ["evaluate", "--store", store(folder), "--checkpoint",
                  folder / "results" / "models" / "unet.pt", "--out", tmp_path / "ev"]):
        proc = condor(*argv, cwd=tmp_path)
        assert proc.returncode == 2 and "Traceback" not in proc.stderr
        assert "sample 3, array fields" in proc.stderr and "check-store --deep" in proc.stderr
    assert not (tmp_path / "m.pt").exists()
