"""JAX's persistent compilation cache as importing manus sets it up (`config._compilation_cache`)."""

import os
import subprocess
import sys
from types import SimpleNamespace

from manus import config

# a computation whose compilation takes well over `CACHE_MIN_COMPILE_S`: 400 scalar steps unrolled
PROGRAM = """
import sys
from manus.config import configure
configure()
import jax, jax.numpy as jnp
def f(x):
    for k in range(400):
        x = jnp.sin(x * 1.0001 + k) + jnp.cos(x)
    return x
print(repr(float(jax.jit(f)(jnp.float64(0.3)))))
"""


def _fake_jax():
    updates = {}
    return SimpleNamespace(config=SimpleNamespace(update=lambda k, v: updates.__setitem__(k, v))), updates


def test_the_cache_folder_follows_the_environment(tmp_path, monkeypatch):
    jax, updates = _fake_jax()
    monkeypatch.delenv("MANUS_JAX_CACHE", raising=False)
    monkeypatch.setenv("XDG_CACHE_HOME", str(tmp_path / "xdg"))
    config._compilation_cache(jax)
    assert updates["jax_compilation_cache_dir"] == str(tmp_path / "xdg" / "manus" / "jax")
    assert (tmp_path / "xdg" / "manus" / "jax").is_dir()
    monkeypatch.setenv("MANUS_JAX_CACHE", str(tmp_path / "mine"))
    config._compilation_cache(jax)
    assert updates["jax_compilation_cache_dir"] == str(tmp_path / "mine")
    jax, updates = _fake_jax()
    monkeypatch.setenv("MANUS_JAX_CACHE", "off")
    config._compilation_cache(jax)
    assert updates == {}
    (tmp_path / "file").write_text("")
    monkeypatch.setenv("MANUS_JAX_CACHE", str(tmp_path / "file" / "jax"))  # cannot be made: no cache, no error
    config._compilation_cache(jax)
    assert updates == {}


def test_a_new_process_reads_what_an_earlier_one_compiled(tmp_path):
    env = {**os.environ, "MANUS_JAX_CACHE": str(tmp_path), "JAX_LOG_COMPILES": "1"}  # (hits logged on stderr)
    run = lambda: subprocess.run([sys.executable, "-c", PROGRAM], env=env, capture_output=True, text=True, check=True)
    first = run()
    assert any(p.name.startswith("jit_f-") for p in tmp_path.iterdir())
    assert "cache hit for 'jit_f'" not in first.stderr
    second = run()
    assert "cache hit for 'jit_f'" in second.stderr and second.stdout == first.stdout
