"""The README's Python snippets run as written (so the README cannot drift from the code), and
the package installs under the one import name `manus`."""

import pathlib
import re
import subprocess
import sys

import pytest

ROOT = pathlib.Path(__file__).resolve().parents[1]
README = (ROOT / "README.md").read_text()
SNIPPETS = re.findall(r"```python\n(.*?)```", README, flags=re.S)


def test_readme_has_snippets():
    assert len(SNIPPETS) >= 2


@pytest.mark.parametrize("code", SNIPPETS, ids=[f"snippet{i + 1}" for i in range(len(SNIPPETS))])
def test_readme_snippet_runs(code, tmp_path):
    # a fresh interpreter in another directory: only the installed `manus` is importable there
    out = subprocess.run([sys.executable, "-c", code], cwd=tmp_path, capture_output=True, text=True, timeout=300)
    assert out.returncode == 0, out.stderr[-2000:]


def test_one_import_name(tmp_path):
    """From outside the source tree, `manus.*` imports and the bare folder names do not."""
    code = (
        "import importlib.util, manus.estimators, manus.adaptive, manus.plants, manus.runs\n"
        "print([n for n in ('plants', 'estimators', 'adaptive', 'runs') if importlib.util.find_spec(n)])"
    )
    out = subprocess.run([sys.executable, "-c", code], cwd=tmp_path, capture_output=True, text=True, timeout=120)
    assert out.returncode == 0, out.stderr[-2000:]
    assert out.stdout.strip() == "[]"


def test_every_module_imports_outside_the_tree(tmp_path):
    """Every module of the package, and the `manus` command's list of commands, from another
    directory: a leftover import of a bare folder name (`runs.x`) would fail only there."""
    code = (
        "import pkgutil, importlib, manus, manus.plants, manus.estimators, manus.adaptive, manus.runs\n"
        "for pkg in (manus.plants, manus.estimators, manus.adaptive, manus.runs):\n"
        "    for m in pkgutil.walk_packages(pkg.__path__, pkg.__name__ + '.'):\n"
        "        importlib.import_module(m.name)\n"
        "from manus.runs.cli import commands\n"
        "print(len(commands()))"
    )
    out = subprocess.run([sys.executable, "-c", code], cwd=tmp_path, capture_output=True, text=True, timeout=300)
    assert out.returncode == 0, out.stderr[-2000:]
    assert int(out.stdout.split()[-1]) >= 10


def test_package_does_not_need_shared():
    """Nothing in the package refers to ../shared, except the demo's search for the EMPS file."""
    hits = [
        f"{p.relative_to(ROOT)}:{i + 1}"
        for d in ("plants", "estimators", "adaptive", "runs", "manus")
        for p in (ROOT / d).rglob("*.py")
        for i, line in enumerate(p.read_text().splitlines())
        if "shared" in line and ("../shared" in line or '"shared"' in line) and p.name != "cmd_demo.py"
    ]
    assert hits == []
    design = [
        str(p.relative_to(ROOT))
        for d in ("plants", "estimators", "adaptive", "runs", "manus")
        for p in (ROOT / d).rglob("*.py")
        if "DESIGN.md" in p.read_text()
    ]
    assert design == []
