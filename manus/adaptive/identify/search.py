"""The search of an effect's non-linear parameter (a cogging order, a delay, a Stribeck velocity)
over the space the effect derives from the recording (`Effect.space`): every grid value's
least-squares statistics on the same row segments (`manus.adaptive.identify.lsq.Stats`), so that
the full fit and each held-out fold of `diagnose` can choose their own value on the rows they
see. Long grids are ranked first on unfiltered columns and only the best few evaluated exactly.
`search_all` searches each of a model's effects in turn, the others held."""

from __future__ import annotations

from collections.abc import Callable, Sequence
from dataclasses import dataclass

import numpy as np

from manus.adaptive.identify import lsq
from manus.adaptive.identify.columns import Columns
from manus.adaptive.identify.prepare import Data
from manus.plants.effects import Delay, Effect, Model


def delay_of(model: Model) -> float | np.ndarray:
    """The command delay a model assumes [s]: its timing effect's (one number, or one per
    joint when the delay differs between joints), 0 without one."""
    e = next((e for e in model.effects if e.timing), None)
    if e is None:
        return 0.0
    assert isinstance(e, Delay)  # the vocabulary's one timing effect
    return e.per_joint(model.n_joints) if isinstance(e.seconds, tuple) else float(e.seconds)


Stats = lsq.Stats | lsq.Appended  # a grid value's statistics

SCREEN_ABOVE = 24  # grids longer than this are ranked on unfiltered columns first
SCREEN_KEEP = 3  # ... and this many best are evaluated exactly


