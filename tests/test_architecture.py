"""docs/architecture.md holds true: its flow of imports, its table of every module of the package,
and its way of adding a method (the example module and the program that registers it), run from
the command line."""
from __future__ import annotations

import ast
import json
import os
import re
import subprocess
import sys
from pathlib import Path

from helpers import places, write_traversal

REPO = Path(__file__).resolve().parents[1]
DOC = REPO / "docs" / "architecture.md"


def test_every_module_is_listed_once_and_nothing_else() -> None:
    listed = re.findall(r"^\| `([^`]+\.py)` \|", DOC.read_text(), re.MULTILINE)
    modules = sorted(str(path.relative_to(REPO / "wiloc")) for path in (REPO / "wiloc").rglob("*.py"))
    assert sorted(listed) == modules


def _load_time_imports(path: Path) -> set[str]:
    """The package's modules (a subpackage as one) that ``path`` imports when it loads: import
    statements outside functions and ``if TYPE_CHECKING:`` blocks."""
    found = set()
    pending: list[ast.AST] = [ast.parse(path.read_text())]
    while pending:
        node = pending.pop()
        if isinstance(node, (ast.FunctionDef, ast.AsyncFunctionDef, ast.Lambda)) or \
                isinstance(node, ast.If) and ast.unparse(node.test) == "TYPE_CHECKING":
            continue
        if isinstance(node, ast.ImportFrom) and node.level == 0 and (node.module or "").startswith("wiloc"):
            parts = node.module.split(".")
            found |= {parts[1]} if len(parts) > 1 else {a.name for a in node.names if _is_module(a.name)}
        elif isinstance(node, ast.Import):
            found |= {a.name.split(".")[1] for a in node.names if a.name.startswith("wiloc.")}
        pending.extend(ast.iter_child_nodes(node))
    return found


def _is_module(name: str) -> bool:
    return (REPO / "wiloc" / f"{name}.py").is_file() or (REPO / "wiloc" / name).is_dir()


def test_a_module_imports_only_modules_left_of_it_in_the_flow() -> None:
    text = DOC.read_text()
    flow = re.findall(r"\w+", text[text.index("    errors ->"):text.index("The library never prints")])
    place = {name: i for i, name in enumerate(flow)}
    units: dict[str, set[str]] = {}
    for path in (REPO / "wiloc").rglob("*.py"):
        unit = path.relative_to(REPO / "wiloc").with_suffix("").parts[0]
        if unit != "__init__":
            units.setdefault(unit, set()).update(_load_time_imports(path) - {unit, "__init__"})
    assert sorted(flow) == sorted(units)  # each module or subpackage once
    later = {unit: sorted(d for d in deps if place[d] > place[unit]) for unit, deps in units.items()}
    assert not any(later.values()), {unit: deps for unit, deps in later.items() if deps}


def _adding_a_method() -> list[str]:
    """The Python blocks of the doc's "Adding a method": the method module, then the program."""
    text = DOC.read_text()
    section = text[text.index("### Adding a method"):text.index("## Modules and their contracts")]
    return re.findall(r"```python\n(.*?)```", section, re.DOTALL)


def test_a_method_registered_before_the_command_line_loads_runs_from_it(tmp_path: Path) -> None:
    module, program = _adding_a_method()
    (tmp_path / "ratio.py").write_text(module)
    (tmp_path / "my_wiloc.py").write_text(program)
    scenes = places(30)
    ref = write_traversal(tmp_path / "ref", scenes, 1.0, 1)
    query = write_traversal(tmp_path / "query", scenes, 0.7, 2)
    env = {**os.environ, "WILOC_CACHE": str(tmp_path / "cache"), "COLUMNS": "120"}

    def wiloc(*args: str) -> subprocess.CompletedProcess[str]:
        return subprocess.run([sys.executable, "my_wiloc.py", *args], cwd=tmp_path, env=env,
                              capture_output=True, text=True, timeout=300, check=False)

    out = tmp_path / "ratio.csv"
    done = wiloc("localize", str(query), "--map", str(ref), "--method", "ratio", "--window", "3",
                 "--out", str(out), "--jobs", "1", "--json")
    assert done.returncode == 0, done.stderr
    [run] = json.loads(done.stdout)["runs"]
    assert run["method"] == "ratio" and run["frames"] == 30
    header = dict(line[2:].split(": ", 1) for line in out.read_text().splitlines() if line.startswith("# "))
    assert json.loads(header["params"])["window"] == 3
    assert "second" in out.read_text().splitlines()[len(header)].split(",")  # the method's own column
    shown = wiloc("localize", "--help").stdout
    assert "options of fabmap, ratio" in shown  # --window, which fabmap declares too
    refused = wiloc("localize", str(query), "--map", str(ref), "--method", "ratio", "--particles", "5")
    assert refused.returncode == 2 and "--particles: method 'ratio' takes no such option" in refused.stderr


def _wiloc_imports(path: Path) -> set[str]:
    """Every wiloc module ``path`` imports, when it loads or inside a function."""
    found = set()
    for node in ast.walk(ast.parse(path.read_text())):
        if isinstance(node, ast.ImportFrom) and node.level == 0 and (node.module or "").startswith("wiloc"):
            found |= {node.module} if node.module != "wiloc" else {f"wiloc.{a.name}" for a in node.names}
        elif isinstance(node, ast.Import):
            found |= {a.name for a in node.names if a.name.startswith("wiloc")}
    return found - {"wiloc.__version__"}


def test_every_module_stays_small() -> None:
    """Each module of the package: at most 500 lines, at most 12 wiloc modules imported."""
    sizes = {str(path.relative_to(REPO)): (len(path.read_text().splitlines()), len(_wiloc_imports(path)))
             for path in (REPO / "wiloc").rglob("*.py")}
    assert len(sizes) > 80
    assert {name: size for name, size in sizes.items() if size[0] > 500 or size[1] > 12} == {}


def test_error_types_are_imported_from_wiloc_errors() -> None:
    """An error type has one home, wiloc.errors: a module importing one through another module
    (which happens to import it too) depends on that module for nothing it defines."""
    errors = {node.name for node in ast.parse((REPO / "wiloc" / "errors.py").read_text()).body
              if isinstance(node, ast.ClassDef)}
    elsewhere = sorted(f"{path.relative_to(REPO)}: {a.name} from {node.module}"
                       for path in (REPO / "wiloc").rglob("*.py")
                       for node in ast.walk(ast.parse(path.read_text()))
                       if isinstance(node, ast.ImportFrom) and (node.module or "").startswith("wiloc")
                       and node.module != "wiloc.errors" for a in node.names if a.name in errors)
    assert elsewhere == []



def test_the_package_is_typed() -> None:
    """Users' type checkers read wiloc's annotations only with the PEP 561 marker, which a wheel
    holds only when it is declared package data."""
    assert (REPO / "wiloc" / "py.typed").is_file()
    assert re.search(r'^wiloc = \[.*"py\.typed".*\]$', (REPO / "pyproject.toml").read_text(), re.MULTILINE)
