"""A tree of links that spells the installed package for pyright: `.venv/typing/manus/plants` ->
`plants/`, and so on for every package one level below `manus` in pyproject.toml's `package-dir`.

The editable install maps `manus.plants` to `plants/` with an import hook, which a static type
checker cannot follow; pyright finds the package through this tree (`extraPaths`). The links are
to directories, so new modules need no new link. `make setup` runs it.
"""

import pathlib
import tomllib

ROOT = pathlib.Path(__file__).resolve().parents[1]
TREE = ROOT / ".venv" / "typing" / "manus"

dirs = tomllib.loads((ROOT / "pyproject.toml").read_text())["tool"]["setuptools"]["package-dir"]
TREE.mkdir(parents=True, exist_ok=True)
for old in TREE.iterdir():
    old.unlink()
(TREE / "__init__.py").symlink_to(ROOT / dirs["manus"] / "__init__.py")
for name, path in dirs.items():
    if name.count(".") == 1:
        (TREE / name.split(".")[1]).symlink_to(ROOT / path, target_is_directory=True)
