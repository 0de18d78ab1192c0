"""Nothing lost, nothing mixed: the workflow and the CLI under a careless user's mistakes.

Each test copies the session's finished tiny run (`tiny_run`, tests/conftest.py: 16 moulds in
4 batches of 4; test moulds 4-9 with 4 replicas, samples 16-33: 4, 5, 7 and 8 the generator's,
6 and 9 lab moulds) and makes one mistake on the copy."""

import json
import os
import resource
import shutil
import signal
import subprocess
import sys
import time
from pathlib import Path

import numpy as np
import pytest
import xarray as xr

from condor.data.store_check import check_store
from condor.folder import RunLock
from conftest import condor_cli
from test_cli_surrogate import _without_write_permission
from test_workflow import REPO, TINY, run, snakemake_args

pytestmark = pytest.mark.slow

# The tiny scene, cut down, for runs of their own: 8 moulds in 4 batches, 2 test moulds of 4
# replicas (the fewest the studies take: condor.studies.recipes.MIN_REPLICAS), both the
# generator's (the accuracy study's moulds: report.moulds).
SMALL = {"n_moulds": 8, "batch_size": 2, "split": {"test": 2, "lab_test": 0},
         "simulation": {"replicas": {"test": 4}}, "report": {"moulds": 2}}


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
    the store exists, the job's output does not. The rerun keeps the store and finishes, and
    the manifest written again (now "created": false) is not newer input to the moulds and
    the studies: the run after it has nothing to do (it planned all 31 jobs again)."""
    before = fields_of(folder)
    (folder / "results" / "dataset.json").unlink()
    proc = run(folder, "results/dataset.json", *TINY)
    assert "rule init_store" in proc.stderr and (folder / "results" / "dataset.json").is_file()
    np.testing.assert_array_equal(fields_of(folder), before)
    dry = run(folder, *tiny_args("-n"))
    assert "Nothing to be done" in dry.stdout + dry.stderr


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


# --- issue 44: nothing silent -------------------------------------------------------------------


def condor_lines(proc):
    return [line for line in proc.stderr.splitlines() if line.startswith("condor: ")]


def planned(proc):
    """How many jobs of each rule a dry run (-n) planned (it lists them on stdout)."""
    return jobs(subprocess.CompletedProcess(proc.args, proc.returncode, "", proc.stdout))


def test_a_deleted_store_and_its_record_are_built_again_bit_for_bit(folder):
    """Probe 1: `rm -rf dataset.zarr dataset.json` and the run did nothing ("Nothing to be
    done"). Now the store is built again from the folder's own files (the moulds JSON, the
    simulations): no mould or simulation job, the same bytes; and what follows it is planned."""
    before = store_files(folder)
    shutil.rmtree(store(folder))
    (folder / "results" / "dataset.json").unlink()
    plan = planned(run(folder, *tiny_args("-n")))
    assert {"init_store", "fields", "dataset", "train", "report"} <= set(plan), plan
    assert plan["fields"] == 4 and not {"moulds", "simulate", "sweep_mould"} & set(plan)
    proc = run(folder, *tiny_args("--until", "dataset"))
    assert jobs(proc) == {"init_store": 1, "fields": 4, "dataset": 1}
    assert store_files(folder) == before and (folder / "results" / "dataset.json").is_file()


def test_a_deleted_model_or_table_is_built_again(folder):
    """Probe 2: `rm models/unet.pt report.html` reran the report alone and left the model
    missing. Now every output is a target of `all`: the model, any table."""
    model = folder / "results" / "models" / "unet.pt"
    before = model.read_bytes()
    for path in (model, folder / "results" / "report.html",
                 folder / "results" / "evaluation" / "families_lab.csv",
                 folder / "results" / "studies" / "convergence.csv"):
        path.unlink()
    plan = planned(run(folder, *tiny_args("-n")))
    assert {"train", "accuracy", "convergence", "report"} <= set(plan), plan
    run(folder, "results/models/unet.pt", *TINY)
    assert model.read_bytes() == before  # its finished working checkpoint, published again


@pytest.mark.parametrize("record", ["kept", "deleted too"])
def test_a_deleted_store_then_a_changed_seed_stops_before_any_job(folder, record):
    """Probe 3: with the store and dataset.json deleted, `--config seed=7` was accepted: the
    convergence study ran with seed 7 beside seed 2026's moulds and model, and the report
    failed on every rerun. Now the folder's own record (.condor.folder.json) still says what
    it holds; without any record, data there cannot be checked and is refused too."""
    shutil.rmtree(store(folder))
    (folder / "results" / "dataset.json").unlink()
    if record != "kept":
        (folder / "results" / ".condor.folder.json").unlink()
    proc = run(folder, *tiny_args("--config", "seed=7"), check=False)
    assert proc.returncode != 0 and "Traceback" not in proc.stderr
    assert "Building DAG" not in proc.stderr  # before Snakemake looked at a file
    (line,) = condor_lines(proc)
    if record == "kept":
        assert "seed: folder has 2026, config asks 7" in line and ".condor.folder.json" in line
    else:
        assert "no record" in line and "moulds/" in line and "results/sims" in line
    assert "--config results=" in line and not store(folder).exists()


@pytest.mark.parametrize("array, index, found_by, repaired_by", [
    ("fields_mean", 1, "--deep", {"dataset": 1}),  # probe 4: fields_mean[1] *= 1.5
    ("split", 3, "", {"dataset": 1}),             # another valid split name
    ("inputs", 19, "--deep", {"fields": 1, "dataset": 1}),  # a replica's copy of its mould's
])
def test_a_rewrite_with_a_valid_checksum_is_found_and_repaired(folder, array, index, found_by,
                                                               repaired_by):
    """Probe 4: a derived array rewritten through zarr passed `check-store` and `--deep`, and
    the rerun planned nothing. Now `--deep` recomputes what the store derives from its samples
    (and the fast check compares the split with the data configuration's); the chunk is set
    aside and the next run writes it again, bit for bit."""
    import zarr

    before = store_files(folder)
    group = zarr.open_group(store(folder), mode="r+")
    values = group[array][index]
    if array == "split":
        group[array][index] = "test" if values != "test" else "train"
    elif array == "inputs":
        group[array][index] = np.where(np.indices(values.shape).sum(0) == 0, 1 - values, values)
    else:
        group[array][index] = values * 1.5
    if found_by:
        assert check_store_cli(folder).returncode == 0  # the fast check decodes no grid
    check = check_store_cli(folder, *filter(None, [found_by]))
    assert check.returncode == 1 and f"array {array}:" in check.stdout
    assert "differs from" in check.stdout or "the data configuration's split" in check.stdout
    proc = run(folder, *tiny_args("--until", "dataset"))
    assert jobs(proc) == repaired_by
    assert store_files(folder) == before
    assert check_store_cli(folder, "--deep").returncode == 0


LIMITED_RUN = """
import contextlib, io, json, resource, sys
limit = int(sys.argv[2])
resource.setrlimit(resource.RLIMIT_FSIZE, (limit, limit))
from condor import cli
results = []
for argv in json.loads(sys.argv[1]):
    err = io.StringIO()
    with contextlib.redirect_stderr(err), contextlib.redirect_stdout(io.StringIO()):
        try:
            cli.main(argv)
            code = 0
        except SystemExit as exit:
            code = exit.code
    results.append([code, err.getvalue()])
print(json.dumps(results))
"""


def test_a_file_size_limit_leaves_no_output_and_names_it(tiny_run, tmp_path):
    """Probe 5: under `ulimit -f 10`, `condor simulate` left a truncated s.npz (a rerun was
    refused, "exists"; rasterise failed, "BadZipFile"), predict a partial .zarr, and the
    message, "[Errno 27] File too large", named no file. Now every command writes to a
    temporary name and renames at the end: nothing is left, and one line names the output."""
    mould = tmp_path / "m.json"
    assert condor_cli("mould", "--seed", "1", "--scene", "tiny", "--out", mould).returncode == 0
    checkpoint = tiny_run / "results" / "models" / "unet.pt"
    sim = next((tiny_run / "results" / "sims" / "batch_0000").glob("*.npz"))
    out = tmp_path / "out"
    out.mkdir()
    commands = {
        "s.npz": ["simulate", str(mould), "--scene", "tiny", "--out", str(out / "s.npz")],
        "f.png": ["rasterise", str(sim), "--out", str(out / "f.png")],
        "p.zarr": ["predict", str(mould), "--checkpoint", str(checkpoint), "--out",
                   str(out / "p.zarr")],
        "p.png": ["predict", str(mould), "--checkpoint", str(checkpoint), "--out",
                  str(out / "p.png")],
        "m.png": ["mould", "--seed", "2", "--scene", "tiny", "--out", str(out / "m2.json"),
                  "--png", str(out / "m.png")],
        "m.pt": ["train", "--store", str(tiny_run / "results" / "dataset.zarr"), "--checkpoint",
                 str(out / "m.pt"), "--epochs", "1", "--base", "8", "--threads", "1"],
        "d": ["design", "--objective", "alignment:x", "--checkpoint", str(checkpoint), "--out",
              str(out / "d"), "--budget", "4", "--top", "1", "--random", "1", "--replicas", "1"],
    }
    proc = subprocess.run([sys.executable, "-c", LIMITED_RUN, json.dumps(list(commands.values())),
                           str(10 * 1024)], capture_output=True, text=True, cwd=tmp_path)
    assert proc.returncode == 0, proc.stderr[-3000:]
    named = {"m.pt": ".m.training.pt"}  # train fails on its first epoch's checkpoint
    for name, (code, err) in zip(commands, json.loads(proc.stdout.splitlines()[-1])):
        lines = [line for line in err.splitlines() if "error:" in line]
        assert code == 2 and len(lines) == 1 and "Traceback" not in err, (name, err)
        assert named.get(name, name) in lines[0] and "file too large" in lines[0], lines[0]
    assert sorted(p.name for p in out.iterdir()) == []  # nothing half-written, no temporary
    again = condor_cli(*commands["s.npz"])  # not refused ("exists"), and whole
    assert again.returncode == 0, again.stderr
    assert condor_cli("rasterise", out / "s.npz", "--out", out / "g.npy").returncode == 0


def _read_only_mount(target):
    """The command prefix that runs a command with `target` mounted read-only (a private
    mount namespace: EROFS, as a read-only disk), or a skip where it cannot."""
    prefix = [shutil.which("unshare") or "unshare", "-m", "sh", "-c",
              'mount --bind -o ro "$0" "$0" && exec "$@"', str(target)]
    try:
        probe = subprocess.run([*prefix, "touch", str(target / "probe")], capture_output=True)
    except OSError:
        probe = None
    if probe is None or probe.returncode == 0 or b"Read-only" not in probe.stderr:
        pytest.skip("cannot mount a folder read-only here (needs unshare and mount)")
    return prefix


@pytest.mark.parametrize("read_only", ["results", "results/figures"])
def test_a_read_only_file_system_is_one_line(folder, read_only):
    """Probe 6: a results folder on a read-only file system gave "OSError ... [Errno 30]
    results/.condor.lock" and its stack frames (a permission error was one line already)."""
    (folder / "results" / "report.html").unlink()  # leave work to do
    (folder / "results" / "figures" / "mould_gallery.png").unlink()
    prefix = _read_only_mount(folder / read_only)
    proc = subprocess.run([*prefix, *snakemake_args(folder, *TINY)], capture_output=True,
                          text=True)
    assert proc.returncode != 0 and "Traceback" not in proc.stderr
    (line,) = condor_lines(proc)
    assert "cannot be written" in line and read_only in line
    assert not (folder / "results" / "report.html").exists()
    assert not (folder / "results" / ".condor.lock").exists()


def test_a_file_size_limit_in_a_workflow_job_is_one_line(folder):
    """Probe 6: a file-size limit while training printed 3 chained tracebacks, the last
    PyTorch's "enforce fail at inline_container.cc". Now one line names the file and why."""
    models = folder / "results" / "models"
    for name in ("unet.pt", "unet_history.csv", ".unet.training.pt"):
        (models / name).unlink()
    limit = 100 * 1024  # Snakemake's own files stay below it; the checkpoint does not
    proc = subprocess.run(snakemake_args(folder, "results/models/unet.pt", *TINY),
                          capture_output=True, text=True,
                          preexec_fn=lambda: resource.setrlimit(resource.RLIMIT_FSIZE,
                                                                (limit, limit)))
    assert proc.returncode != 0 and "Traceback" not in proc.stderr, proc.stderr[-3000:]
    (line,) = condor_lines(proc)
    assert "rule train" in line and ".unet.training.pt" in line and "file too large" in line
    assert not models.exists() or not any(models.iterdir())


@pytest.mark.skipif(__import__("torch").cuda.is_available(), reason="this machine has CUDA")
def test_an_unavailable_device_is_one_line(tiny_run, tmp_path):
    """Probe 6: `condor predict --device cuda` on a machine without CUDA raised torch's
    AssertionError ("Torch not compiled with CUDA enabled")."""
    assert condor_cli("mould", "--seed", "1", "--scene", "tiny", "--out", tmp_path / "m.json",
                      ).returncode == 0
    proc = condor_cli("predict", tmp_path / "m.json", "--checkpoint",
                      tiny_run / "results" / "models" / "unet.pt", "--out", tmp_path / "f.zarr",
                      "--device", "cuda")
    assert proc.returncode == 2 and "Traceback" not in proc.stderr, proc.stderr
    assert "'cuda'" in proc.stderr and "no CUDA device" in proc.stderr
    assert not (tmp_path / "f.zarr").exists()


def workflow_copy(tmp_path):
    """The workflow's own files (Snakefile, rules, scripts, configs, profiles) in a folder of
    their own, run from there as a user runs them from the repository."""
    copy = tmp_path / "repo"
    copy.mkdir()
    shutil.copy2(REPO / "Snakefile", copy / "Snakefile")
    for name in ("workflow", "config", "profiles"):
        shutil.copytree(REPO / name, copy / name)
    return copy


@pytest.mark.parametrize("mistake, said", [
    ("yaml", "config file config/config.yaml is not valid YAML at line 3, column 12"),
    ("missing", "config file config/config.yaml does not exist"),
])
def test_a_broken_default_config_is_one_line_naming_it(tmp_path, mistake, said):
    """Probe 7: a YAML mistake in a config file gave Snakemake's "Config file is not valid
    JSON or YAML", with no file or line. condor reads the workflow's own config first; the
    files of --configfile Snakemake reads before condor's code runs (README)."""
    repo = workflow_copy(tmp_path)
    config = repo / "config" / "config.yaml"
    if mistake == "yaml":
        lines = config.read_text().splitlines()
        lines.insert(2, "n_moulds: 4: 5")
        config.write_text("\n".join(lines) + "\n")
    else:
        config.unlink()
    proc = subprocess.run([sys.executable, "-m", "snakemake", "-n", "--cores", "1"], cwd=repo,
                          capture_output=True, text=True)
    assert proc.returncode != 0 and "Traceback" not in proc.stderr
    (line,) = condor_lines(proc)
    assert said in line


def test_a_run_started_while_another_holds_the_folder_stops_before_reading_it(folder):
    """Probe 7: two runs started in the same instant: the second stopped with Snakemake's
    "a concurrent process has deleted it", met while it built its DAG, because condor's lock
    was taken only after that. Now it is taken as the workflow is read: held by a live run
    (this test), the second stops at once, before Snakemake looks at any file."""
    (folder / "results" / "dataset_summary.csv").unlink()  # leave work to do
    lock = RunLock(folder / "results")
    lock.acquire()
    try:
        proc = run(folder, *TINY, check=False)
        dry = run(folder, *tiny_args("-n"), check=False)  # looking takes no lock
    finally:
        lock.release()
    assert proc.returncode != 0 and "Building DAG" not in proc.stderr
    (line,) = condor_lines(proc)
    assert "in use by another run" in line and f"PID {os.getpid()}" in line
    assert dry.returncode == 0 and planned(dry).get("dataset") == 1
    assert not (folder / "results" / "dataset_summary.csv").exists()