@dataclass
class Grid:
    """One effect's non-linear parameter searched over its space, every grid value's statistics
    on the same segments (so a fold can choose its own value on its training segments)."""

    values: list  # the effect at each grid value
    stats: list[Stats | None]  # the rest of the model plus that value (exact columns), or None until needed
    screen: list[lsq.Appended] | None  # on unfiltered columns (long grids), else None
    build: Callable[[int], Stats] | None  # value index -> exact statistics
    lower: np.ndarray | None = None  # each column's lower bound (the effect's physical ones; −inf: none)
    own: np.ndarray | None = None  # which columns are the effect's (a mask: the last ones)
    every: lsq.Appended | None = None  # every value's exact statistics at once (a leading axis), when built together

    def exact(self, i: int) -> Stats:
        """Value i's exact statistics (built on first use)."""
        st = self.stats[i]
        if st is None:
            if self.every is not None:
                st = self.every.one(i)
            else:
                assert self.build is not None, "a grid without statistics builds them"
                st = self.build(i)
            self.stats[i] = st
        return st

    def choose(self, use: np.ndarray) -> tuple[int, np.ndarray]:
        """The value with the least squared error on the segments `use` (those a fit sees), and
        every value's error there (inf where not evaluated exactly). Each value is fitted within
        its effect's physical bounds: a value is chosen for what it explains as the physics
        allows (a Stribeck velocity where the fitted static friction falls below the Coulomb
        level is no Stribeck velocity), not for a term of the wrong sign."""
        best, errs = self.choose_each(use[None])
        return int(best[0]), errs[0]

    def choose_each(self, masks: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
        """`choose` for each of the segment masks (F, S) at once (each fold of a held-out test
        chooses on its own training segments): the best value per mask (F,) and the errors (F, V)."""
        F, V = masks.shape[0], len(self.values)
        if self.every is not None:
            errs = self.every.sses(self.every.coefs(masks, self.lower), masks).T
            return np.argmin(errs, axis=1), errs
        errs = np.full((F, V), np.inf)
        if self.screen is not None and any(st is None for st in self.stats):  # (once all are built: exact)
            rough = np.stack([st.sses(st.coefs(masks, self.lower), masks) for st in self.screen], 1)  # (F, V)
            keep = np.zeros((F, V), bool)
            np.put_along_axis(keep, np.argsort(rough, axis=1)[:, :SCREEN_KEEP], True, axis=1)
        else:
            keep = np.ones((F, V), bool)
        for i in np.flatnonzero(keep.any(0)):
            st, on = self.exact(int(i)), keep[:, i]
            errs[on, i] = st.sses(st.coefs(masks[on], self.lower), masks[on])
        return np.argmin(errs, axis=1), errs

    def held_out(self, train: np.ndarray, test: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
        """For each held-out block (its training segments `train` and its own `test`, (F, S)
        each): the value chosen on its training segments (`choose_each`), and the squared error
        on its own segments of that value's fit on its training ones, within the bounds (F,)."""
        if self.every is not None:  # (every value's fits on the training segments at once)
            C = self.every.coefs(train, self.lower)  # (V, F, P)
            chosen = np.argmin(self.every.sses(C, train), axis=0)
            return chosen, self.every.sses(C, test)[chosen, np.arange(train.shape[0])]
        chosen, _ = self.choose_each(train)
        sse = np.zeros(train.shape[0])
        for i in np.unique(chosen):
            st, on = self.exact(int(i)), chosen == i
            sse[on] = st.sses(st.coefs(train[on], self.lower), test[on])
        return chosen, sse

    def free(self, use: np.ndarray) -> np.ndarray:
        """Per value (V,): does its fit on the segments `use`, within the bounds, leave any of
        the effect's own columns off its bound? A value whose every column is
        held there adds nothing physical."""
        if self.lower is None or not np.isfinite(self.lower[self.own]).any():
            return np.ones(len(self.values), bool)
        if self.every is not None:
            coefs = self.every.coefs(use[None], self.lower)[:, 0]
            return np.any((coefs > self.lower * self.every.scale)[:, self.own], axis=1)
        out = np.zeros(len(self.values), bool)
        for i in range(len(self.values)):
            st = self.exact(i)
            c = st.coefs(use[None], self.lower)[0]
            out[i] = bool(np.any(c[self.own] > (self.lower * st.scale)[self.own]))
        return out


def grid(
    data: Data,
    cols: Columns,
    rest: Model,
    effect: Effect,
    starts: np.ndarray,
    values: Sequence[Effect] | None = None,
    icols: Columns | None = None,
    keep: np.ndarray | None = None,
    exact: bool = False,
    base: lsq.Stats | None = None,
) -> Grid:
    """The grid search of `effect`'s non-linear parameter on top of `rest` (see `Grid`): a linear
    effect changes the columns, a timing effect the torque. `icols`: instruments (IV). `keep`: a
    mask over the effect's columns (the others held at 0, their physical bound). `exact`: every
    value's statistics built now, their columns computed together (no screening). `base`: the
    statistics of `rest` on these segments where they are at hand (its instruments' too with IV)."""
    vals: list[Effect] = list(values if values is not None else effect.space(data.span().of(effect)))
    src: Columns | _Kept = cols if keep is None else _Kept(cols, keep)
    isrc: Columns | _Kept | None = icols if keep is None or icols is None else _Kept(icols, keep)
    delay = delay_of(rest)
    Y = src.model(rest)
    if base is None:
        base = lsq.Stats.of(Y, data.tau(delay), starts, isrc.model(rest) if isrc is not None else None)
    st = base
    if effect.timing:  # (a delay's value moves the torque only)
        build = lambda i: st.retimed(data.tau(_timing(vals[i], rest, delay)))
        return Grid(vals, [None] * len(vals), None, build)
    build = lambda i: base.extend(src.effect(vals[i]), isrc.effect(vals[i]) if isrc is not None else None)
    bounds = np.asarray(effect.lower_bounds(rest.structure), float)  # the effect's own columns' physical bounds
    bounds = bounds if keep is None else bounds[np.asarray(keep, bool)]
    lower = np.r_[np.full(Y.shape[2], -np.inf), bounds]
    mine = np.r_[np.zeros(Y.shape[2], bool), np.ones(bounds.size, bool)]
    if exact:
        for c in (src, isrc):
            if c is not None:
                c.prefetch(vals)
        every = (
            base.extend([src.effect(v) for v in vals], None if isrc is None else [isrc.effect(v) for v in vals])
            if vals
            else None
        )
        return Grid(vals, [None] * len(vals), None, build, lower, mine, every)
    screen = None
    if len(vals) > SCREEN_ABOVE:
        rough = lsq.Stats.of(Y, data.tau(delay), starts)
        screen = [rough.extend(src.screen(v)) for v in vals]
    return Grid(vals, [None] * len(vals), screen, build, lower, mine)


def _timing(value: Effect, rest: Model, delay) -> float | np.ndarray:
    """The delay a timing value gives on top of `rest` (which holds none: its delay is `delay`,
    0): one number, or one per joint."""
    assert isinstance(value, Delay)  # the vocabulary's one timing effect
    return value.per_joint(rest.n_joints) if isinstance(value.seconds, tuple) else delay + value.seconds


class _Kept:
    """Columns of an effect with some left out (held at 0): what `grid` sees."""

    def __init__(self, cols: Columns, keep: np.ndarray):
        self.cols, self.keep = cols, keep

    def model(self, model: Model) -> np.ndarray:
        """The model's columns, all of them."""
        return self.cols.model(model)

    def effect(self, e: Effect) -> np.ndarray:
        """The effect's columns that are kept."""
        return self.cols.effect(e)[..., self.keep]

    def screen(self, e: Effect) -> np.ndarray:
        """`Columns.screen` of the columns that are kept."""
        return self.cols.screen(e)[..., self.keep]

    def prefetch(self, effects: Sequence[Effect]) -> None:
        """`Columns.prefetch`."""
        self.cols.prefetch(effects)


def search_all(
    data: Data, cols: Columns, model: Model, fixed: set[str], icols: Columns | None = None
) -> tuple[Model, dict]:
    """Each effect's non-linear parameter not `fixed`, searched on all rows, the others held:
    the model with the values found, and the search curves (name -> (the values described,
    their rel_errors))."""
    curves: dict = {}
    span = data.span()
    everything = np.ones(1, bool)
    for e in model.effects:
        if e.name in fixed or not e.space(span.of(e)):
            continue
        g = grid(data, cols, model.without(e.name), e, np.array([0]), icols=icols)
        best, errs = g.choose(everything)
        yy = float(np.sum(data.tau(delay_of(model.without(e.name))) ** 2))
        model = model.with_effect(g.values[best])
        curves[e.name] = ([v.describe() for v in g.values], np.sqrt(np.maximum(errs, 0) / yy) if yy else errs)
    return model, curves
