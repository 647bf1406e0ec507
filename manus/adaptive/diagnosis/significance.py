"""How a candidate's significance is judged over contiguous blocks of the recording: its
held-out errors (`held_out`, the per-block log ratio t-tested: `one_sided_p`), the score test's
clusters (`score_blocks`), and one p from both tests (`combined`, Simes' rule).
"""

from __future__ import annotations

import numpy as np
from scipy import stats

from manus.adaptive.diagnosis.scores import correlation_time
from manus.adaptive.identify.lsq import Stats
from manus.adaptive.identify.prepare import Data

SIGNIFICANCE = ("score", "held_out")  # the tests a candidate's p combines (`combined`)
SPAN = 4.0  # the score test's blocks are at least this many correlation times of the residual long ...
MIN_TEST_BLOCKS = 10  # ... and at least this many (2⁹ sign patterns: a p below the step's threshold is possible)


def held_out(st: Stats, folds) -> np.ndarray:
    """Per block, the squared error of the fit on the other blocks."""
    train, test = (np.array(m) for m in zip(*folds, strict=True))
    return st.sses(st.coefs(train), test)


def one_sided_p(base_sse: np.ndarray, sse: np.ndarray) -> float:
    """p of 'the candidate predicts the held-out blocks better': a one-sided t-test over blocks
    on the log ratio of squared errors (scale-free: a loud block does not dominate)."""
    ok = (base_sse > 0) & (sse > 0)
    if ok.sum() < 3:
        return 1.0
    d = np.log(base_sse[ok] / sse[ok])
    sd = d.std(ddof=1)
    if not sd > 0:
        return 0.0 if d.mean() > 0 else 1.0
    return float(stats.t.sf(d.mean() / (sd / np.sqrt(d.size)), d.size - 1))


def combined(tests: dict) -> float:
    """One p of a candidate from its tests (`SIGNIFICANCE`; a delay, which has no columns, only
    the held-out one), by Simes' rule: the sorted p's, each times their number over its rank, the
    smallest (two tests: the smaller doubled, or the larger as it is). Either test may decide
    alone at half the level, and both together at the level: the two are computed from the same
    residual and rise and fall together (positively dependent, where Simes' rule keeps its level),
    and Bonferroni's doubling of the smaller would pay for a second look that mostly agrees with
    the first. The score test is the more powerful where the model is nearly right and the
    residual noisy; the held-out errors where the model is far from the data (several large
    effects missing: what is left is not noise, and a score's yardstick is swamped by it, while a
    better prediction of every held-out block still shows)."""
    ps = np.sort(np.asarray(list(tests.values()), float))
    return float(min(1.0, np.min(ps.size * ps / np.arange(1, ps.size + 1))))


def score_blocks(folds, data: Data, resid: np.ndarray) -> np.ndarray:
    """The held-out blocks as the score test's clusters (G, S), merged where the residual of the
    model with the candidate is correlated for longer than a block (a slow, unrecorded
    disturbance): each group at least `SPAN` correlation times long, so that neighbouring groups
    are nearly independent, and at least `MIN_TEST_BLOCKS` of them."""
    blocks = np.array([test for _, test in folds])
    G = blocks.shape[0]
    t = data.rec.t[data.rows]
    tau = correlation_time(resid, float(np.median(np.diff(t))) if t.size > 1 else data.dt)
    want = int((t[-1] - t[0]) / (SPAN * tau)) if tau > 0 else G
    g = int(np.clip(want, min(MIN_TEST_BLOCKS, G), G))
    if g == G:
        return blocks
    return np.array([blocks[i].any(0) for i in np.array_split(np.arange(G), g)])
