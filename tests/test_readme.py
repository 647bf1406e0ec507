"""The README is a newcomer's page that cannot drift from the code: its Python snippets run as
written, every command it names exists, every page it links is there, and it stays short and free
of history. The package installs under the one import name `manus`."""

import pathlib
import re
import subprocess
import sys

import pytest

ROOT = pathlib.Path(__file__).resolve().parents[1]
README = (ROOT / "README.md").read_text()
SNIPPETS = re.findall(r"```python\n(.*?)```", README, flags=re.S)
PACKAGES = ("plants", "estimators", "adaptive", "experiments", "runs")


def test_readme_opens_with_the_two_commands_and_stays_short():
    head = "\n".join(README.splitlines()[:40])
    assert "make demo" in head and "make test" in head
    assert len(README.splitlines()) <= 250


def test_readme_carries_no_history():
    """Measured results live in docs/ and history in git log; the README states what is."""
    history = re.compile(r"this stop|stop \d+|this round|measured and not adopted|previous stop|before:", re.I)
    assert history.findall(README) == []


def test_readme_links_resolve_and_reach_every_doc():
    links = re.findall(r"\]\(([^)#]+)\)", README)
    assert [link for link in links if not link.startswith("http") and not (ROOT / link).exists()] == []
    docs = {f"docs/{p.name}" for p in (ROOT / "docs").glob("*.md") if p.name != "README.md"}
    assert docs - set(links) == set()


def test_readme_names_only_real_commands():
    from manus.runs.cli import commands

    named = set(re.findall(r"^\$? ?manus ([a-z][a-z-]*)", README, flags=re.M))
    assert named >= {"demo", "fit", "diagnose", "discover", "estimators", "simulate", "converge"}
    assert named - set(commands()) == set()


def test_readme_has_snippets():
    assert len(SNIPPETS) >= 2


@pytest.mark.parametrize("code", SNIPPETS, ids=[f"snippet{i + 1}" for i in range(len(SNIPPETS))])
def test_readme_snippet_runs(code, tmp_path):
    # a fresh interpreter in another directory: only the installed `manus` is importable there
    if "rec.csv" in code:  # the recording the README's five minutes make
        made = re.search(r"`(manus simulate [^`]*--out rec\.csv)`", README)
        assert made, "the README says how rec.csv is made"
        argv = [sys.executable, "-m", "manus.runs.cli", *made.group(1).split()[1:]]
        subprocess.run(argv, cwd=tmp_path, capture_output=True, check=True, timeout=300)
    out = subprocess.run([sys.executable, "-c", code], cwd=tmp_path, capture_output=True, text=True, timeout=300)
    assert out.returncode == 0, out.stderr[-2000:]


def test_one_import_name(tmp_path):
    """From outside the source tree, `manus.*` imports and the bare folder names do not."""
    code = (
        f"import importlib, importlib.util\n"
        f"for n in {PACKAGES!r}: importlib.import_module('manus.' + n)\n"
        f"print([n for n in {PACKAGES!r} if importlib.util.find_spec(n)])"
    )
    out = subprocess.run([sys.executable, "-c", code], cwd=tmp_path, capture_output=True, text=True, timeout=120)
    assert out.returncode == 0, out.stderr[-2000:]
    assert out.stdout.strip() == "[]"


def test_version_is_the_installed_one(tmp_path):
    code = "import importlib.metadata, manus; print(manus.__version__ == importlib.metadata.version('manus'))"
    out = subprocess.run([sys.executable, "-c", code], cwd=tmp_path, capture_output=True, text=True, timeout=120)
    assert out.returncode == 0, out.stderr[-2000:]
    assert out.stdout.strip() == "True"


def test_every_module_imports_outside_the_tree(tmp_path):
    """Every module of the package, and the `manus` command's list of commands, from another
    directory: a leftover import of a bare folder name (`runs.x`) would fail only there."""
    code = (
        f"import pkgutil, importlib\n"
        f"for n in {PACKAGES!r}:\n"
        f"    pkg = importlib.import_module('manus.' + n)\n"
        f"    for m in pkgutil.walk_packages(pkg.__path__, pkg.__name__ + '.'):\n"
        f"        importlib.import_module(m.name)\n"
        f"from manus.runs.cli import commands\n"
        f"print(len(commands()))"
    )
    out = subprocess.run([sys.executable, "-c", code], cwd=tmp_path, capture_output=True, text=True, timeout=300)
    assert out.returncode == 0, out.stderr[-2000:]
    assert int(out.stdout.split()[-1]) >= 10


def test_package_does_not_need_shared():
    """Nothing in the package refers to ../shared, except the demo's search for the EMPS file."""
    sources = sorted((ROOT / "manus").rglob("*.py"))
    hits = [
        f"{p.relative_to(ROOT)}:{i + 1}"
        for p in sources
        for i, line in enumerate(p.read_text().splitlines())
        if "shared" in line and ("../shared" in line or '"shared"' in line) and p.name != "cmd_demo.py"
    ]
    assert hits == []
    assert [str(p.relative_to(ROOT)) for p in sources if "DESIGN.md" in p.read_text()] == []
