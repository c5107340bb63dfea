"""The code's shape: no import cycles among the project's modules, the compiler's packages
importing only downward, no long functions. `python tests/test_layout.py` (or
`pytest -s tests/test_layout.py`) prints the package graph."""

from __future__ import annotations

import ast
import re
from pathlib import Path

from repo_paths import REPO

PACKAGES = {
    "ngpm_compiler": REPO / "ngpm_compiler",
    "ngpm_runtime": REPO / "runtime" / "ngpm_runtime",
}
# The compiler's packages (and top-level modules), lowest first: each imports only those before
# it (and the runtime), so no package cycle can form. A new package gets its place here.
PACKAGE_ORDER = (
    "language",
    "datasets",
    "progress",
    "jobs",
    "evaluation",
    "learning",
    "experiments",
    "web",
    "cli",
)
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
                cycles.append(stack[stack.index(n) :] + [n])
            elif n not in state:
                visit(n)
        stack.pop()
        state[m] = 2

    for m in sorted(graph):
        if m not in state:
            visit(m)
    assert not cycles, "\n".join(" -> ".join(c) for c in cycles)


def package_of(module: str) -> str | None:
    """The compiler package (or top-level module) a module belongs to; "ngpm_runtime" for
    the runtime; None for `ngpm_compiler` itself (its API names import lazily, by string)."""
    parts = module.split(".")
    if parts[0] != "ngpm_compiler":
        return parts[0]
    return parts[1] if len(parts) > 1 else None


def package_graph() -> dict[str, dict[str, list[str]]]:
    """Compiler package -> package it imports -> the module imports behind that edge."""
    mods = modules()
    graph: dict[str, dict[str, list[str]]] = {}
    for m, path in mods.items():
        src = package_of(m)
        if not m.startswith("ngpm_compiler") or src is None:
            continue
        graph.setdefault(src, {})
        for target in sorted(imports(m, path, set(mods))):
            dst = package_of(target)
            if dst is not None and dst != src:
                graph[src].setdefault(dst, []).append(f"{m} -> {target}")
    return graph


def format_graph(graph: dict[str, dict[str, list[str]]]) -> str:
    """One line per package: what it imports, with the number of module imports behind each."""
    return "\n".join(
        f"{src} -> "
        + ", ".join(f"{dst} ({len(edges)})" for dst, edges in sorted(graph[src].items()))
        for src in sorted(graph)
    )


def test_packages_import_only_downward() -> None:
    graph = package_graph()
    print("\n" + format_graph(graph))
    unplaced = sorted(p for p in graph if p not in PACKAGE_ORDER)
    assert not unplaced, f"packages missing from PACKAGE_ORDER: {unplaced}"
    upward = [
        edge
        for src, dsts in graph.items()
        for dst, edges in dsts.items()
        if dst != "ngpm_runtime"
        and (dst not in PACKAGE_ORDER or PACKAGE_ORDER.index(dst) > PACKAGE_ORDER.index(src))
        for edge in edges
    ]
    assert not upward, "imports against PACKAGE_ORDER:\n" + "\n".join(upward)


def test_pyproject_ships_every_package() -> None:
    text = (REPO / "pyproject.toml").read_text(encoding="utf-8")  # no tomllib on 3.10
    block = re.search(r"^packages = \[(.*?)\]", text, re.M | re.S)
    assert block, "pyproject.toml: no 'packages = [...]' list"
    listed = set(re.findall(r'"([\w.]+)"', block.group(1)))
    found = {m for m, path in modules().items() if path.name == "__init__.py"}
    assert found <= listed, f"not in pyproject's packages: {sorted(found - listed)}"


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


if __name__ == "__main__":
    print(format_graph(package_graph()))
