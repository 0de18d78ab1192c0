"""Every benchmark script still imports against the current library and answers --help.

A script does its work only under `if __name__ == "__main__"`, so importing it and asking for
its --help are cheap; together they catch imports of moved or removed library names, which
no other test exercises. A script without argparse would run its workload on --help, so
its --help is skipped.
"""

from __future__ import annotations

import importlib.util
import subprocess
import sys
from pathlib import Path

import pytest

REPO = Path(__file__).resolve().parents[1]
BENCHMARKS = sorted((REPO / "benchmarks").glob("*.py"))


def _id(path: Path) -> str:
    return path.stem


def test_benchmarks_found():
    assert BENCHMARKS, "no benchmarks/*.py found"


@pytest.mark.parametrize("script", BENCHMARKS, ids=_id)
def test_benchmark_imports_and_answers_help(script: Path):
    name = f"_benchmark_{script.stem}"
    spec = importlib.util.spec_from_file_location(name, script)
    module = importlib.util.module_from_spec(spec)
    sys.modules[name] = module  # as `import` does: dataclasses look their module up there
    try:
        spec.loader.exec_module(module)
    except SystemExit as err:  # a script must not run (or exit) at import
        pytest.fail(f"{script.name} exited at import ({err.code!r})")
    finally:
        sys.modules.pop(name, None)
    if "argparse" not in script.read_text():
        pytest.skip(f"{script.name} has no argparse: --help would run its workload")
    done = subprocess.run([sys.executable, str(script), "--help"], cwd=REPO, capture_output=True,
                          text=True, timeout=120)
    assert done.returncode == 0, f"{script.name} --help failed:\n{done.stderr[-2000:]}"
    assert "usage:" in done.stdout
