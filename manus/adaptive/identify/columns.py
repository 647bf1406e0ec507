"""Regressor columns of a model's effects on a prepared recording, computed once per effect.

The model's regressor is the stack of its effects' columns (`manus.plants.effects`, ∂torque/∂θ),
so candidate models share the columns computed once (`Columns`, cached by effect spec). Each
column is evaluated on the kinematic band's q, q̇, q̈ on the working grid (`Data.work`: the full
rate, or every `stride`-th sample where the rate is far above the band), then low-passed at the
cut-off like the torque (`Data.smoothed`) and read on the used rows. IDIM-IV's instruments are the same
columns on the simulated motion (`Columns(data, kinematics=...)`).
"""

from __future__ import annotations

import contextlib
import functools
import threading
from collections.abc import Iterator, Sequence

import jax
import jax.numpy as jnp
import numpy as np

from manus.adaptive.identify.prepare import PREFETCH_BYTES, Data
from manus.estimators.offline import lowpass
from manus.plants.effects import Effect, Model
from manus.stored import stored_jit


def identified(structure):
    """The form of a structure that identification fits: a serial chain's base parameters, the
    others as they are."""
    return structure.identified_form()


@functools.lru_cache(maxsize=1)
def _pool():
    from concurrent.futures import ThreadPoolExecutor

    return ThreadPoolExecutor(2, thread_name_prefix="manus-columns")


SUBSAMPLES = 16  # points per sample period over which a friction column is averaged


def _columns_of(effect: Effect, structure, q, qd, qdd, dt):
    """One effect's columns at every sample of a grid of period `dt`. A friction effect switches
    with the sign of q̇, and near a reversal it does so within a sample period: what the recorded
    motion integrates over the period is the torque's average there, not its value at the sample
    (at 200 Hz a Stribeck hump a few milliseconds wide falls between samples or on one), and on a
    working grid coarser than the recording a step read at the grid's samples would alias into
    the band. Its columns are averaged over the period [t_k − T/2, t_k + T/2] along the motion
    q + q̇ s + q̈ s²/2 (`SUBSAMPLES` midpoints); smooth effects' columns are their values at the
    samples."""
    reg = jax.vmap(Model(structure, (effect,)).regressor)
    if not effect.dry or not dt > 0:
        return reg(q, qd, qdd)
    offsets = ((jnp.arange(SUBSAMPLES) + 0.5) / SUBSAMPLES - 0.5) * dt

    def add(total, s):
        return total + reg(q + qd * s + 0.5 * qdd * s**2, qd + qdd * s, qdd), None

    total, _ = jax.lax.scan(add, jnp.zeros(jax.eval_shape(reg, q, qd, qdd).shape), offsets)
    return total / SUBSAMPLES


effect_columns = stored_jit(_columns_of)


@stored_jit
def _batch_columns(effects: Effect, structure, q, qd, qdd, dt):
    """`effect_columns` of a stack of one effect's values (array fields with a leading axis)."""
    return jax.vmap(lambda e: _columns_of(e, structure, q, qd, qdd, dt))(effects)


