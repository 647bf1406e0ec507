"""Thresholds from step tests: the stability map over a grid, and edges found by multisection.

`stability_map` runs the grid (one vmapped call, or on Dask) and reads, for each b_c, the
largest stable k below the first unstable one, and which type of instability that is.

`edge` finds where stability ends along a line with far fewer trials: each round puts `points`
trials between the last stable and the first unstable point of every line (all lines in one
vmapped call), so two rounds of 24 and 12 narrow a factor-1000 range in k to about 2 %. It
returns the last stable value (the limit) and the kind of the first unstable one. Along k the
points are spaced geometrically, along b_c linearly (b_c may run downwards: negative damping).
"""

from __future__ import annotations

from typing import NamedTuple

import numpy as np

from manus.experiments.stability import sweep
from manus.experiments.stability.steptest import STABLE, Metrics, StepTest, verdict


class Edge(NamedTuple):
    limit: np.ndarray  # last stable value along each line (nan: unstable at the start)
    step: np.ndarray  # the bracket: the first unstable value is limit + step (0: none found)
    kind: np.ndarray  # of the first unstable point: STABLE (none found), TYPE1 or TYPE2


def edge(
    test: StepTest, fixed, start: float, stop: float, along: str = "k", points=(24, 12), cluster=None, **criteria
) -> Edge:
    """For each value in `fixed` (b_c when `along` is "k", k when it is "b_c"), the last stable
    value from `start` towards `stop` before the first unstable one. `criteria` go to
    `verdict` (psd_threshold, split_hz, native)."""
    fixed = np.atleast_1d(np.asarray(fixed, float))
    lo, hi = np.full(fixed.shape, float(start)), np.full(fixed.shape, float(stop))
    kind = np.full(fixed.shape, STABLE, np.int8)
    open_ = np.ones(fixed.shape, bool)  # still bracketing an edge
    for r, n in enumerate(points):
        # round 0: from start to stop inclusive; later: inside (lo, hi), hi being unstable
        frac = np.linspace(0.0, 1.0, n) if r == 0 else np.arange(1, n + 1) / (n + 1)
        s = lo[:, None] * (hi / lo)[:, None] ** frac if along == "k" else lo[:, None] + (hi - lo)[:, None] * frac
        other = np.broadcast_to(fixed[:, None], s.shape)
        k, b_c = (s, other) if along == "k" else (other, s)
        v = verdict(sweep.run(test, k, b_c, cluster, progress=False), test, **criteria)
        bad = v != STABLE
        first = np.where(bad.any(1), bad.argmax(1), n)
        for i in np.flatnonzero(open_):
            j = first[i]
            if r == 0 and j == 0:  # unstable where it starts
                lo[i], kind[i], open_[i] = np.nan, v[i, 0], False
            elif r == 0 and j == n:  # stable all the way
                lo[i], open_[i] = hi[i], False
            elif j < n:
                lo[i], hi[i], kind[i] = (s[i, j - 1] if j else lo[i]), s[i, j], v[i, j]
            else:
                lo[i] = s[i, -1]
    return Edge(lo, np.where(kind != STABLE, hi - lo, 0.0), kind)


class StabilityMap(NamedTuple):
    b_cs: np.ndarray  # rows
    ks: np.ndarray  # columns
    metrics: Metrics  # each (rows, columns)
    kinds: np.ndarray  # STABLE / TYPE1 / TYPE2, (rows, columns)
    limit: np.ndarray  # per row: the largest stable k below the first unstable (nan: none stable)
    limit_kind: np.ndarray  # per row: the kind of that first unstable point (STABLE: none)


def stability_map(test: StepTest, b_cs, ks, cluster=None, progress: bool = True, **criteria) -> StabilityMap:
    """The step test over the grid b_cs × ks (ks ascending) and each row's limit."""
    b_cs, ks = np.asarray(b_cs, float), np.asarray(ks, float)
    m = sweep.grid(test, b_cs, ks, cluster, progress=progress)
    return read_map(test, b_cs, ks, m, **criteria)


def read_map(test: StepTest, b_cs, ks, m: Metrics, **criteria) -> StabilityMap:
    """Classify a grid of metrics (again, e.g. with other criteria) and read each row's limit."""
    kinds = verdict(m, test, **criteria)
    bad = kinds != STABLE
    first = np.where(bad.any(1), bad.argmax(1), len(ks))
    limit = np.where(first > 0, ks[np.maximum(first - 1, 0)], np.nan)
    limit_kind = np.where(first < len(ks), kinds[np.arange(len(b_cs)), np.minimum(first, len(ks) - 1)], STABLE)
    return StabilityMap(b_cs, ks, m, kinds, limit, limit_kind.astype(np.int8))


def boundary(smap: StabilityMap, kind: int) -> list[dict]:
    """The rows whose limit is set by `kind`: [{"b_c", "k"}, ...] (a threshold curve)."""
    return [
        {"b_c": float(b), "k": float(k)}
        for b, k, c in zip(smap.b_cs, smap.limit, smap.limit_kind, strict=True)
        if c == kind and np.isfinite(k)
    ]


def slope(points: list[dict]) -> float:
    """Least-squares slope dk/db_c of a threshold curve [N/m per N·s/m] (nan: too few points)."""
    if len(points) < 2:
        return float("nan")
    b, k = np.array([p["b_c"] for p in points]), np.array([p["k"] for p in points])
    return float(np.polyfit(b, k, 1)[0])
