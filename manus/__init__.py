"""manus: adaptive control of interactive robots in JAX.

One import name for the whole framework. The source tree keeps its packages at the top
(`plants/`, `estimators/`, `adaptive/`, `runs/`); the build maps them into this package
(`pyproject.toml`, setuptools `package-dir`), so they are imported as `manus.plants`,
`manus.estimators`, `manus.adaptive` and `manus.runs`. See `docs/architecture.md`.
"""

from importlib.metadata import PackageNotFoundError, version

try:
    __version__ = version("manus")
except PackageNotFoundError:  # a source tree that was never installed
    __version__ = "0+unknown"