class Columns:
    """Regressor columns of effects on prepared data, cached by effect spec. `kinematics` (q, q̇,
    q̈ at full rate) replaces the measured ones: the instruments of IDIM-IV are the same columns
    on the simulated motion. `rows`: other rows than the data's (on its working grid)."""

    def __init__(self, data: Data, rows: np.ndarray | None = None, kinematics: tuple | None = None):
        self.data = data
        self.structure = identified(data.rec.structure)
        self.rows = data.rows if rows is None else rows
        self.mask = None if data.mask is None or rows is not None else data.mask[:, :, None]  # stuck joints' equations
        self._plain = rows is not None  # (other rows than the data's, rests included: the plain low-pass)
        self._cache: dict[str, np.ndarray] = {}
        q, qd, qdd = kinematics if kinematics is not None else (data.q, data.qd, data.qdd)
        self._kin = (np.asarray(q), np.asarray(qd), np.asarray(qdd))
        self._args = tuple(jnp.asarray(data.work(x)) for x in self._kin)
        self._lists: dict[tuple[str, ...], threading.Lock] = {}  # one per list of effects `prefetch` is given
        self._guard = threading.Lock()

    def __getstate__(self) -> dict:
        """Pickled (a fit shipped to the figure worker) without its locks and its cache: where it
        is unpickled, the columns asked for are computed again."""
        return {**self.__dict__, "_cache": {}, "_lists": {}, "_guard": None}

    def __setstate__(self, state: dict) -> None:
        self.__dict__.update(state, _guard=threading.Lock())

    def smoothed(self, x: np.ndarray, at: np.ndarray) -> np.ndarray:
        """x on the working grid low-passed like the torque, on the samples `at`."""
        if self._plain:
            return lowpass(x, self.data.work_dt, self.data.cutoff_hz)[at // self.data.stride]
        return self.data.smoothed(x, at)

    def effect(self, e: Effect) -> np.ndarray:
        """(rows, n, p) columns of one linear effect, low-passed like the torque."""
        if e.spec not in self._cache:
            full = np.asarray(effect_columns(e, self.structure, *self._args, self.data.work_dt))
            self._cache[e.spec] = self._filtered(full[None])[0]
        return self._cache[e.spec]

    def _filtered(self, full: np.ndarray) -> np.ndarray:
        """Columns (V, W, n, p) on the working grid -> low-passed on the used rows (V, rows, n, p); the
        entries that are zero throughout (a joint's own parameter on another joint) not filtered."""
        on = np.any(full, axis=(0, 1))  # (n, p)
        out = np.zeros((full.shape[0], self.rows.size) + full.shape[2:])
        if on.any():
            low = self.smoothed(np.ascontiguousarray(np.moveaxis(full[:, :, on], 0, 1)), self.rows)  # (rows, V, m)
            out[:, :, on] = np.moveaxis(low, 1, 0)
        return out if self.mask is None else out * self.mask

    def prefetch(self, effects: Sequence[Effect], batch: int = 32) -> None:
        """The columns of many values of one effect (a search's grid: the same effect with other
        non-linear parameters, array fields) computed together: one compiled call and one
        filter pass per `batch` of them, fewer on a long recording (their columns held
        at once stay under `PREFETCH_BYTES`: a 20-minute recording is no reason to run out of memory).
        The same list asked for twice at once (`ahead`) is computed once, in the same batches."""
        with self._guard:
            lock = self._lists.setdefault(tuple(e.spec for e in effects), threading.Lock())
        with lock:
            self._prefetch(effects, batch)

    @contextlib.contextmanager
    def ahead(self, lists: Sequence[Sequence[Effect]]) -> Iterator[None]:
        """`prefetch` each of `lists` in turn on a thread of its own while the caller goes on
        inside the block (a diagnosis's candidates' columns while its model is fitted, on the
        core the fit leaves idle). A later `prefetch` of the same list finds its columns
        computed, or waits for them: the columns are those it would have computed itself, bit
        for bit. A block that fails stops the thread after the list it is computing."""
        stop = threading.Event()

        def work() -> None:
            for effects in lists:
                if stop.is_set():
                    return
                try:
                    self.prefetch(effects)
                except Exception:  # (the same prefetch asked for later meets the failure again and says it)
                    return

        thread = threading.Thread(target=work, name="manus-ahead", daemon=True)
        thread.start()
        try:
            yield
        except BaseException:
            stop.set()
            thread.join()
            raise

    def _prefetch(self, effects: Sequence[Effect], batch: int) -> None:
        todo = list({e.spec: e for e in effects if e.spec not in self._cache}.values())
        if todo:
            per_value = self._args[0].shape[0] * self.data.n_joints * max(len(todo[0].names(self.structure)), 1) * 8
            batch = int(np.clip(PREFETCH_BYTES // (2 * per_value), 1, batch))  # (two held at once)
            batch = min(batch, -(-len(todo) // 2))  # (at least two batches: two threads)

        def one(part):
            if len(part) == 1:
                return [self.effect(part[0])]
            stacked = jax.tree.map(lambda *xs: jnp.stack(xs), *part)
            return self._filtered(np.asarray(_batch_columns(stacked, self.structure, *self._args, self.data.work_dt)))

        parts = [todo[i : i + batch] for i in range(0, len(todo), batch)]
        # two batches at a time on two threads (JAX and the filter's loop release the GIL; each
        # value's columns are computed alone, so the result does not depend on the order)
        for part, low in zip(parts, _pool().map(one, parts) if len(parts) > 1 else map(one, parts), strict=True):
            for j, e in enumerate(part):
                self._cache[e.spec] = low[j]

    def screen(self, e: Effect) -> np.ndarray:
        """The columns of `e` on the used rows without the low-pass: a cheap stand-in to rank
        the many values of a grid search before the best few are evaluated exactly."""
        q, qd, qdd = (jnp.asarray(x[self.rows]) for x in self._kin)
        out = np.asarray(effect_columns(e, self.structure, q, qd, qdd, self.data.work_dt))
        return out if self.mask is None else out * self.mask

    def model(self, model: Model) -> np.ndarray:
        """(rows, n, P): the model's regressor, its effects' columns side by side."""
        blocks = [self.effect(e) for e in model.effects if e.linear]
        n = self.data.n_joints
        return np.concatenate(blocks, axis=2) if blocks else np.zeros((self.rows.size, n, 0))
