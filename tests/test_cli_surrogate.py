"""`condor train`, `condor evaluate` and `condor predict` on a real-format store holding the
synthetic dataset (condor.surrogate.synthetic), through the CLI's `main`."""

import builtins
import json
import re
import os
import shutil
import subprocess
import sys

import numpy as np
import shapely
import pandas as pd
import pytest
import torch
import xarray as xr
from PIL import Image

from condor import cli
from condor.moulds.mould import input_channels, load_json
from condor.data.store import StoreSpec, create_store, open_store, write_inputs, write_sample
from condor.surrogate.checkpoint import load_checkpoint, save_checkpoint
from condor.surrogate.networks import PREDICTION_MODES
from condor.surrogate.predict import predict
from condor.surrogate.synthetic import synthetic_dataset

SIZE = 32
BOX = 31.25  # the `default` scene's box, so that `condor mould` moulds fit the checkpoint
FAST = ["--variant", "unet_l1", "--base", "8", "--batch-size", "4", "--lr", "2e-3", "--threads", "1"]


def write_store(path, ds, box=BOX):
    """The synthetic samples in a store made by condor.data.store, as the workflow writes it."""
    n, size = ds.sizes["sample"], ds.sizes["x"]
    spec = StoreSpec(n_moulds=n, pixels=size, seed=0, split=tuple(ds["split"].values.astype(str)),
                     attrs={"pixel_size": box / size, "scene": {"name": "synthetic", "box": box}})
    create_store(path, spec)
    for i in range(n):
        write_inputs(path, i, ds["inputs"].values[i],
                     {"seed": 0, "symmetry": "none", "order": 1, "removal": "none", "n_tethers": 1}, lattice=np.zeros(ds["inputs"].values[i].shape, np.float32),
                     polygon=shapely.box(*(box / 2 - (0.2 + 0.25 * i / n) * box,) * 2,
                                         *(box / 2 + (0.2 + 0.25 * i / n) * box,) * 2),
                     tethers=[[box / 2, box / 2, 1.0]])  # areas 0.16-0.8 of the box
        write_sample(path, i, ds["fields"].values[i],
                     {"sim_seed": 0, "n_cells": int(ds["n_cells"].values[i]), "energy": 0.0,
                      "max_force": 0.0, "solver": "synthetic", "solver_seconds": 0.0, "hardware": "test"}, "ok")


@pytest.fixture(scope="module")
def trained(tmp_path_factory):
    """A store and a checkpoint trained on it by `condor train` (2 epochs, then resumed to 3)."""
    root = tmp_path_factory.mktemp("cli")
    store, checkpoint = root / "data.zarr", root / "m.pt"
    write_store(store, synthetic_dataset(16, SIZE, splits=("train",) * 6 + ("val", "test")))
    cli.main(["train", "--store", str(store), "--checkpoint", str(checkpoint), "--epochs", "2", *FAST])
    return store, checkpoint


def run_main(argv):
    with pytest.raises(SystemExit) as exit_info:
        cli.main(argv)
    return exit_info.value.code


def test_the_parser_offers_the_library_s_choices_without_importing_torch():
    """The parser's --mode and --precision choices are condor.surrogate.modes' (the networks'
    and the Predictor's own), and building it does not import torch (`condor --help` stays
    quick)."""
    import subprocess
    import sys

    from condor.surrogate import inference, networks

    parser = cli.build_parser()
    sub = next(a for a in parser._actions if a.dest == "command").choices["predict"]
    choices = {a.dest: tuple(a.choices) for a in sub._actions if a.choices}
    assert choices["mode"] == networks.PREDICTION_MODES == PREDICTION_MODES
    assert choices["precision"] == (inference.AUTO_PRECISION, *inference.PRECISIONS)
    code = "import sys, condor.cli; condor.cli.build_parser(); print('torch' in sys.modules)"
    proc = subprocess.run([sys.executable, "-c", code], capture_output=True, text=True, check=True)
    assert proc.stdout.strip() == "False"


def test_train_writes_checkpoint(trained):
    _, checkpoint = trained
    state = load_checkpoint(checkpoint)
    assert state["epoch"] == 2 and state["config"]["network"] == "unet_l1"
    assert state["generator_config"]["size"] == SIZE and state["generator_config"]["base"] == 8
    assert state["data"]["pixel_size"] == pytest.approx(BOX / SIZE)
    assert state["data"]["n_train"] == 12  # 6 of every 8 samples are "train"
    assert len(state["data"]["fingerprint"]) == 64  # of the data it was trained on


