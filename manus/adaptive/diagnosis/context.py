"""The context one diagnosis step judges its candidates in (`Context`): the prepared recording,
its columns, the model fitted, the held-out blocks and the levels."""

from __future__ import annotations

import threading
from collections.abc import Callable
from dataclasses import dataclass, field
from typing import TypeVar

import numpy as np

from manus.adaptive.identify.columns import Columns
from manus.adaptive.identify.lsq import Stats
from manus.adaptive.identify.prepare import Data
from manus.adaptive.identify.result import Fit, fit_rows
from manus.adaptive.identify.search import delay_of
from manus.plants.effects import Model, Span

T = TypeVar("T")
KEEP = 3  # statistics a context keeps (each holds its rows' columns)
_STATS_LOCK = threading.Lock()  # candidates are judged on threads (`verdict`): one computes statistics at a time


@dataclass(frozen=True, eq=False)
class Context:
    """What every candidate of one diagnosis step is judged in."""

    data: Data
    cols: Columns  # the effects' columns on `data`
    icols: Columns | None  # the instruments' columns where the model is fitted by IV, else None
    base: Fit  # the model, fitted on every row
    base_sse: np.ndarray  # (blocks,) its held-out squared errors
    starts: np.ndarray  # the first row of each segment of rows (`lsq.folds`)
    folds: list[tuple[np.ndarray, np.ndarray]]  # per held-out block, (train, test) masks over the segments
    span: Span  # what the effects' search spaces are derived from
    alpha: float  # the level each candidate is judged at (the step's, shared among its candidates)
    min_share: float  # the share of the recorded torque (RMS) a candidate must explain
    _stats: dict = field(init=False, repr=False, default_factory=dict)  # `stats` computed, by model and delay
    _kept: dict = field(init=False, repr=False, default_factory=dict)  # `once`'s answers

    @property
    def whole(self) -> np.ndarray:
        """Every segment (the fit on every row)."""
        return np.ones(self.starts.size, bool)

    @property
    def train(self) -> np.ndarray:
        """(blocks, segments): each block's training segments."""
        return np.array([train for train, _ in self.folds])

    @property
    def test(self) -> np.ndarray:
        """(blocks, segments): each block's own segments."""
        return np.array([test for _, test in self.folds])

    def fit(self, model: Model, held: tuple = ()) -> Fit:
        """`model` fitted on every row as the base model is (LS, or IV with its instruments);
        the parameters named in `held` held at 0 (`once`)."""
        return self.once(
            ("fit", model.spec, held), lambda: fit_rows(self.data, self.cols, model, None, self.icols, held)
        )

    def once(self, key: tuple, compute: Callable[[], T]) -> T:
        """`compute()` the first time `key` is asked for in this step, its answer after: the step asks
        some questions twice (a model holding the verdict and a rival is fitted and tested on top of
        each, to tell whether the verdict accounts for the rival, then whether it overlaps it)."""
        with _STATS_LOCK:
            if key in self._kept:
                return self._kept[key]
        answer = compute()
        with _STATS_LOCK:
            return self._kept.setdefault(key, answer)

    def stats(self, model: Model, delay: float | np.ndarray | None = None) -> Stats:
        """The least-squares statistics of `model` over the segments (its instruments' too with
        IV), the torque read `delay` late (default: the model's own, `delay_of`); the last few
        kept (every candidate of a step is judged on top of the same model)."""
        delay = delay_of(model) if delay is None else delay
        key = (model.spec, np.asarray(delay, float).tobytes())
        with _STATS_LOCK:
            if key not in self._stats:
                if len(self._stats) >= KEEP:
                    del self._stats[next(iter(self._stats))]
                z = None if self.icols is None else self.icols.model(model)
                self._stats[key] = Stats.of(self.cols.model(model), self.data.tau(delay), self.starts, z)
            return self._stats[key]

    def remember(self, model: Model, delay: float | np.ndarray, st: Stats) -> None:
        """`st` as `stats(model, delay)` (computed before this context)."""
        with _STATS_LOCK:
            self._stats[(model.spec, np.asarray(delay, float).tobytes())] = st
