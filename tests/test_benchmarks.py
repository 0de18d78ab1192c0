"""The performance tools (benchmarks/) run on the tiny scene; every experiment script
(experiments/<study>/) still imports against the current library and answers --help.

A script does its work only under `if __name__ == "__main__"`, so importing it and asking for
its --help are cheap; together they catch imports of moved or removed library names, which
no other test exercises. The benchmarks are run for real, with the smallest settings, in a
scratch folder: each must finish and print its figures (the figures themselves depend on the
machine and are not checked).
"""

from __future__ import annotations

import importlib.util
import json
import os
import subprocess
import sys
from pathlib import Path

import pytest

from conftest import build_once

REPO = Path(__file__).resolve().parents[1]
BENCHMARKS = sorted((REPO / "benchmarks").glob("*.py"))
EXPERIMENTS = sorted((REPO / "experiments").glob("*/*.py"))

# Each performance tool with its smallest settings on the tiny scene, and a word its output
# must hold.
SMOKE = {
    "bench_fields": (["--cells", "300", "--repeats", "1"], "ms"),
    "bench_busy": (["--rounds", "1", "--steps", "1", "--competitors", "1", "--settings",
                    "1-passive"], "ratio"),
    "bench_simulator": (["--scene", "tiny", "--solvers", "lbfgs"], "lbfgs"),
    "bench_surrogate": (["--repeats", "1", "--batch", "2", "--threads", "1"], "s/mould"),
    "bench_design": (["--scene", "tiny", "--budget", "20", "--repeats", "1"], "designs"),
    "bench_workflow_overhead": (["--moulds", "6", "--repeats", "1", "--sizes", "6"], "job"),
    # the tiny run's checkpoint (the shared tiny run, tests/conftest.py)
    "bench_predict": (["{checkpoint}", "--moulds", "2", "--repeats", "1"], "ms a mould"),
}


def _id(path: Path) -> str:
    return f"{path.parent.name}/{path.stem}"


def test_benchmarks_are_the_performance_tools_and_studies_live_in_experiments():
    assert {p.stem for p in BENCHMARKS} == set(SMOKE)
    assert EXPERIMENTS, "no experiments/*/*.py found"
    for folder in {p.parent for p in EXPERIMENTS}:
        assert (folder / "README.md").is_file(), f"{folder.name} has no README.md"


# Every script's --help in one fresh interpreter (a script's own folder on sys.path, its sibling
# modules forgotten after it, the library's imports shared): one start-up and one import of
# torch and the library for all of them, not one each (about 26 x 5 CPU seconds).
HELP_RUNNER = r"""
import contextlib, io, json, os, runpy, sys, traceback
del sys.path[0]  # this runner's own folder: a script sees only its own
results = {}
for script in json.loads(sys.argv[1]):
    folder, before = os.path.dirname(script), set(sys.modules)
    out, err, code = io.StringIO(), io.StringIO(), 0
    sys.argv = [script, "--help"]
    sys.path.insert(0, folder)  # as `python <script>` does
    try:
        with contextlib.redirect_stdout(out), contextlib.redirect_stderr(err):
            runpy.run_path(script, run_name="__main__")
    except SystemExit as done:
        code = done.code if isinstance(done.code, int) else int(done.code is not None)
    except BaseException:
        err.write(traceback.format_exc())
        code = 1
    finally:
        sys.path.remove(folder)
        for name in set(sys.modules) - before:
            if (getattr(sys.modules[name], "__file__", None) or "").startswith(folder + os.sep):
                del sys.modules[name]
    results[script] = {"returncode": code, "stdout": out.getvalue(), "stderr": err.getvalue()}
print(json.dumps(results))
"""


def _run_helps(folder: Path):
    folder.mkdir()
    scripts = [str(s) for s in EXPERIMENTS + BENCHMARKS if "argparse" in s.read_text()]
    (folder / "runner.py").write_text(HELP_RUNNER)
    done = subprocess.run([sys.executable, str(folder / "runner.py"), json.dumps(scripts)],
                          cwd=REPO, capture_output=True, text=True)
    assert done.returncode == 0, done.stderr[-3000:]
    (folder / "helps.json").write_text(done.stdout.splitlines()[-1])


@pytest.fixture(scope="session")
def helps(tmp_path_factory):
    """{script: returncode, stdout, stderr} of `python <script> --help`, run once a session."""
    folder = build_once(tmp_path_factory, "script_helps", _run_helps)
    return json.loads((folder / "helps.json").read_text())


@pytest.mark.parametrize("script", EXPERIMENTS + BENCHMARKS, ids=_id)
def test_script_imports_without_path_tricks_and_answers_help(script: Path, helps):
    text = script.read_text()
    assert "sys.path.insert" not in text and "sys.path.append" not in text
    name = f"_script_{script.parent.name}_{script.stem}"
    spec = importlib.util.spec_from_file_location(name, script)
    module = importlib.util.module_from_spec(spec)
    sys.modules[name] = module  # as `import` does: dataclasses look their module up there
    sys.path.insert(0, str(script.parent))  # as `python <script>` does for its own folder
    before = set(sys.modules)
    environ = dict(os.environ)  # a script sets its threads (NUMBA_NUM_THREADS) at import
    try:
        spec.loader.exec_module(module)
    except SystemExit as err:  # a script must not run (or exit) at import
        pytest.fail(f"{script.name} exited at import ({err.code!r})")
    finally:
        sys.modules.pop(name, None)
        sys.path.remove(str(script.parent))
        # numba reads the environment at every compile and refuses a thread count other than
        # the one it launched with: a later test of this worker would fail on it
        os.environ.clear()
        os.environ.update(environ)
        # its own folder's modules (a sibling `run`) go too, as with the process that
        # `python <script>` ends: another folder's script would otherwise import this one's
        for added in set(sys.modules) - before:
            origin = getattr(sys.modules[added], "__file__", None) or ""
            if Path(origin).parent == script.parent:
                del sys.modules[added]
    if "argparse" not in text:
        pytest.skip(f"{script.name} has no argparse: --help would run its workload")
    done = helps[str(script)]
    assert done["returncode"] == 0, f"{script.name} --help failed:\n{done['stderr'][-2000:]}"
    assert "usage:" in done["stdout"]


@pytest.mark.slow
@pytest.mark.parametrize("script", BENCHMARKS, ids=_id)
def test_benchmark_runs_on_the_tiny_scene(script: Path, tmp_path, request):
    args, word = SMOKE[script.stem]
    if "{checkpoint}" in args:
        checkpoint = request.getfixturevalue("tiny_run") / "results" / "models" / "unet.pt"
        args = [str(checkpoint) if a == "{checkpoint}" else a for a in args]
    env = {**os.environ, "OPENBLAS_NUM_THREADS": "1", "OMP_NUM_THREADS": "1"}
    done = subprocess.run([sys.executable, str(script), *args], cwd=tmp_path,
                          capture_output=True, text=True, env=env)
    assert done.returncode == 0, f"{script.name} failed:\n{done.stderr[-3000:]}"
    assert word in done.stdout, done.stdout[-2000:]
