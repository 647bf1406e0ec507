"""The package as installed: its import graph has no circle, and arrows point one way,
runs -> experiments -> adaptive -> estimators -> plants (docs/architecture.md).

Every `import` of a manus module counts, at module level or inside a function: an import moved
into a function to dodge a circle is still a circle."""

from __future__ import annotations

import ast
from pathlib import Path

import pytest

ROOT = Path(__file__).resolve().parents[1]
PACKAGES = ("plants", "estimators", "adaptive", "experiments", "runs")
LAYER = {"plants": 0, "estimators": 1, "adaptive": 2, "experiments": 3, "runs": 4}


def modules() -> dict[str, Path]:
    """Installed module name -> source file."""
    found = {}
    for top in PACKAGES:
        for path in sorted((ROOT / "manus" / top).rglob("*.py")):
            parts = list(path.relative_to(ROOT / "manus" / top).with_suffix("").parts)
            if parts[-1] == "__init__":
                parts = parts[:-1]
            found[".".join(["manus", top, *parts])] = path
    return found


def imports(name: str, path: Path, known: set[str]) -> set[str]:
    """The manus modules `name` imports (a `from package import module` names the module)."""
    package = name if path.name == "__init__.py" else name.rpartition(".")[0]
    out = set()
    for node in ast.walk(ast.parse(path.read_text(encoding="utf-8"))):
        if isinstance(node, ast.Import):
            out |= {a.name for a in node.names if a.name in known}
        elif isinstance(node, ast.ImportFrom):
            base = node.module or ""
            if node.level:
                base = ".".join(
                    package.split(".")[: len(package.split(".")) - node.level + 1] + ([base] if base else [])
                )
            for a in node.names:
                full = f"{base}.{a.name}"
                if full in known:
                    out.add(full)
                elif base in known:
                    out.add(base)
    out.discard(name)
    return out


def graph() -> dict[str, set[str]]:
    found = modules()
    return {name: imports(name, path, set(found)) for name, path in found.items()}


def layer(name: str) -> int:
    return LAYER[name.split(".")[1]]


def test_no_import_points_from_a_lower_layer_to_a_higher_one():
    wrong = [f"{a} imports {b}" for a, deps in graph().items() for b in deps if layer(b) > layer(a)]
    assert not wrong, "\n".join(wrong)


def test_the_import_graph_has_no_circle():
    g = graph()
    index, low, on, stack, circles = {}, {}, set(), [], []

    def visit(v):  # Tarjan's strongly connected components
        index[v] = low[v] = len(index)
        stack.append(v)
        on.add(v)
        for w in g[v]:
            if w not in index:
                visit(w)
                low[v] = min(low[v], low[w])
            elif w in on:
                low[v] = min(low[v], index[w])
        if low[v] == index[v]:
            component = []
            while True:
                w = stack.pop()
                on.discard(w)
                component.append(w)
                if w == v:
                    break
            if len(component) > 1:
                circles.append(sorted(component))

    for v in g:
        if v not in index:
            visit(v)
    assert not circles, "\n".join(" <-> ".join(c) for c in circles)


@pytest.mark.parametrize("top", PACKAGES)
def test_every_folder_of_modules_is_a_package(top):
    """setuptools installs the folders under manus/ that hold an `__init__.py`: one without is missing
    once installed."""
    for path in sorted((ROOT / "manus" / top).rglob("*.py")):
        assert (path.parent / "__init__.py").exists(), f"{path.parent} has modules but no __init__.py"
