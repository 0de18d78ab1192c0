"""The import graph of src/condor against the floors of docs/architecture.md: every module is
on a floor, the floors below the top are folders, no import (at module level or inside a
function) climbs a floor, and no modules import each other in a circle. And the size bar: no
module of src/condor over MODULE_LINES lines, no function of cli.py over CLI_FUNCTION_LINES."""

import ast
import re
from pathlib import Path

REPO = Path(__file__).resolve().parents[1]
SRC = REPO / "src" / "condor"
ARCHITECTURE = REPO / "docs" / "architecture.md"
MODULE_LINES = 600  # a module longer than this is split along its ideas
CLI_FUNCTION_LINES = 40  # a command or parser function of cli.py longer than this is split


def floors() -> list[tuple[str, list[str]]]:
    """The table of docs/architecture.md's "The floors": [(floor, [module names under
    condor, a package's name for all of it])], bottom up."""
    text = ARCHITECTURE.read_text().split("## The floors", 1)[1].split("\n## ", 1)[0]
    table: list[tuple[str, list[str]]] = []
    for line in text.splitlines():
        cells = [c.strip() for c in line.strip().strip("|").split("|")]
        if len(cells) < 3 or cells[0] == "floor" or cells[1].startswith("---"):
            continue
        names = re.findall(r"`([\w.]+)`", cells[1])
        if cells[0]:
            table.append((cells[0], []))
        table[-1][1].extend(names)
    return table


def modules() -> dict[str, Path]:
    """Every module of the package by dotted name under condor ('model.simulate'; a
    package's __init__ by the package's name)."""
    found = {}
    for path in SRC.rglob("*.py"):
        parts = path.relative_to(SRC).with_suffix("").parts
        if parts[-1] == "__init__":
            parts = parts[:-1]
        found[".".join(parts) or "condor"] = path  # "condor": the package itself, the top
    return found


def imports(name: str, path: Path, known: set[str]) -> set[str]:
    """The condor modules `name` imports, anywhere in it."""
    package = name.split(".") if path.name == "__init__.py" else name.split(".")[:-1]
    out = set()
    for node in ast.walk(ast.parse(path.read_text())):
        if isinstance(node, ast.Import):
            targets = [a.name for a in node.names]
        elif isinstance(node, ast.ImportFrom):
            if node.level:
                base = package[:len(package) - node.level + 1]
                stem = ".".join(["condor", *base, *([node.module] if node.module else [])])
            else:
                stem = node.module or ""
            targets = [f"{stem}.{a.name}" for a in node.names] + [stem]
        else:
            continue
        for target in targets:
            if target != "condor" and not target.startswith("condor."):
                continue
            target = target[len("condor."):]
            while target and target not in known:  # `from m import function`: the module m
                target = target.rpartition(".")[0]
            target = target or "condor"
            if target != name:
                out.add(target)
    return out


def graph() -> dict[str, set[str]]:
    found = modules()
    return {name: imports(name, path, set(found)) for name, path in found.items()}


def floor_of(name: str, table) -> int:
    if name == "condor":  # the package's own __init__ (condor.open_dataset): the top floor
        return len(table) - 1
    best = None
    for level, (floor, names) in enumerate(table):
        if name == floor:  # a floor's folder: its package
            return level
        for entry in names:
            if name == entry or name.startswith(entry + "."):
                if best is None or len(entry) > best[1]:
                    best = (level, len(entry))
    assert best is not None, f"condor.{name} is on no floor of docs/architecture.md"
    return best[0]


def test_every_module_is_on_a_floor_and_the_floors_are_folders():
    table = floors()
    assert [floor for floor, _ in table][:1] == ["base"] and table[-1][0] == "top"
    for name in modules():
        floor = table[floor_of(name, table)][0]
        if floor not in ("base", "top"):
            assert name.split(".")[0] == floor, f"condor.{name} is on floor {floor!r}"
        else:  # a module of base or top, or of a package the table puts there (stages, report)
            level = floor_of(name, table)
            assert "." not in name or name.split(".")[0] in table[level][1], name


def label(name: str, table=None) -> str:
    full = name if name == "condor" else f"condor.{name}"
    return full if table is None else f"{full} ({table[floor_of(name, table)][0]})"


