"""Compiled functions whose lowered program a new process reads instead of tracing (`manus.stored`)."""

import os
import subprocess
import sys

import equinox as eqx
import jax
import jax.numpy as jnp
import numpy as np
import pytest

from manus import stored

TRACES = []  # one entry per trace of `_chain` in this process


class _Spring(eqx.Module):
    k: float  # static (a Python float): part of the key
    x0: jax.Array  # an array: an argument of the program


def _chain(spring: _Spring, q, steps: int):
    TRACES.append(steps)
    for _ in range(steps):
        q = q + 0.01 * (-spring.k * (q - spring.x0) + jnp.sin(q))
    return q, jnp.sum(q**2)


@pytest.fixture
def cache(tmp_path, monkeypatch):
    """A folder of its own for the stored programs."""
    monkeypatch.setenv("MANUS_JAX_CACHE", str(tmp_path / "jax"))
    TRACES.clear()
    return tmp_path / "jax-exported"


@pytest.fixture
def chain():
    """`_chain` stored, as a new process has it (nothing held in memory)."""
    return stored.stored_jit(_chain)


def _plain(spring, q, steps):
    return eqx.filter_jit(_chain)(spring, q, steps)


def test_the_stored_program_gives_the_plain_result_to_the_last_bit_and_is_read_back(cache, chain):
    spring, q = _Spring(3.0, jnp.asarray(0.1)), np.linspace(0.0, 1.0, 5)
    first = chain(spring, q, 30)
    assert len(list(cache.iterdir())) == 1 and TRACES == [30]
    again = stored.Stored(_chain)  # (a new process's object: its memory empty, the folder kept)
    TRACES.clear()
    second = again(spring, q, 30)
    assert TRACES == []  # read from the folder, not traced
    reference = _plain(spring, q, 30)
    for a, b, c in zip(first, second, reference, strict=True):
        np.testing.assert_array_equal(np.asarray(a), np.asarray(c))
        np.testing.assert_array_equal(np.asarray(b), np.asarray(c))


def test_other_static_values_or_shapes_are_other_programs(cache, chain):
    spring, q = _Spring(3.0, jnp.asarray(0.1)), np.linspace(0.0, 1.0, 5)
    a = chain(spring, q, 30)[1]
    b = chain(_Spring(5.0, spring.x0), q, 30)[1]  # another static value
    c = chain(spring, np.linspace(0.0, 1.0, 6), 30)[1]  # another shape
    d = chain(spring, q, 31)[1]  # another static argument
    assert len(list(cache.iterdir())) == 4
    assert float(b) == float(_plain(_Spring(5.0, spring.x0), q, 30)[1]) != float(a)
    assert float(c) == float(_plain(spring, np.linspace(0.0, 1.0, 6), 30)[1])
    assert float(d) == float(_plain(spring, q, 31)[1])


def test_what_cannot_be_stored_is_the_plain_call(cache, chain, monkeypatch):
    class Local(float):  # (a class defined here does not pickle: no key)
        pass

    q = np.linspace(0.0, 1.0, 5)
    odd = _Spring(Local(3.0), jnp.asarray(0.0))
    assert float(chain(odd, q, 3)[1]) == float(_plain(odd, q, 3)[1])
    assert not cache.exists()
    spring = _Spring(3.0, jnp.asarray(0.0))
    batched = jax.vmap(lambda x: chain(spring, x, 3)[1])(jnp.ones((4, 5)))  # under vmap: its tracers are no key
    assert batched.shape == (4,) and not cache.exists()
    monkeypatch.setenv("MANUS_JAX_CACHE", "off")
    assert float(chain(spring, q, 3)[1]) == float(_plain(spring, q, 3)[1])
    assert not cache.exists()


def test_a_damaged_file_is_traced_again_and_replaced(cache, chain):
    spring, q = _Spring(3.0, jnp.asarray(0.0)), np.linspace(0.0, 1.0, 5)
    chain(spring, q, 30)
    (path,) = cache.iterdir()
    path.write_bytes(path.read_bytes()[:100])  # cut short
    TRACES.clear()
    out = stored.Stored(_chain)(spring, q, 30)
    assert TRACES == [30] and float(out[1]) == float(_plain(spring, q, 30)[1])
    assert stored.Stored._read(path, [jnp.asarray(0.0), jnp.asarray(q)]) is not None  # whole again


