"""The code's shape: no import cycles among the project's modules, no long functions."""

from __future__ import annotations

import ast
from pathlib import Path

from repo_paths import REPO

PACKAGES = {"ngpm_compiler": REPO / "ngpm_compiler",
            "ngpm_runtime": REPO / "runtime" / "ngpm_runtime"}
MAX_LINES = 80  # a longer function says why in its docstring ("Long because ...")
# smc() is being split into readable parts on the speed branch (issue #10)
def modules() -> dict[str, Path]:
    out = {}
    for pkg, root in PACKAGES.items():
        for path in sorted(root.rglob("*.py")):
            parts = [pkg, *path.relative_to(root).with_suffix("").parts]
            if parts[-1] == "__init__":
                parts.pop()
            out[".".join(parts)] = path
    return out


def imports(name: str, path: Path, known: set[str]) -> set[str]:
    """Project modules `name` imports, at any depth (lazy imports in functions count)."""
    found = set()
    for node in ast.walk(ast.parse(path.read_text(encoding="utf-8"))):
        if isinstance(node, ast.Import):
            targets = [a.name for a in node.names]
        elif isinstance(node, ast.ImportFrom) and node.module and node.level == 0:
            targets = [node.module] + [f"{node.module}.{a.name}" for a in node.names]
        else:
            continue
        for t in targets:
            while t and t not in known:
                t = t.rpartition(".")[0]
            if t and t != name and not name.startswith(t + "."):  # a parent package
                found.add(t)
    return found


def test_no_import_cycles() -> None:
    mods = modules()
    graph = {m: imports(m, p, set(mods)) for m, p in mods.items()}
    # packages' __init__ modules import their children; only module-to-module edges matter
    state: dict[str, int] = {}
    stack: list[str] = []
    cycles: list[list[str]] = []

    def visit(m: str) -> None:
        state[m] = 1
        stack.append(m)
        for n in sorted(graph[m]):
            if state.get(n) == 1:
                cycles.append(stack[stack.index(n):] + [n])
            elif n not in state:
                visit(n)
        stack.pop()
        state[m] = 2

    for m in sorted(graph):
        if m not in state:
            visit(m)
    assert not cycles, "\n".join(" -> ".join(c) for c in cycles)


def test_runtime_never_imports_the_compiler() -> None:
    mods = modules()
    for m, p in mods.items():
        if m.startswith("ngpm_runtime"):
            assert not any(i.startswith("ngpm_compiler") for i in imports(m, p, set(mods))), m


def test_functions_are_short_or_say_why() -> None:
    long = []
    for m, path in modules().items():
        for node in ast.walk(ast.parse(path.read_text(encoding="utf-8"))):
            if isinstance(node, (ast.FunctionDef, ast.AsyncFunctionDef)):
                lines = node.end_lineno - node.lineno + 1
                doc = ast.get_docstring(node) or ""
                if lines > MAX_LINES and "Long because" not in doc:
                    long.append(f"{m}.{node.name}: {lines} lines")
    assert not long, "\n".join(long)