def test_a_checkpoint_written_before_network_was_named_so_still_loads(trained, tmp_path):
    """Checkpoints record TrainConfig; its `model` became `network` (the physics is
    condor.model): one written with `model` loads with `network`, and predicts."""
    import torch

    _, checkpoint = trained
    state = torch.load(checkpoint, weights_only=True)
    state["config"]["model"] = state["config"].pop("network")
    old = tmp_path / "old.pt"
    torch.save(state, old)
    loaded = load_checkpoint(old)
    assert loaded["config"]["network"] == "unet_l1" and "model" not in loaded["config"]
    inputs = np.zeros((2, SIZE, SIZE), np.uint8)
    inputs[0, 8:24, 8:24] = 1
    np.testing.assert_array_equal(predict(old, inputs).raw, predict(checkpoint, inputs).raw)


def test_train_never_overwrites_and_resumes_only_an_interrupted_run(trained, tmp_path, capsys,
                                                                     monkeypatch):
    store, trained_checkpoint = trained
    checkpoint = tmp_path / "my_model.pt"
    shutil.copyfile(trained_checkpoint, checkpoint)
    before = checkpoint.read_bytes()
    argv = ["train", "--store", str(store), "--checkpoint", str(checkpoint), "--epochs", "3", *FAST]
    # An existing checkpoint is never replaced without --force: one line naming it.
    code = run_main(argv)
    err = capsys.readouterr().err
    assert code == 2 and err.count("\n") == 1 and "my_model.pt" in err and "--force" in err
    assert checkpoint.read_bytes() == before

    def dies_after_epoch_1(*args, **kwargs):
        if str(args[0]).startswith("epoch 1/"):
            raise KeyboardInterrupt
        builtins.print(*args, **kwargs)

    with monkeypatch.context() as patch:
        patch.setattr(cli, "print", dies_after_epoch_1, raising=False)
        with pytest.raises(KeyboardInterrupt):
            cli.main([*argv, "--force"])
    assert checkpoint.read_bytes() == before  # nothing is published before the last epoch
    # An interrupted run of other settings is not discarded without --fresh.
    code = run_main([*argv, "--force", "--base", "16"])
    err = capsys.readouterr().err
    assert code == 2 and err.count("\n") == 1 and "cannot resume" in err and "--fresh" in err
    assert "base" in err
    # The same settings and data resume it.
    cli.main([*argv, "--force"])
    out = capsys.readouterr().out
    assert "resuming from" in out and "epoch 3/3" in out and "epoch 1/3" not in out
    assert load_checkpoint(checkpoint)["epoch"] == 3
    # A finished run is only a copy of the published model: other settings train from scratch.
    cli.main([*argv[:-len(FAST) - 2], "--epochs", "1", *FAST, "--force"])
    out = capsys.readouterr().out
    assert "training from scratch" in out and "epochs: checkpoint 3 vs now 1" in out
    assert load_checkpoint(checkpoint)["epoch"] == 1


def test_missing_checkpoint_is_one_line_and_exit_2(trained, tmp_path, capsys):
    store, _ = trained
    missing = tmp_path / "nope.pt"
    for argv in (["evaluate", "--store", str(store), "--checkpoint", str(missing), "--out",
                  str(tmp_path / "ev")],
                 ["predict", str(tmp_path / "m.npy"), "--checkpoint", str(missing), "--out",
                  str(tmp_path / "f.zarr")]):
        code = run_main(argv)
        err = capsys.readouterr().err
        assert code == 2
        assert err.count("\n") == 1 and "nope.pt" in err and "does not exist" in err
    assert not (tmp_path / "ev").exists()


def test_missing_store_is_one_line_and_exit_2(tmp_path, capsys):
    code = run_main(["train", "--store", str(tmp_path / "none.zarr"), "--checkpoint",
                     str(tmp_path / "m.pt")])
    err = capsys.readouterr().err
    assert code == 2 and err.count("\n") == 1 and "none.zarr" in err