def test_the_folder_is_kept_under_its_limit_oldest_first(cache, chain, monkeypatch):
    spring, q = _Spring(3.0, jnp.asarray(0.0)), np.linspace(0.0, 1.0, 5)
    chain(spring, q, 10)
    size = next(cache.iterdir()).stat().st_size
    monkeypatch.setattr(stored, "LIMIT_BYTES", int(2.5 * size))
    for steps in (11, 12, 13):
        os.utime(next(iter(sorted(cache.iterdir(), key=lambda p: p.stat().st_mtime))), (0, 0))  # (oldest: clear)
        chain(spring, q, steps)
    assert sum(p.stat().st_size for p in cache.iterdir()) <= 2.5 * size
    assert len(list(cache.iterdir())) == 2


def _split(x):
    """sin(x)² of x (B, n), the rows split over two devices (`shard_map`)."""
    TRACES.append("split")
    P = jax.sharding.PartitionSpec
    mesh = jax.sharding.Mesh(np.array(jax.devices()[:2]), ("rows",))
    return jax.shard_map(lambda y: jnp.sin(y) ** 2, mesh=mesh, in_specs=P("rows"), out_specs=P("rows"))(x)


def test_a_program_split_over_devices_is_read_back_and_run_on_them(cache):
    if len(jax.devices()) < 2:
        pytest.skip("one device: nothing to split over")
    x = np.linspace(0.0, 3.0, 12).reshape(6, 2)
    first = stored.stored_jit(_split)(x)
    assert len(list(cache.iterdir())) == 1
    TRACES.clear()
    again = stored.stored_jit(_split)(x)
    assert TRACES == [] and again.sharding.num_devices == 2  # read back, not traced; run on both devices
    np.testing.assert_array_equal(np.asarray(again), np.asarray(first))
    np.testing.assert_allclose(np.asarray(first), np.sin(x) ** 2, rtol=1e-15)


PROGRAM = """
import numpy as np
import manus
from manus.plants.catalog import structure_named
from manus.plants.effects import Model
from manus.adaptive.identify.columns import effect_columns
q, qd, qdd = np.random.default_rng(0).normal(size=(3, 200, 2))
m = Model(structure_named("manus2", 2), "rigid,viscous,coulomb")
print(repr(np.asarray(effect_columns(m.get("coulomb"), m.structure, q, qd, qdd, 1e-3)).sum()))
"""


def test_a_new_process_reads_what_an_earlier_one_traced(tmp_path):
    env = {**os.environ, "MANUS_JAX_CACHE": str(tmp_path / "jax"), "JAX_LOG_COMPILES": "1"}
    run = lambda: subprocess.run([sys.executable, "-c", PROGRAM], env=env, capture_output=True, text=True, check=True)
    first = run()
    assert "Finished tracing _columns_of" in first.stderr
    second = run()
    assert "Finished tracing _columns_of" not in second.stderr  # read, not traced
    assert second.stdout.split()[0] == first.stdout.split()[0]


ON_DEVICES = """
import numpy as np
import manus
import jax, jax.numpy as jnp
from manus.stored import stored_jit
def split(x):
    d = jax.devices()
    if len(d) < 2:
        return jnp.sin(x) ** 2
    P = jax.sharding.PartitionSpec
    mesh = jax.sharding.Mesh(np.array(d[:2]), ("rows",))
    return jax.shard_map(lambda y: jnp.sin(y) ** 2, mesh=mesh, in_specs=P("rows"), out_specs=P("rows"))(x)
print(len(jax.devices()), repr(float(stored_jit(split)(np.linspace(0.0, 3.0, 12).reshape(6, 2)).sum())))
"""


def test_a_process_with_other_devices_traces_its_own_program(tmp_path):
    env = {**os.environ, "MANUS_JAX_CACHE": str(tmp_path / "jax")}
    run = lambda **extra: subprocess.run(
        [sys.executable, "-c", ON_DEVICES], env={**env, **extra}, capture_output=True, text=True, check=True
    ).stdout.split()
    two = run(XLA_FLAGS="--xla_force_host_platform_device_count=2")
    one = run(XLA_FLAGS="--xla_force_host_platform_device_count=1")  # (the two-device program is not its own)
    assert two[0] == "2" and one[0] == "1" and float(one[1]) == pytest.approx(float(two[1]), rel=1e-14)
    assert len(list((tmp_path / "jax-exported").iterdir())) == 2
