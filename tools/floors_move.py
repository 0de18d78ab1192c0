"""Issue 30, item 4: the floors of docs/architecture.md as folders of src/condor.

A pure move: `git mv` of each module below (and surrogate/data.py to surrogate/samples.py,
a name no reader confuses with the data floor), a package `__init__.py` (a one-line docstring)
for each new folder, and a rewrite of every reference to a moved module in the tracked text
files (imports, `condor.<module>` names, `src/condor/<module>.py` paths). Nothing else
changes. Run from the repository root on a clean tree, then commit:

    python tools/floors_move.py && git add -A && git commit

It can be replayed after merging other branches: a module already moved is skipped, and the
rewrite only touches references to the old names. `condor.dataset` stays the public name of
the dataset reader (`condor/__init__.py` serves it), so only its imports and path change.
"""

from __future__ import annotations

import re
import subprocess
from pathlib import Path

ROOT = Path(__file__).resolve().parents[1]
PKG = ROOT / "src" / "condor"

# old module (under condor) -> new module (under condor)
MOVES = {
    # the model: the CONDOR physics and its solvers
    "scenes": "model.scenes", "lattice": "model.lattice", "energy": "model.energy",
    "walls": "model.walls", "anneal": "model.anneal", "lbfgs": "model.lbfgs",
    "minimise": "model.minimise", "simulate": "model.simulate",
    # the data: moulds, their fields and inputs, the store and its reader
    "seeds": "data.seeds", "moulds": "data.moulds", "drawings": "data.drawings",
    "fields": "data.fields", "inputs": "data.inputs", "store": "data.store",
    "dataset": "data.reader",
    # the measures
    "estimators": "measures.estimators", "metrics": "measures.metrics",
    # a study
    "stability": "studies.stability",
    # within a floor: the surrogate's view of the samples, not to be confused with data/
    "surrogate.data": "surrogate.samples",
}
PACKAGES = {
    "model": "The model: scenes, the FCC lattice and walls, the CONDOR energy, its solvers, one "
             "simulation (docs/architecture.md).",
    "data": "The data: moulds (generated and drawn), seeds, fields, inputs, the Zarr store and its "
            "reader (docs/architecture.md).",
    "measures": "The measures: errors against the expected fields with the replica noise removed, "
                "and the paper's own metrics (docs/architecture.md).",
}
ALIASED = {"dataset"}  # `condor.dataset` stays a public name (condor/__init__.py)
TEXT = (".py", ".md", ".smk", ".rst", ".yaml", ".yml", ".toml", ".txt", ".cfg", ".ini")
SKIP = ("docs/data/",)


def git(*args: str) -> str:
    return subprocess.run(["git", *args], cwd=ROOT, check=True, capture_output=True,
                          text=True).stdout


def move() -> None:
    for name, text in PACKAGES.items():
        init = PKG / name / "__init__.py"
        if not init.exists():
            init.parent.mkdir(exist_ok=True)
            init.write_text(f'"""{text}"""\n')
            git("add", str(init.relative_to(ROOT)))
    for old, new in MOVES.items():
        src = PKG / (old.replace(".", "/") + ".py")
        dst = PKG / (new.replace(".", "/") + ".py")
        if src.exists() and not dst.exists():
            git("mv", str(src.relative_to(ROOT)), str(dst.relative_to(ROOT)))


FROM_CONDOR = re.compile(r"^(?P<indent>\s*)from condor import (?P<names>[^#(\n]+?)(?P<tail>\s*#.*)?$",
                         re.M)


def _split_from_condor(match: re.Match) -> str:
    """`from condor import a as b, c` with moved names regrouped by their new package."""
    groups: dict[str, list[str]] = {}
    for item in (part.strip() for part in match["names"].split(",")):
        name, _, alias = (x.strip() for x in item.partition(" as "))
        if name in MOVES:
            parent, _, leaf = ("condor." + MOVES[name]).rpartition(".")
            alias = alias or (name if leaf != name else "")
            groups.setdefault(parent, []).append(f"{leaf} as {alias}" if alias else leaf)
        else:
            groups.setdefault("condor", []).append(item)
    if list(groups) == ["condor"]:
        return match[0]
    tail = match["tail"] or ""
    lines = [f"{match['indent']}from {parent} import {', '.join(items)}{tail}"
             for parent, items in groups.items()]
    return "\n".join(lines)


FROM_PACKAGE = re.compile(r"^(?P<indent>\s*)from condor\.(?P<package>\w+) import "
                          r"(?P<names>[^#(\n]+?)(?P<tail>\s*#.*)?$", re.M)


def _from_package(match: re.Match) -> str:
    """`from condor.<package> import <module>` of a module moved within its package."""
    items, moved = [], False
    for item in (part.strip() for part in match["names"].split(",")):
        name, _, alias = (x.strip() for x in item.partition(" as "))
        new = MOVES.get(f"{match['package']}.{name}")
        if new and new.rpartition(".")[0] == match["package"]:
            item, moved = f"{new.rpartition('.')[2]} as {alias or name}", True
        items.append(item)
    if not moved:
        return match[0]
    return f"{match['indent']}from condor.{match['package']} import {', '.join(items)}" \
        f"{match['tail'] or ''}"


def rewrite(text: str, path: str) -> str:
    text = FROM_CONDOR.sub(_split_from_condor, text)
    text = FROM_PACKAGE.sub(_from_package, text)
    for old, new in MOVES.items():
        dotted = re.escape(old)
        if old in ALIASED:  # imports only: `condor.dataset.x` in prose and code is the alias
            text = re.sub(rf"(?<![\w.])(from|import) condor\.{dotted}\b", rf"\1 condor.{new}",
                          text)
        else:
            text = re.sub(rf"(?<![\w.])condor\.{dotted}\b", f"condor.{new}", text)
        text = re.sub(rf"(?<![\w.])condor/{re.escape(old.replace('.', '/'))}\.py\b",
                      f"condor/{new.replace('.', '/')}.py", text)
        if path.startswith("src/condor/") and path.count("/") == 3:  # a subpackage's module
            text = re.sub(rf"^(\s*)from \.\.{dotted} import", rf"\1from ..{new} import", text,
                          flags=re.M)
            package, _, module = old.rpartition(".")
            if package and path.startswith(f"src/condor/{package}/"):  # its own package
                text = re.sub(rf"^(\s*)from \.{module} import",
                              rf"\1from .{new.rpartition('.')[2]} import", text, flags=re.M)
    return text


def main() -> None:
    move()
    for path in git("ls-files").splitlines():
        if not path.endswith(TEXT) and Path(path).name != "Snakefile":
            continue
        if path.startswith(SKIP) or path == "tools/floors_move.py":
            continue
        file = ROOT / path
        if not file.is_file():
            continue
        text = file.read_text()
        new = rewrite(text, path)
        if new != text:
            file.write_text(new)


if __name__ == "__main__":
    main()