def test_evaluate_writes_tables_figures_and_baselines(trained, tmp_path, capsys):
    store, checkpoint = trained
    out = tmp_path / "ev"
    cli.main(["evaluate", "--store", str(store), "--checkpoint", str(checkpoint), "--out", str(out),
              "--modes", "eval"])
    printed = capsys.readouterr().out
    summary = pd.read_csv(out / "summary.csv", index_col="method")
    assert list(summary.index) == ["unet_l1_eval", "masked_mean", "mould_blur"]
    # The MAE table agrees with a direct computation from the store and the checkpoint.
    ds = open_store(store)
    test = np.flatnonzero(ds["split"].values.astype(str) == "test")
    truth = ds["fields"].values[test]
    pred = predict(checkpoint, ds["inputs"].values[test], mode="eval").raw
    expect = np.abs(pred.astype(np.float64) - truth).mean(axis=(0, 2, 3))
    got = summary.loc["unet_l1_eval", [f"mae_{k}" for k in ("P", "T", "Sx2", "Sy2", "Sz2", "SxSy",
                                                              "SxSz", "SySz")]].to_numpy(float)
    np.testing.assert_allclose(got, expect, rtol=1e-5)
    per_sample = pd.read_csv(out / "unet_l1_eval_mae.csv", index_col="sample")
    assert sorted(per_sample.index) == sorted(test.tolist())
    for name in ("unet_l1_eval_Sx2_best.png", "unet_l1_eval_T_worst.png",
                 "unet_l1_eval_statistics.png", "mould_blur_mae_distribution.png"):
        assert (out / "figures" / name).stat().st_size > 2000
    assert "masked_mean" in printed and "mould_blur" in printed and "paper" in printed
    assert "0.881" in printed


def test_predict_from_mould_json_writes_zarr(trained, tmp_path, capsys):
    _, checkpoint = trained
    mould_json = tmp_path / "m.json"
    cli.main(["mould", "--seed", "7", "--id", "0", "--out", str(mould_json)])
    out = tmp_path / "fields.zarr"
    cli.main(["predict", str(mould_json), "--checkpoint", str(checkpoint), "--out", str(out)])
    assert "N_c" in capsys.readouterr().out
    written = xr.open_zarr(out)
    inputs = input_channels(load_json(mould_json), SIZE)
    np.testing.assert_array_equal(written["inputs"].values, inputs)
    expect = predict(checkpoint, inputs)
    np.testing.assert_allclose(written["raw"].values, expect.raw, rtol=1e-6)
    # Normalised = raw * N_p / N_c with N_c the predicted density sum (independent check).
    raw = written["raw"].values.astype(np.float64)
    np.testing.assert_allclose(written["normalised"].values, raw * SIZE ** 2 / raw[0].sum(),
                               rtol=1e-4)
    np.testing.assert_allclose(written["x"].values[:2], np.array([0.5, 1.5]) * BOX / SIZE)
    assert list(written["field"].values) == ["P", "T", "Sx2", "Sy2", "Sz2", "SxSy", "SxSz", "SySz"]


def test_predict_from_npy_and_png_agree(trained, tmp_path, capsys):
    """The masks as a .npy are read as they are; a picture of them (red mould, green posts on
    black, row 0 at the top) is a picture of the mould, read as one (its larger side spans the
    box) and placed as a drawing, centred: the same footprint, moved, to the pixels along its
    edge."""
    _, checkpoint = trained
    inputs = synthetic_dataset(16, SIZE)["inputs"].values[3]
    np.save(tmp_path / "m.npy", inputs)
    rgb = np.zeros((SIZE, SIZE, 3), dtype=np.uint8)
    rgb[..., 0], rgb[..., 1] = inputs[0][::-1] * 255, inputs[1][::-1] * 255
    Image.fromarray(rgb).save(tmp_path / "m.png")
    written = {}
    for source in ("m.npy", "m.png"):
        out = tmp_path / f"{source}.zarr"
        cli.main(["predict", str(tmp_path / source), "--checkpoint", str(checkpoint), "--out", str(out)])
        written[source] = xr.open_zarr(out)["inputs"].values
    np.testing.assert_array_equal(written["m.npy"], inputs)
    assert "m.png: read 1 outline" in capsys.readouterr().out
    footprint = [w.any(axis=0) for w in written.values()]
    assert footprint[1].sum() == pytest.approx(footprint[0].sum(), rel=0.15)
    extents = [[np.ptp(np.nonzero(f)[k]) for k in (0, 1)] for f in footprint]
    np.testing.assert_allclose(extents[1], extents[0], atol=1)
    cli.main(["predict", str(tmp_path / "m.npy"), "--checkpoint", str(checkpoint), "--out",
              str(tmp_path / "f.png")])
    assert (tmp_path / "f.png").stat().st_size > 5000


