"""The `condor` command line for the dataset stages: its entry point as a user runs it (a
subprocess), and what each command does, run in this process (`condor_cli`: `cli.main`, with
the exit status, stdout and stderr a user would see)."""

import json
import shutil
import subprocess
import sys

import numpy as np
import shapely
import pytest

from condor import cli
from conftest import condor_cli
from condor.data.fields import FIELD_NAMES
from condor.moulds.mould import load_json
from condor.model.simulate import SimResult
from condor.data.store import StoreSpec, assign_splits, create_store, write_inputs, write_sample


def condor(*args, cwd):
    return condor_cli(*args, cwd=cwd)


def test_mould_writes_geometry_and_picture(tmp_path):
    """Through the entry point, as a user runs it (`python -m condor.cli`, a subprocess)."""
    proc = subprocess.run([sys.executable, "-m", "condor.cli", "mould", "--seed", "7", "--out",
                           "m.json", "--png", "m.png"], cwd=tmp_path, capture_output=True, text=True)
    assert proc.returncode == 0, proc.stderr
    mould = load_json(tmp_path / "m.json")  # validates on load
    assert mould.seed == 7 and mould.mould_id == 0
    assert (tmp_path / "m.png").read_bytes()[:8] == b"\x89PNG\r\n\x1a\n"
    again = condor("mould", "--seed", 7, "--out", "m2.json", cwd=tmp_path)
    assert again.returncode == 0
    assert json.loads((tmp_path / "m.json").read_text()) == json.loads((tmp_path / "m2.json").read_text())


@pytest.mark.parametrize("seed", ["-1", "seven", "1.5", str(2**64)])
def test_bad_seed_is_named(tmp_path, seed):
    proc = condor("mould", "--seed", seed, "--out", "m.json", cwd=tmp_path)
    assert proc.returncode == 2
    assert "--seed" in proc.stderr
    assert "Traceback" not in proc.stderr
    assert not (tmp_path / "m.json").exists()


def test_simulate_then_rasterise_tiny(tmp_path):
    assert condor("mould", "--seed", 3, "--id", 1, "--scene", "tiny", "--out", "m.json", cwd=tmp_path).returncode == 0
    proc = condor("simulate", "m.json", "--scene", "tiny", "--out", "s.npz", cwd=tmp_path)
    assert proc.returncode == 0, proc.stderr
    result = SimResult.load(tmp_path / "s.npz")
    assert result.status == "ok" and result.n_cells > 50
    proc = condor("rasterise", "s.npz", "--scene", "tiny", "--out", "f.npy", cwd=tmp_path)
    assert proc.returncode == 0, proc.stderr
    fields = np.load(tmp_path / "f.npy")
    assert fields.shape == (len(FIELD_NAMES), 32, 32)
    # density integrates to the cell count (moulds keep clear of the box edge)
    assert fields[0].sum() == pytest.approx(result.n_cells, rel=1e-3)


def test_simulate_refuses_a_mould_from_another_scene(tmp_path):
    condor("mould", "--seed", 3, "--scene", "tiny", "--out", "m.json", cwd=tmp_path)
    proc = condor("simulate", "m.json", "--scene", "paper", "--out", "s.npz", cwd=tmp_path)
    assert proc.returncode == 2
    assert "scene" in proc.stderr and "15.625" in proc.stderr and "Traceback" not in proc.stderr


def test_simulate_names_a_corrupt_mould_file(tmp_path):
    (tmp_path / "m.json").write_text('{"polygon": "nonsense"}')
    proc = condor("simulate", "m.json", "--out", "s.npz", cwd=tmp_path)
    assert proc.returncode == 2
    assert "m.json" in proc.stderr and "Traceback" not in proc.stderr


def test_check_store_lists_states(tmp_path):
    store = tmp_path / "d.zarr"
    create_store(store, StoreSpec(n_moulds=4, pixels=8, seed=0, split=assign_splits(4, 1, 0.0, 0), attrs={}))
    meta = {"seed": 0, "symmetry": "cyclic", "order": 2, "removal": "none", "n_tethers": 4}
    sim = {"sim_seed": 1, "n_cells": 10, "energy": 0.0, "max_force": 1e-4, "solver": "hybrid", "solver_seconds": 0.1, "hardware": "test"}
    for sample in (0, 1, 2):
        write_inputs(store, sample, np.zeros((2, 8, 8), "uint8"), meta, lattice=np.zeros((2, 8, 8), np.float32),
                     polygon=shapely.box(1, 1, 7, 7), tethers=np.full((4, 3), 2.0))
    write_sample(store, 0, np.ones((8, 8, 8), "float32"), sim, "ok")
    write_sample(store, 1, None, sim, "folded lattice")
    proc = condor("check-store", store, cwd=tmp_path)
    assert proc.returncode == 1  # not every sample is finished
    assert "ok 1" in proc.stdout and "failed 1" in proc.stdout
    assert "pending: 2" in proc.stdout and "missing: 3" in proc.stdout
    assert "folded lattice" in proc.stdout
    proc = condor("check-store", tmp_path / "nowhere.zarr", cwd=tmp_path)
    assert proc.returncode == 2 and "no dataset store" in proc.stderr


