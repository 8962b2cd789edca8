"""The package structure docs/architecture.md promises: imports flow one way, no import loops,
no module grows past the size a reader can hold without a stated reason."""

import ast
from pathlib import Path

import pytest

ROOT = Path(__file__).resolve().parents[1]
PACKAGES = ("tracer", "worker", "cluster", "api", "cli")
MAX_LINES = 600
LONG_MODULES: dict[str, str] = {
    "tracer/geometry/bvh.py": "one tree: the builder and the traversal layout it converts into, "
    "whose invariants the builder establishes (2% over)",
}
"""Modules allowed past ``MAX_LINES``, each with its reason."""

MAY_IMPORT = {
    "tracer": {"tracer"},
    "worker": {"worker", "tracer"},
    "cluster": {"cluster", "worker", "tracer"},
    "api": {"api", "cluster", "worker", "tracer"},
    "cli": {"cli", "api", "cluster", "worker", "tracer"},
}
"""Which of our packages each package may import (``api -> cluster -> worker -> tracer``)."""

FOREIGN = {"tracer": {"ray", "fastapi", "starlette", "uvicorn", "httpx", "requests"}}
"""Libraries a package must not import: tracer/ knows nothing of Ray, HTTP or processes."""


def module_name(path: Path) -> str:
    parts = path.relative_to(ROOT).with_suffix("").parts
    return ".".join(parts[:-1] if parts[-1] == "__init__" else parts)


def modules() -> dict[str, Path]:
    return {
        module_name(path): path
        for package in PACKAGES
        for path in sorted((ROOT / package).rglob("*.py"))
    }


def imports_of(name: str, path: Path) -> set[str]:
    """Every module ``path`` imports, at any depth of the file (lazy imports count)."""
    package = name if path.name == "__init__.py" else name.rpartition(".")[0]
    found = set()
    for node in ast.walk(ast.parse(path.read_text(encoding="utf-8"))):
        if isinstance(node, ast.Import):
            found.update(alias.name for alias in node.names)
        elif isinstance(node, ast.ImportFrom):
            base = node.module or ""
            if node.level:
                anchor = package.split(".")[: len(package.split(".")) - node.level + 1]
                base = ".".join([*anchor, base] if base else anchor)
            found.add(base)
            found.update(f"{base}.{alias.name}" for alias in node.names)
    return found


@pytest.fixture(scope="module")
def graph() -> dict[str, set[str]]:
    """Our modules and the modules of ours each one imports."""
    ours = modules()
    return {
        name: {target for target in imports_of(name, path) if target in ours and target != name}
        for name, path in ours.items()
    }


def test_imports_flow_one_way():
    """No package imports a package above it, and tracer/ imports no Ray or HTTP library."""
    wrong = []
    for name, path in modules().items():
        package = name.split(".")[0]
        for target in imports_of(name, path):
            top = target.split(".")[0]
            if top in PACKAGES and top not in MAY_IMPORT[package]:
                wrong.append(f"{name} imports {target}")
            if top in FOREIGN.get(package, ()):
                wrong.append(f"{name} imports {target}")
    assert not wrong, wrong


def test_no_import_loops(graph):
    """No module reaches itself through the modules it imports (lazy imports included; a
    package's ``__init__`` counts as its modules' importer only where it imports them)."""
    index, low, stack, on_stack, loops = {}, {}, [], set(), []

    def visit(node: str) -> None:  # Tarjan's strongly connected components
        index[node] = low[node] = len(index)
        stack.append(node)
        on_stack.add(node)
        for target in graph[node]:
            if target not in index:
                visit(target)
                low[node] = min(low[node], low[target])
            elif target in on_stack:
                low[node] = min(low[node], index[target])
        if low[node] == index[node]:
            component = []
            while True:
                member = stack.pop()
                on_stack.discard(member)
                component.append(member)
                if member == node:
                    break
            if len(component) > 1:
                loops.append(sorted(component))

    for node in sorted(graph):
        if node not in index:
            visit(node)
    assert not loops, f"import loops: {loops}"


def test_modules_stay_small():
    """No module past MAX_LINES lines unless LONG_MODULES says why."""
    long = {
        path.relative_to(ROOT).as_posix(): len(path.read_text(encoding="utf-8").splitlines())
        for path in modules().values()
    }
    over = {path: n for path, n in long.items() if n > MAX_LINES and path not in LONG_MODULES}
    assert not over, f"modules over {MAX_LINES} lines without a reason in LONG_MODULES: {over}"
    stale = [path for path in LONG_MODULES if long.get(path, 0) <= MAX_LINES]
    assert not stale, f"LONG_MODULES lists modules that are short now: {stale}"