def test_predict_rejects_bad_inputs(trained, tmp_path, capsys):
    _, checkpoint = trained
    cases = {"wrong box": None, "3 channels": np.zeros((3, SIZE, SIZE), np.uint8),
             "not binary": np.full((2, SIZE, SIZE), 2, np.uint8),
             "no integer ratio": np.zeros((2, 24, 24), np.uint8)}
    cli.main(["mould", "--seed", "7", "--scene", "tiny", "--out", str(tmp_path / "tiny.json")])
    capsys.readouterr()
    for name, array in cases.items():
        path = tmp_path / "tiny.json"
        if array is not None:
            path = tmp_path / f"{name.replace(' ', '_')}.npy"
            np.save(path, array)
        code = run_main(["predict", str(path), "--checkpoint", str(checkpoint), "--out",
                         str(tmp_path / "f.zarr")])
        err = capsys.readouterr().err
        assert code == 2 and err.count("\n") == 1, name
        assert str(path.name) in err or "box" in err, (name, err)
    np.save(tmp_path / "ok.npy", np.zeros((2, SIZE, SIZE), np.uint8))
    code = run_main(["predict", str(tmp_path / "ok.npy"), "--checkpoint", str(checkpoint),
                     "--out", str(tmp_path / "f.txt")])
    assert code == 2 and "f.txt" in capsys.readouterr().err and not (tmp_path / "f.txt").exists()


@pytest.mark.parametrize("objective, words", [
    ("alignmnt:x", "unknown objective"),
    ("alignment:x@rect(0.5,0.5,0.5,0.9)", "empty"),
    ("alignment:x; alignment:x>1.5", "no mould can meet"),
])
def test_design_refuses_a_bad_objective_before_any_search(trained, tmp_path, capsys, objective, words):
    _, checkpoint = trained
    code = run_main(["design", "--objective", objective, "--checkpoint", str(checkpoint),
                     "--out", str(tmp_path / "d")])
    err = capsys.readouterr().err
    assert code == 2 and words in err and err.count("\n") == 1
    assert not (tmp_path / "d").exists()  # nothing searched, nothing written


def test_a_file_that_is_not_a_checkpoint_is_one_line(trained, tmp_path, capsys):
    store, _ = trained
    torch.save(torch.nn.Linear(2, 2), tmp_path / "module.pt")  # a pickled model, not a dict
    np.save(tmp_path / "array.npy", np.zeros(3))
    (tmp_path / "notes.txt").write_text("not a checkpoint")
    np.save(tmp_path / "m.npy", np.zeros((2, SIZE, SIZE), np.uint8))
    for name in ("module.pt", "array.npy", "notes.txt"):
        bad = str(tmp_path / name)
        for argv in (["predict", str(tmp_path / "m.npy"), "--checkpoint", bad, "--out",
                      str(tmp_path / "f.zarr")],
                     ["evaluate", "--store", str(store), "--checkpoint", bad, "--out",
                      str(tmp_path / "ev")],
                     ["design", "--objective", "alignment:x", "--checkpoint", bad, "--out",
                      str(tmp_path / "d")]):
            code = run_main(argv)
            err = capsys.readouterr().err
            assert code == 2 and err.count("\n") == 1, (argv, err)
            assert name in err and "not a surrogate checkpoint" in err and "weights_only" not in err
    assert not {"f.zarr", "ev", "d"} & {p.name for p in tmp_path.iterdir()}


# --- design's output folder ---------------------------------------------------------------

DESIGN = ["--objective", "alignment:x", "--budget", "4", "--top", "1", "--random", "1",
          "--replicas", "1"]


@pytest.fixture(scope="module")
def design_checkpoint(trained, tmp_path_factory):
    """The trained checkpoint with a mould depth, so that its designs can be simulated."""
    state = load_checkpoint(trained[1])
    state["data"]["depth"] = 2.0
    path = tmp_path_factory.mktemp("design") / "depth.pt"
    save_checkpoint(state, path)
    return path


def _snapshot(*folders):
    return {p: p.read_bytes() for folder in folders for p in sorted(folder.rglob("*"))
            if p.is_file()}


def test_design_force_never_deletes_what_design_did_not_write(trained, design_checkpoint,
                                                              tmp_path, capsys, monkeypatch):
    store = tmp_path / "data.zarr"
    shutil.copytree(trained[0], store)
    results = tmp_path / "results"
    (results / "models").mkdir(parents=True)
    (results / "dataset.json").write_text("{}")
    (results / "models" / "unet.pt").write_bytes(b"a model")
    user = tmp_path / "user"
    (user / "thesis").mkdir(parents=True)
    (user / "thesis" / "chapter1.tex").write_text("\\chapter{One}")
    (user / "notes.txt").write_text("notes")
    monkeypatch.chdir(user)
    before = _snapshot(tmp_path)
    for out, words in {str(store): "is a Zarr store", str(results): "results folder",
                       ".": "is the current directory", str(tmp_path): "above the current",
                       "thesis": "did not write"}.items():
        code = run_main(["design", *DESIGN, "--checkpoint", str(design_checkpoint), "--out",
                         out, "--force"])
        err = capsys.readouterr().err
        assert code == 2 and err.count("\n") == 1 and words in err and repr(out) in err, err
        assert "Errno" not in err
    assert _snapshot(tmp_path) == before


