"""Fixtures shared by the whole test session.

`tiny_run` is one finished run of the workflow on config/tiny.yaml, built once per session
however many pytest-xdist workers ask for it: it is built under a file lock in the session's
temporary folder, which every worker shares, and the others wait for it and reuse it. Tests
read it and never change it; a test that changes a run works on `tiny_copy`.

The build starts in the background as soon as a session holds a test that needs it, and those
tests run last, so that the run is built while the other tests run.
"""

import os
import shutil
import subprocess
import sys
import threading
from pathlib import Path

import pytest
from filelock import FileLock

REPO = Path(__file__).resolve().parents[1]
TINY_CONFIG = REPO / "config" / "tiny.yaml"

# One thread a process: pytest-xdist already runs one worker a core, and a second thread pool
# in each (torch's, BLAS's) only makes them wait on each other, far worse on a busy machine.
# Set before torch or numpy is imported; the subprocesses (snakemake, its jobs) inherit it.
for _name in ("OMP_NUM_THREADS", "MKL_NUM_THREADS", "OPENBLAS_NUM_THREADS"):
    os.environ.setdefault(_name, "1")


def snakemake_command(workdir, *extra, cores=2):
    return [sys.executable, "-m", "snakemake", "--cores", str(cores),
            "--snakefile", str(REPO / "Snakefile"),
            "--workflow-profile", str(REPO / "profiles" / "default"),
            "--directory", str(workdir), *extra]


def condor_cli(*args, cwd=None):
    """`condor <args>` run in this process (`condor.cli.main`), as a `CompletedProcess`: the
    exit status, stdout and stderr a user would see. An exception that escapes `main` is exit
    status 1 with its traceback on stderr, as the console script would print it. For tests of
    what a command does: it spares each a fresh interpreter and its imports (seconds). The
    entry point itself runs as a subprocess in tests/test_cli.py."""
    import contextlib
    import io
    import traceback

    from condor import cli

    out, err, code, here = io.StringIO(), io.StringIO(), 0, os.getcwd()
    try:
        if cwd is not None:
            os.chdir(cwd)
        with contextlib.redirect_stdout(out), contextlib.redirect_stderr(err):
            try:
                cli.main([str(a) for a in args])
            except SystemExit as done:
                if isinstance(done.code, str):
                    print(done.code, file=sys.stderr)
                code = done.code if isinstance(done.code, int) else int(done.code is not None)
            except Exception:  # noqa: BLE001 - what the console script would print
                traceback.print_exc()
                code = 1
    finally:
        os.chdir(here)
    return subprocess.CompletedProcess(["condor", *map(str, args)], code, out.getvalue(),
                                       err.getvalue())


def session_folder(tmp_path_factory):
    """The session's temporary folder, the same for every xdist worker."""
    root = tmp_path_factory.getbasetemp()
    return root.parent if os.environ.get("PYTEST_XDIST_WORKER") else root


def build_once(tmp_path_factory, name, build):
    """The folder `name`, built by `build(folder)` once per session (under a file lock)."""
    folder = session_folder(tmp_path_factory) / "shared" / name
    folder.parent.mkdir(parents=True, exist_ok=True)
    with FileLock(str(folder) + ".lock"):
        done = folder.with_name(name + ".done")
        if not done.exists():
            if folder.exists():  # a build that failed in another worker
                shutil.rmtree(folder)
            build(folder)
            done.touch()
    return folder


def _build_tiny_run(folder):
    folder.mkdir()
    proc = subprocess.run(snakemake_command(folder, "--configfile", str(TINY_CONFIG)),
                          capture_output=True, text=True)
    (folder.parent / "tiny_run.log").write_text(proc.stderr)
    if proc.returncode != 0:
        raise AssertionError(f"the tiny run failed ({proc.returncode}):\n{proc.stderr[-4000:]}")


def _needs_tiny_run(item):
    return "tiny_run" in getattr(item, "fixturenames", ())


def pytest_collection_modifyitems(items):
    """The tests on the shared tiny run last (the same order in every xdist worker)."""
    items.sort(key=_needs_tiny_run)


def _warm_numba(folder):
    from condor.stages.build import warm_kernels

    warm_kernels()
    folder.mkdir()


@pytest.fixture(scope="session", autouse=True)
def _numba_kernels(tmp_path_factory):
    """The workflow's numba kernels compiled into numba's on-disk cache once, by one worker,
    before any test or run: else every worker and the tiny run's jobs compile them at once
    (the same CPU-minute each, and a cache written by many processes at once can break)."""
    build_once(tmp_path_factory, "numba_kernels", _warm_numba)


@pytest.fixture(scope="session", autouse=True)
def _start_tiny_run(request, tmp_path_factory, _numba_kernels):
    """Start building the tiny run in the background when this session will need it."""
    if any(map(_needs_tiny_run, request.session.items)):
        def build():
            try:
                build_once(tmp_path_factory, "tiny_run", _build_tiny_run)
            except Exception:  # the fixture builds it again and reports the failure
                pass

        threading.Thread(target=build, daemon=True).start()


@pytest.fixture(scope="session")
def tiny_run(tmp_path_factory):
    """A finished tiny run (every target of `snakemake --configfile config/tiny.yaml`), read
    only: copy it (`tiny_copy`) to change it."""
    return build_once(tmp_path_factory, "tiny_run", _build_tiny_run)


@pytest.fixture
def tiny_copy(tiny_run, tmp_path):
    """A private copy of the finished tiny run (mtimes kept, so that nothing looks stale)."""
    copy = tmp_path / "tiny"
    shutil.copytree(tiny_run, copy, symlinks=True)
    return copy