def test_version_and_bash_completion(capsys):
    """condor --version; condor completion prints a bash script naming every subcommand and
    each one's flags (issue 32, item 5)."""
    import condor

    with pytest.raises(SystemExit) as done:
        cli.main(["--version"])
    assert done.value.code == 0 and capsys.readouterr().out.strip() == f"condor {condor.__version__}"
    cli.main(["completion"])
    script = capsys.readouterr().out
    assert "complete -o filenames -F _condor condor" in script
    for command in ("mould", "simulate", "predict", "design", "check-store"):
        assert command in script
    assert "--l0-um" in script and "--keep" in script and "--fit" in script
    if shutil.which("bash"):
        subprocess.run(["bash", "-n"], input=script, text=True, check=True)  # valid syntax


def test_help_states_each_scenes_window_in_mm(capsys):
    with pytest.raises(SystemExit):
        cli.main(["simulate", "--help"])
    text = " ".join(capsys.readouterr().out.split())
    assert "tiny 0.25 mm, default 0.5 mm, paper 1 mm" in text and "--fit extent" in text


def test_simulate_prints_the_statistics_by_predict_s_names(tmp_path):
    """condor simulate prints the whole-mould statistics under the names and units condor
    predict prints (condor.data.statistics.MOULD_STATISTICS) and keeps them in the result."""
    from condor.data.statistics import MOULD_STATISTICS, STATISTIC_UNITS

    condor("mould", "--seed", 3, "--id", 1, "--scene", "tiny", "--out", "m.json", cwd=tmp_path)
    proc = condor("simulate", "m.json", "--scene", "tiny", "--out", "s.npz", "--l0-um", 16,
                  cwd=tmp_path)
    assert proc.returncode == 0, proc.stderr
    assert proc.stdout.splitlines()[0].startswith("m.json: read 1 outline, 0 holes, ")
    lines = {line.split()[0]: line for line in proc.stdout.splitlines() if line.startswith("  ")}
    stored = SimResult.load(tmp_path / "s.npz").info["statistics"]
    for name in (*MOULD_STATISTICS, "tissue_area_mm2"):
        assert name in lines and name in stored
        assert f"{stored[name]['value']:.4g}" in lines[name]
    assert f"({STATISTIC_UNITS['mean_tension']})" in lines["mean_tension"]
    assert stored["tissue_area_mm2"]["value"] == pytest.approx(
        stored["tissue_area"]["value"] * 0.016 ** 2)


@pytest.mark.parametrize("argv, hint", [
    (["predcit"], "did you mean 'predict'?"),
    (["simulate", "m.json", "--out", "s.npz", "--fitt"], "--fitt: did you mean --fit?"),
    (["simulate", "m.json", "--out", "s.npz", "--l0um", "16"], "--l0um: did you mean --l0-um?"),
    (["simulate", "m.json", "--out", "s.npz", "--posts", "darkk"], "did you mean 'dark'?"),
])
def test_a_mistyped_command_flag_or_choice_suggests_the_nearest(argv, hint, capsys):
    with pytest.raises(SystemExit) as done:
        cli.main(argv)
    err = capsys.readouterr().err
    assert done.value.code == 2 and hint in err.splitlines()[-1]


def test_help_texts_the_issue_found_missing(capsys):
    """check-store's store, evaluate --split and completion have help; rasterise --scene
    states its real default, not None."""
    def help_of(*command):
        with pytest.raises(SystemExit):
            cli.main([*command, "--help"])
        return " ".join(capsys.readouterr().out.split())

    assert "the dataset store to check" in help_of("check-store")
    assert "the split whose moulds are scored" in help_of("evaluate")
    assert "bash completion script" in help_of("completion")
    rasterise = help_of("rasterise")
    assert "(default: None)" not in rasterise and "the scene the simulation records" in rasterise


def test_a_checkpoint_that_is_a_folder_is_named_as_one(tmp_path, capsys):
    (tmp_path / "models").mkdir()
    (tmp_path / "models" / "unet.pt").write_bytes(b"")
    (tmp_path / "m.npy").write_bytes(b"")
    with pytest.raises(SystemExit) as done:
        cli.main(["predict", str(tmp_path / "m.npy"), "--checkpoint", str(tmp_path / "models"),
                  "--out", str(tmp_path / "p.zarr")])
    err = capsys.readouterr().err
    assert done.value.code == 2 and err.count("\n") == 1
    assert "is a folder, not a checkpoint file" in err and "unet.pt" in err
    assert "train a model first" not in err