def test_design_force_replaces_only_its_own_folder(design_checkpoint, tmp_path, capsys):
    out = tmp_path / "design"
    argv = ["design", *DESIGN, "--checkpoint", str(design_checkpoint), "--out", str(out)]
    cli.main(argv)
    mark = json.loads((out / "condor_design.json").read_text())
    assert mark["written_by"] == "condor design"
    written = {str(p.relative_to(out)) for p in out.iterdir() if p.name != "figures"}
    written |= {f"figures/{p.name}" for p in (out / "figures").iterdir()}
    assert written - {"condor_design.json"} <= set(mark["files"])
    assert {"designs.csv", "design_01.json", "predictions.zarr", "figures/designs.png"} <= written
    code = run_main(argv)  # an earlier design: replaced with --force only
    assert code == 2 and "--force" in capsys.readouterr().err
    (out / "design_01.json").write_text("an earlier design")
    cli.main([*argv, "--force"])
    assert (out / "design_01.json").read_text() != "an earlier design"
    (out / "mine.txt").write_text("mine")  # the user's file in design's folder
    before = _snapshot(out)
    capsys.readouterr()  # the run above: its progress lines (one per phase) on stderr
    code = run_main([*argv, "--force"])
    err = capsys.readouterr().err
    assert code == 2 and err.count("\n") == 1 and "mine.txt" in err
    assert _snapshot(out) == before


# --- a read-only output folder --------------------------------------------------------------

RUN_EACH = """
import contextlib, io, json, sys, traceback
from condor import cli
results = []
for argv in json.loads(sys.argv[1]):
    err = io.StringIO()
    with contextlib.redirect_stderr(err):
        try:
            cli.main(argv)
            code = 0
        except SystemExit as exit:
            code = exit.code
        except BaseException:
            code, err = "traceback", io.StringIO(traceback.format_exc())
    results.append([code, err.getvalue()])
print(json.dumps(results))
"""


def _without_write_permission(folder):
    """The command prefix under which `folder` (mode 555) cannot be written: none for a user,
    root without the capabilities that override file permissions (setpriv)."""
    if os.geteuid() != 0:
        return []
    prefix = [shutil.which("setpriv") or "setpriv",
              "--bounding-set=-dac_override,-dac_read_search,-fowner", "--"]
    try:
        probe = subprocess.run([*prefix, "touch", str(folder / "probe")], capture_output=True)
    except OSError:
        probe = None
    if probe is None or probe.returncode == 0:
        pytest.skip("running as root and cannot drop the capability to write anywhere")
    return prefix


def test_a_read_only_output_folder_is_one_line(trained, design_checkpoint, tmp_path):
    store, checkpoint = trained
    folder = tmp_path / "readonly"
    folder.mkdir()
    np.save(tmp_path / "m.npy", synthetic_dataset(16, SIZE)["inputs"].values[3])
    folder.chmod(0o555)
    try:
        prefix = _without_write_permission(folder)
        commands = [
            ["train", "--store", str(store), "--checkpoint", str(folder / "m.pt"), "--epochs",
             "1", *FAST],
            ["evaluate", "--store", str(store), "--checkpoint", str(checkpoint), "--out",
             str(folder / "ev")],
            ["predict", str(tmp_path / "m.npy"), "--checkpoint", str(checkpoint), "--out",
             str(folder / "f.zarr")],
            ["predict", str(tmp_path / "m.npy"), "--checkpoint", str(checkpoint), "--out",
             str(folder / "f.png")],
            ["mould", "--seed", "1", "--out", str(folder / "m.json")],
            ["design", *DESIGN, "--checkpoint", str(design_checkpoint), "--out",
             str(folder / "d")],
        ]
        run = subprocess.run([*prefix, sys.executable, "-c", RUN_EACH, json.dumps(commands)],
                             capture_output=True, text=True, timeout=600)
    finally:
        folder.chmod(0o755)
    assert run.returncode == 0, run.stderr
    for argv, (code, err) in zip(commands, json.loads(run.stdout.splitlines()[-1])):
        assert code == 2 and err.count("\n") == 1, (argv, err)
        assert "permission denied" in err and "readonly" in err, (argv, err)
    assert not list(folder.iterdir())


