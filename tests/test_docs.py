"""The docs a newcomer reads (README.md, docs/*.md) name only what exists.

- no machine path (/work/, /root/, /home/, /Users/): a doc is read on another machine;
- every repository path it names (src/..., workflow/..., config/..., benchmarks/...,
  experiments/..., tests/..., docs/..., profiles/...) exists; `<name>` and `*` are wildcards;
- every `condor.<module>[.<name>]` it names imports;
- every module table row (| `file.py` | `name`, `name(...)`, ... |) names attributes that the
  module holds;
- every name in backticks that reads as code (`snake_case`, `CamelCase`, `name(...)`,
  `Class.member`) is one the code holds: a member of a condor class or module it names
  (`Predictor.mould_arguments`), or an identifier or a string's word of the code (a function, a
  config key, a column); a name that is gone from the code fails;
- a page over PAGE_LINES lines says why in its first lines ("Long page:").
"""

from __future__ import annotations

import functools
import importlib
import io
import pkgutil
import re
import tokenize
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
CODE = re.compile(r"`([A-Za-z_]\w*(?:\.[A-Za-z_]\w*)*)(\([^`]*\))?`")
WORD = re.compile(r"[A-Za-z_]\w*")
CODE_ROOTS = ("src", "workflow", "config", "benchmarks", "experiments", "profiles", ".ci",
              "tests")
FILE_SUFFIXES = {"py", "zarr", "html", "csv", "png", "json", "npz", "npy", "yaml", "md", "pt",
                 "svg", "dxf", "smk", "txt", "log", "sh", "lock", "toml", "rst"}


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


@functools.cache
def _code_words() -> frozenset:
    """Every identifier the code holds: Python's names and the words of its strings, and every
    word of the other code files (workflow rules, configs, the schema, profiles, scripts)."""
    words: set[str] = set()
    paths = [p for root in CODE_ROOTS for p in (REPO / root).rglob("*") if p.is_file()]
    for path in [*paths, REPO / "Snakefile", REPO / "pyproject.toml"]:
        if path.suffix in (".npz", ".png", ".pt", ".csv", ".json", ".md") or \
                "cache" in path.parts or path == Path(__file__).resolve():
            continue  # data, and this file (whose strings name what must not exist)
        try:
            text = path.read_text()
        except (UnicodeDecodeError, OSError):
            continue
        if path.suffix != ".py":
            words |= set(WORD.findall(text))
            continue
        for token in tokenize.generate_tokens(io.StringIO(text).readline):
            if token.type in (tokenize.NAME, tokenize.STRING):
                words |= set(WORD.findall(token.string))
    return frozenset(words)


@functools.cache
def _condor_objects() -> dict:
    """{name: [objects]}: every condor module by its last name, and every top-level name a
    condor module defines."""
    import condor

    found: dict = {}
    for info in pkgutil.walk_packages(condor.__path__, "condor."):
        module = importlib.import_module(info.name)
        found.setdefault(info.name.rsplit(".", 1)[-1], []).append(module)
        for name, value in vars(module).items():
            if not name.startswith("__") and getattr(value, "__module__", None) == info.name:
                found.setdefault(name, []).append(value)
    return found


def _looks_like_code(name: str, call: str | None) -> bool:
    """A name in backticks that reads as code, not a word or a file: dotted, called, with an
    underscore, or CamelCase."""
    if name.rsplit(".", 1)[-1] in FILE_SUFFIXES and "." in name:
        return False  # a file (the path checks cover it)
    return "." in name or call is not None or "_" in name.strip("_") or \
        (name[0].isupper() and any(c.islower() for c in name) and any(c.isupper() for c in name[1:]))


def _names_code(name: str) -> bool:
    """Whether the code holds `name` (see the module docstring). A dotted name is checked when
    its head is a condor class (`Predictor.mould_arguments`): each member must be the class's,
    or, for an instance's attribute, a name of the code; any other dotted name (a library's, a
    variable's: `np.isfinite`, `config.scene`) is not."""
    head, *rest = name.split(".")
    if not rest:
        return name in _code_words()
    classes = [c for c in _condor_objects().get(head, []) if isinstance(c, type)]
    if not classes:
        return True
    for obj in classes:
        try:
            for part in rest:
                obj = getattr(obj, part)
        except AttributeError:
            if len(rest) == 1 and rest[0] in _code_words():
                return True  # an instance's attribute (set in __init__, a dataclass field)
            continue
        return True
    return False


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
def test_doc_names_only_code_that_exists(doc: Path):
    names = {m.group(1) for m in CODE.finditer(doc.read_text())
             if not m.group(1).startswith("condor.") and _looks_like_code(*m.groups())}
    missing = sorted(n for n in names if not _names_code(n))
    assert not missing, f"{doc.name} names code that does not exist: {missing}"


@pytest.mark.parametrize("doc", DOCS, ids=_id)
def test_a_long_page_says_why(doc: Path):
    lines = doc.read_text().splitlines()
    if len(lines) > PAGE_LINES:
        assert any(line.startswith("Long page:") for line in lines[:15]), (
            f"{doc.name} has {len(lines)} lines (more than {PAGE_LINES}) and no 'Long page:' "
            "line near its top saying why")


def test_the_readme_s_first_screen_is_for_a_newcomer():
    """The README's first 40 lines (what a newcomer reads first): no commit hash, no command
    or line wider than 100 characters, no table (its cells grow long; docs/results.md has it)."""
    first = (REPO / "README.md").read_text().splitlines()[:40]
    hashes = [word for line in first for word in re.findall(r"\b[0-9a-f]{7,40}\b", line)
              if re.search(r"[a-f]", word) and re.search(r"[0-9]", word)]
    assert not hashes, f"commit hashes on the README's first screen: {hashes}"
    assert max(map(len, first)) <= 100
    assert not any(line.lstrip().startswith("|") for line in first)


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
    assert _names_code("Predictor.mould_arguments") and not _names_code("Predictor.predict_file")
    assert _names_code("load_mould") and not _names_code("read_mould")
    assert _names_code("relaxed_anneal") and _names_code("np.array_equal")
    assert not _looks_like_code("snakemake", None) and _looks_like_code("run", "(x)")
