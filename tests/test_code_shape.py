"""The shape of the code: the commands stay thin and every module fits in a head."""

from __future__ import annotations

import ast
from pathlib import Path

import mdvae_cli

PACKAGE = Path(mdvae_cli.__file__).parent
#: the most lines a function of ``cli/`` may have (def line to last line)
MAX_CLI_FUNCTION = 80
#: the most lines a module of the package may have
MAX_MODULE = 400


def functions(path: Path) -> list[tuple[str, int]]:
    """Every function (nested ones too) in ``path`` with its length in lines."""
    tree = ast.parse(path.read_text(encoding="utf-8"))
    return [
        (f"{path.name}:{node.name}", node.end_lineno - node.lineno + 1)
        for node in ast.walk(tree)
        if isinstance(node, ast.FunctionDef | ast.AsyncFunctionDef)
    ]


def test_the_length_counts_def_to_last_line(tmp_path):
    (tmp_path / "m.py").write_text("def f(\n    a,\n):\n    x = 1\n\n    return x\n")
    assert functions(tmp_path / "m.py") == [("m.py:f", 6)]


def test_no_function_in_cli_is_over_80_lines():
    found = [f for p in sorted((PACKAGE / "cli").glob("*.py")) for f in functions(p)]
    assert len(found) > 50  # the walk sees the commands
    long = [(name, n) for name, n in found if n > MAX_CLI_FUNCTION]
    assert long == []


def test_no_module_in_the_package_is_over_400_lines():
    modules = sorted(PACKAGE.rglob("*.py"))
    assert len(modules) > 100
    lines = {str(p.relative_to(PACKAGE)): len(p.read_text(encoding="utf-8").splitlines())
             for p in modules}  # fmt: skip
    assert {name: n for name, n in lines.items() if n > MAX_MODULE} == {}


def module_imports(path: Path) -> set[str]:
    """The package's modules ``path`` imports at its top level (not inside functions)."""
    tree = ast.parse(path.read_text(encoding="utf-8"))
    found = set()
    for node in tree.body:
        if isinstance(node, ast.ImportFrom) and node.module and node.module.startswith("mdvae_cli"):
            found |= {f"{node.module}.{a.name}" for a in node.names} | {node.module}
        elif isinstance(node, ast.Import):
            found |= {a.name for a in node.names if a.name.startswith("mdvae_cli")}
    return found


def test_no_module_imports_itself_round_a_circle():
    names = {
        ".".join(("mdvae_cli", *p.relative_to(PACKAGE).with_suffix("").parts)).removesuffix(
            ".__init__"
        ): p
        for p in PACKAGE.rglob("*.py")
    }
    graph = {m: sorted(module_imports(p) & set(names) - {m}) for m, p in names.items()}
    state: dict[str, int] = {}  # 1: on the path, 2: done

    def visit(m: str, path: list[str]) -> list[str] | None:
        state[m] = 1
        for n in graph[m]:
            if state.get(n) == 1:
                return [*path, m, n]
            if n not in state and (cycle := visit(n, [*path, m])):
                return cycle
        state[m] = 2
        return None

    cycles = [c for m in sorted(graph) if m not in state and (c := visit(m, []))]
    assert cycles == []