def test_predict_force_replaces_only_a_prediction(trained, tmp_path, capsys):
    _, checkpoint = trained
    np.save(tmp_path / "m.npy", synthetic_dataset(16, SIZE)["inputs"].values[3])
    argv = ["predict", str(tmp_path / "m.npy"), "--checkpoint", str(checkpoint), "--force",
            "--out"]
    cli.main([*argv, str(tmp_path / "f.zarr")])
    cli.main([*argv, str(tmp_path / "f.zarr")])  # its own prediction: replaced
    assert xr.open_zarr(tmp_path / "f.zarr")["raw"].shape == (8, SIZE, SIZE)
    mine = tmp_path / "mine.zarr"  # a folder predict did not write
    (mine / "thesis").mkdir(parents=True)
    (mine / "thesis" / "chapter1.tex").write_text("mine")
    capsys.readouterr()
    code = run_main([*argv, str(mine)])
    err = capsys.readouterr().err
    assert code == 2 and err.count("\n") == 1 and "mine.zarr" in err and "did not write" in err
    assert (mine / "thesis" / "chapter1.tex").read_text() == "mine"


# --------------------------------------------------------------------------- issue 32


def _millimetre_mould(path):
    """A 0.6 x 0.3 mm rectangle with 4 posts of radius 0.02 mm, in mm: at l0 = 16 um it is
    37.5 x 18.75 l0, wider than the 31.25 l0 box."""
    posts = [[x, y, 0.02] for x in (0.15, 0.45) for y in (0.08, 0.22)]
    path.write_text(json.dumps({"outline": [[0, 0], [0.6, 0], [0.6, 0.3], [0, 0.3]],
                                "tethers": posts, "units": "mm"}))
    return path


def test_predict_prints_statistics_and_writes_mm_coordinates(trained, tmp_path, capsys):
    _, checkpoint = trained
    mould = _millimetre_mould(tmp_path / "plate.json")
    out = tmp_path / "p.zarr"
    code = run_main(["predict", str(mould), "--checkpoint", str(checkpoint), "--out", str(out),
                     "--l0-um", "16"])
    err = capsys.readouterr().err
    assert code == 2 and "0.5 mm square at l0 = 16 um" in err and "--fit extent" in err
    cli.main(["predict", str(mould), "--checkpoint", str(checkpoint), "--out", str(out),
              "--l0-um", "16", "--fit", "extent"])
    printed = capsys.readouterr().out
    scale = 0.9 * BOX / 37.5
    assert f"scaled by {scale:.4g} (--fit extent)" in printed
    written = xr.open_zarr(out)
    assert written.attrs["fit_scale"] == pytest.approx(scale, rel=1e-9)
    # mm coordinates: pixel centres times l0, at the drawing's size (the mould was scaled)
    np.testing.assert_allclose(written["x"].values,
                               (np.arange(SIZE) + 0.5) * BOX / SIZE * 0.016 / scale)
    assert written["x"].attrs["units"] == "mm" and written["y"].attrs["standard_name"] == \
        "projection_y_coordinate"
    assert written["raw"].attrs["long_name"] and written["raw"].attrs["units"] == "1"
    # the statistics printed, against the definitions computed here from the fields written
    f = written["normalised"].values.astype(np.float64).sum(axis=(1, 2))
    P, T, Sx2, Sy2, SxSy = f[0], f[1], f[2], f[3], f[5]
    alignment = np.hypot(Sx2 - Sy2, 2 * SxSy) / (Sx2 + Sy2)
    stats = written.attrs["statistics"]
    assert stats["alignment"]["value"] == pytest.approx(alignment, rel=1e-5)
    assert stats["alignment_x"]["value"] == pytest.approx((Sx2 - Sy2) / (Sx2 + Sy2), rel=1e-5)
    assert stats["mean_tension"]["value"] == pytest.approx(T / P, rel=1e-5)
    lines = {line.split()[0]: line for line in printed.splitlines() if line.startswith("  ")}
    assert f"{alignment:.4g}" in lines["alignment"]
    # a spread only from a checkpoint with a reproducibility map (this one has none)
    assert ("+-" in lines["alignment"]) == ("spread" in written)
    assert {"mean_tension", "tissue_area", "tissue_area_mm2", "reproducibility"} <= set(lines)
    # areas in mm^2 are the drawn mould's: the placed area scaled back by the fit
    assert stats["tissue_area_mm2"]["value"] == pytest.approx(
        stats["tissue_area"]["value"] * (0.016 / scale) ** 2, rel=1e-9)
    assert "drawn size" in lines["tissue_area_mm2"]
    # the verdict: the shipped calibration reads the score it names; the feature distance
    # (the mould's novelty against the checkpoint's own training moulds) is printed either way
    from condor.findings import load_findings
    from condor.surrogate.novelty import novelty_verdict

    line = re.search(r"training domain: novelty ([\d.]+) \(1 is typical of its training "
                     r"moulds[;,]", printed)
    assert line, printed
    novelty = written.attrs["novelty"]
    assert float(line.group(1)) == pytest.approx(novelty["novelty"], abs=0.006)
    finding = load_findings()["novelty"]
    if finding.values["score"] == "inverse_spread" and "spread" not in written:
        # this checkpoint predicts no spread map: no verdict, and it says why
        assert "which this checkpoint does not predict" in printed
        assert set(novelty) == {"novelty"}
    else:
        assert novelty["threshold"] == finding.values["threshold"]
        text, numbers = novelty_verdict(novelty[finding.values["score"]], finding.frame(),
                                        finding.values["threshold"], "x",
                                        finding.values["score"], novelty["novelty"])
        assert numbers == novelty
    assert "4 posts" in printed