def test_no_import_climbs_a_floor():
    table = floors()
    climbs = [f"{label(a, table)} imports {label(b, table)}"
              for a, targets in graph().items() for b in targets
              if floor_of(b, table) > floor_of(a, table)]
    assert not climbs, "\n".join(climbs)


def test_no_circular_imports():
    edges = graph()
    state: dict[str, int] = {}
    circles = []

    def visit(node, stack):
        state[node] = 1
        for nxt in sorted(edges[node]):
            if state.get(nxt) == 1:
                circles.append(" -> ".join(map(label, stack[stack.index(nxt):] + [nxt])))
            elif nxt not in state:
                visit(nxt, stack + [nxt])
        state[node] = 2

    for node in sorted(edges):
        if node not in state:
            visit(node, [node])
    assert not circles, "\n".join(circles)


def test_import_condor_chooses_how_openmp_threads_wait_unless_told_otherwise():
    """`import condor` chooses the wait before torch or numba load the OpenMP runtime
    (condor.openmp: spin briefly on an idle machine, sleep on a busy one), marks its choice, and
    keeps a value the environment already holds."""
    import os
    import subprocess
    import sys

    from condor import openmp

    code = ("import os, condor; print(os.environ.get('CONDOR_OPENMP_WAIT'), "
            "os.environ.get('OMP_WAIT_POLICY'), os.environ.get('GOMP_SPINCOUNT'))")
    env = {k: v for k, v in os.environ.items() if k not in (*openmp.KEYS, openmp.MARK)}
    chosen = subprocess.run([sys.executable, "-c", code], env=env, capture_output=True,
                            text=True, check=True).stdout.split()
    assert chosen in (["spin", "None", str(openmp.SPIN_COUNT)], ["sleep", "PASSIVE", "None"])
    kept = subprocess.run([sys.executable, "-c", code], env={**env, "OMP_WAIT_POLICY": "ACTIVE"},
                          capture_output=True, text=True, check=True).stdout.split()
    assert kept == ["None", "ACTIVE", "None"]


def test_no_module_is_over_the_line_bar():
    long = [f"{path.relative_to(REPO)}: {n} lines" for path in sorted(SRC.rglob("*.py"))
            if (n := len(path.read_text().splitlines())) > MODULE_LINES]
    assert not long, f"modules over {MODULE_LINES} lines:\n" + "\n".join(long)


def test_no_function_of_the_cli_is_over_the_line_bar():
    tree = ast.parse((SRC / "cli.py").read_text())
    long = [f"{node.name}: {node.end_lineno - node.lineno + 1} lines" for node in tree.body
            if isinstance(node, (ast.FunctionDef, ast.AsyncFunctionDef))
            and node.end_lineno - node.lineno + 1 > CLI_FUNCTION_LINES]
    assert not long, f"functions of cli.py over {CLI_FUNCTION_LINES} lines:\n" + "\n".join(long)


def test_a_config_check_imports_no_torch_and_still_checks_the_surrogate():
    """What every `snakemake` start does (the Snakefile's Config.from_dict, which checks the
    surrogate's settings and the design objective) imports neither torch nor cma: torch alone
    costs about a second a start (condor.surrogate.settings). The check is still made: a bad
    surrogate setting is refused there."""
    import subprocess
    import sys

    code = ("import sys\n"
            "from condor.config import Config, ConfigError\n"
            "Config.from_dict({'scene': 'tiny'})\n"
            "try:\n"
            "    Config.from_dict({'scene': 'tiny', 'surrogate': {'models': {'unet': "
            "{'preset': 'unet', 'head': 'nope'}}}})\n"
            "    print('accepted')\n"
            "except ConfigError as err:\n"
            "    print('refused:', err)\n"
            "print(sorted(m for m in ('torch', 'cma', 'matplotlib') if m in sys.modules))\n")
    done = subprocess.run([sys.executable, "-c", code], capture_output=True, text=True)
    assert done.returncode == 0, done.stderr[-2000:]
    lines = done.stdout.splitlines()
    assert lines[0].startswith("refused:") and "head" in lines[0]
    assert lines[-1] == "[]"
