"""The docs a newcomer reads (README.md, docs/*.md) name only what exists.

- no machine path (/work/, /root/, /home/, /Users/): a doc is read on another machine;
- every repository path it names (src/..., workflow/..., config/..., benchmarks/...,
  experiments/..., tests/..., docs/..., profiles/...) exists; `<name>` and `*` are wildcards;
- every `condor.<module>[.<name>]` it names imports;
- every module table row (| `file.py` | `name`, `name(...)`, ... |) names attributes that the
  module holds;
- a page over PAGE_LINES lines says why in its first lines ("Long page:").
"""

from __future__ import annotations

import importlib
import re
from pathlib import Path

import pytest

REPO = Path(__file__).resolve().parents[1]
DOCS = [REPO / "README.md", *sorted((REPO / "docs").glob("*.md"))]
PAGE_LINES = 400
MACHINE_PATH = re.compile(r"(?<![\w.~-])/(?:work|root|home|Users)/")
ROOTS = ("src/", "workflow/", "config/", "benchmarks/", "experiments/", "tests/", "docs/",
         "profiles/")
PATH = re.compile(r"(?<![\w./-])((?:%s)(?:[\w./<>*-]|\{[\w,]*\})*[\w*>}])"
                  % "|".join(map(re.escape, ROOTS)))
DOTTED = re.compile(r"`(condor(?:\.[A-Za-z_]\w*)+)")
TABLE_ROW = re.compile(r"^\|\s*`([\w/]+)\.py`[^|]*\|(.*)\|\s*$")
NAME = re.compile(r"`([A-Za-z_]\w*)(?![\w.])")


def _id(path: Path) -> str:
    return path.relative_to(REPO).as_posix()


def _exists(path: str) -> bool:
    pattern = re.sub(r"<[^>]*>|\{[^}]*\}", "*", path.rstrip("."))
    return any(REPO.glob(pattern)) if "*" in pattern else (REPO / pattern).exists()


def _resolves(dotted: str) -> bool:
    parts = dotted.split(".")
    for i in range(len(parts), 0, -1):
        try:
            obj = importlib.import_module(".".join(parts[:i]))
        except ImportError:
            continue
        try:
            for name in parts[i:]:
                obj = getattr(obj, name)
        except AttributeError:
            return False
        return True
    return False


def _module_of(stem: str):
    """The one condor module `<stem>.py` names (searched under src/condor), or None."""
    found = [p for p in (REPO / "src" / "condor").rglob(f"{Path(stem).name}.py")
             if p.relative_to(REPO / "src").with_suffix("").as_posix().endswith(stem)]
    if len(found) != 1:
        return None
    return importlib.import_module(found[0].relative_to(REPO / "src").with_suffix("")
                                   .as_posix().replace("/", "."))


@pytest.mark.parametrize("doc", DOCS, ids=_id)
def test_doc_holds_no_machine_path(doc: Path):
    bad = [f"{doc.name}:{n}: {line.strip()}" for n, line in
           enumerate(doc.read_text().splitlines(), 1) if MACHINE_PATH.search(line)]
    assert not bad, "machine paths:\n" + "\n".join(bad)


@pytest.mark.parametrize("doc", DOCS, ids=_id)
def test_doc_names_only_files_that_exist(doc: Path):
    missing = sorted({m for m in PATH.findall(doc.read_text()) if not _exists(m)})
    assert not missing, f"{doc.name} names files that do not exist: {missing}"


@pytest.mark.parametrize("doc", DOCS, ids=_id)
def test_doc_names_only_condor_modules_and_names_that_exist(doc: Path):
    text = doc.read_text()
    missing = sorted({d for d in DOTTED.findall(text) if not _resolves(d)})
    for row in text.splitlines():
        match = TABLE_ROW.match(row)
        if not match or (module := _module_of(match.group(1))) is None:
            continue
        missing += [f"{match.group(1)}.py: {name}" for name in NAME.findall(match.group(2))
                    if not name.startswith("__") and not hasattr(module, name)]
    assert not missing, f"{doc.name} names what does not exist: {missing}"


@pytest.mark.parametrize("doc", DOCS, ids=_id)
def test_a_long_page_says_why(doc: Path):
    lines = doc.read_text().splitlines()
    if len(lines) > PAGE_LINES:
        assert any(line.startswith("Long page:") for line in lines[:15]), (
            f"{doc.name} has {len(lines)} lines (more than {PAGE_LINES}) and no 'Long page:' "
            "line near its top saying why")


def test_the_checks_catch_what_they_are_for():
    assert MACHINE_PATH.search("see /work/data/x.npz") and not MACHINE_PATH.search("a/work/b")
    assert PATH.findall("run `benchmarks/bench_x.py` and experiments/<study>/README.md.") == [
        "benchmarks/bench_x.py", "experiments/<study>/README.md"]
    assert PATH.findall("tables experiments/surrogate/surrogate_curve_{data,size}.csv") == [
        "experiments/surrogate/surrogate_curve_{data,size}.csv"]
    assert _exists("experiments/<study>/README.md") and not _exists("benchmarks/bench_x.py")
    assert _resolves("condor.studies.scoring.paired_ratio")
    assert not _resolves("condor.studies.scoring.no_such_name")
    assert not _resolves("condor.no_such_module")
    assert _module_of("surrogate/train") is not None