def test_design_from_your_mould_keeps_it_and_reports_yours_against_the_best(
        design_checkpoint, tmp_path, capsys):
    mould = _millimetre_mould(tmp_path / "plate.json")
    out = tmp_path / "design"
    cli.main(["design", *DESIGN, "--checkpoint", str(design_checkpoint), "--out", str(out),
              "--mould", str(mould), "--l0-um", "16", "--fit", "extent",
              "--keep", "footprint,posts"])
    captured = capsys.readouterr()
    assert "yours " in captured.out and " -> best " in captured.out
    for phase in ("phase 1/4", "phase 2/4", "phase 3/4", "phase 4/4"):
        assert phase in captured.err  # one line per phase, not on a terminal
    from condor.moulds.read import load_mould
    from condor.model.scenes import get_scene

    placed = load_mould(mould, get_scene("default"), l0_um=16, fit="extent")  # box 31.25 = BOX
    table = pd.read_csv(out / "designs.csv")
    best = load_json(out / "design_01.json")
    assert best.polygon.equals(placed.polygon) or \
        best.polygon.symmetric_difference(placed.polygon).area < 1e-9
    assert best.n_tethers <= 4 and len(table)
    assert (out / "figures" / "designs.png").is_file()
    assert "the objective's predicted spread is" in captured.err  # calibrated or not, said
    summary = pd.read_csv(out / "summary.csv")
    assert np.isfinite(summary["spread_factor"]).all()
    # your mould's +-: at least 6 simulations, its standard error and one simulation's sd said
    assert "(the mean of 6 simulations +- its standard error; one simulation scatters" in \
        captured.out
    # the user's scale end to end: the design at the drawing's size, in mm, beside the l0 one
    scale = 0.9 * BOX / 37.5
    assert summary["fit_scale"].iloc[0] == pytest.approx(scale) and summary["l0_um"].iloc[0] == 16
    mark = json.loads((out / "condor_design.json").read_text())
    assert mark["scale"]["fit_scale"] == pytest.approx(scale)
    assert "design_01_drawn.dxf" in mark["files"]
    drawn = json.loads((out / "design_01_drawn.json").read_text())
    assert drawn["units"] == "mm" and "scaled by" in drawn["comment"]
    xs = [x for x, _ in drawn["outline"]]
    assert max(xs) - min(xs) == pytest.approx(0.6, rel=1e-6)  # the plate as drawn: 0.6 mm
    back = load_mould(out / "design_01_drawn.json", get_scene("default"), l0_um=16, fit="extent")
    assert back.polygon.symmetric_difference(best.polygon).area < 1e-6
    svg = (out / "design_01_drawn.svg").read_text()
    assert "At your drawing's size" in svg and 'data-units="mm"' in svg
    from condor.moulds.read import load_placement

    assert load_placement(out / "design_01_drawn.dxf", get_scene("default"), l0_um=16,
                          fit="extent").drawn_l0[0] == pytest.approx(0.6 * 1000 / 16, rel=1e-6)


def test_predict_checks_itself_by_default_and_writes_the_simulations_beside_it(
        trained, design_checkpoint, tmp_path, capsys):
    """With a checkpoint whose scene can be simulated (the default scene's box and a depth),
    `predict` checks the mould by AUTO_CHECK simulations unasked: the .zarr holds their mean
    (sum P = the mould's cells, the prediction's own N_c) and the check's numbers, and its
    answer is the best estimate of the surrogate's prediction and their mean; the .png a page
    of more panels; `--check 0` writes the surrogate's prediction alone."""
    from condor.model.lattice import lattice_sites
    from condor.stages.check import AUTO_CHECK

    mould_json = tmp_path / "m.json"
    cli.main(["mould", "--seed", "7", "--id", "0", "--out", str(mould_json)])
    out = tmp_path / "auto.zarr"
    cli.main(["predict", str(mould_json), "--checkpoint", str(design_checkpoint), "--out",
              str(out)])
    printed = capsys.readouterr().out
    assert f"checked by {AUTO_CHECK} simulations" in printed and "--check 0 skips it" in printed
    written = xr.open_zarr(out)
    check = written.attrs["check"]
    assert check["simulations"] == AUTO_CHECK and check["automatic"]
    assert check["ratio"] == pytest.approx(check["error"] / check["ceiling"])
    simulated = written["simulated"].values.astype(np.float64)
    mould = load_json(mould_json)
    cells = len(lattice_sites(mould.polygon, mould.tethers, 2.0)[0])  # the checkpoint's depth
    assert simulated[0].sum() == pytest.approx(cells, rel=1e-3)
    assert np.all(written["simulated_sd"].values >= 0)
    # the answer written is the best estimate: between the surrogate's own prediction and the
    # simulations' mean, raw and normalised alike (sum P the mould's cells)
    attrs = written["surrogate_normalised"].attrs
    weight, tension = attrs["prediction_weight"], attrs["prediction_tension_weight"]
    assert 0 <= weight <= 1 and weight == check["best_weight"]
    assert 0 <= tension <= 1 and tension == check["best_tension_weight"]
    assert written.attrs["answer"] == "best estimate"
    w = np.where(np.arange(8) == 1, tension, weight)[:, None, None]  # T (field 1) apart
    np.testing.assert_allclose(written["normalised"].values, w
                               * written["surrogate_normalised"].values + (1 - w)
                               * written["simulated_normalised"].values, rtol=1e-4, atol=1e-6)
    answer_raw = written["raw"].values.astype(np.float64)
    assert answer_raw[0].sum() == pytest.approx(cells, rel=1e-3)
    np.testing.assert_allclose(answer_raw, written["normalised"].values * cells
                               / answer_raw[0].size, rtol=1e-3, atol=1e-6)
    none = tmp_path / "none.zarr"
    cli.main(["predict", str(mould_json), "--checkpoint", str(design_checkpoint), "--out",
              str(none), "--check", "0"])
    assert "checked by" not in capsys.readouterr().out
    alone = xr.open_zarr(none)
    assert "simulated" not in alone and "check" not in alone.attrs
    assert alone.attrs["answer"] == "surrogate"
    np.testing.assert_allclose(alone["normalised"].values, written["surrogate_normalised"].values)
    pages = {}
    for check_arg in ("0", "2"):
        page = tmp_path / f"page{check_arg}.png"
        cli.main(["predict", str(mould_json), "--checkpoint", str(design_checkpoint), "--out",
                  str(page), "--check", check_arg])
        pages[check_arg] = Image.open(page).size
    assert pages["2"][0] == pages["0"][0] and pages["2"][1] > 1.4 * pages["0"][1]
    assert run_main(["predict", str(mould_json), "--checkpoint", str(design_checkpoint),
                     "--out", str(tmp_path / "x.zarr"), "--check", "some"]) == 2
    assert "--check" in capsys.readouterr().err


def test_predict_s_check_help_states_the_automatic_check_s_own_numbers():
    """--check's help quotes AUTO_CHECK and AUTO_CHECK_MAX_CELLS (written out there so that the
    parser need not import the simulator): it must say what the code does."""
    from condor.stages.check import AUTO, AUTO_CHECK, AUTO_CHECK_MAX_CELLS

    parser = cli.build_parser()
    sub = next(a for a in parser._actions if a.dest == "command").choices["predict"]
    check = next(a for a in sub._actions if a.dest == "check")
    assert check.default == AUTO
    assert f"{AUTO_CHECK} simulations" in check.help
    assert f"{AUTO_CHECK_MAX_CELLS:,} cells" in check.help
