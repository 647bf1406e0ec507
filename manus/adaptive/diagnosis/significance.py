"""How a candidate's significance is judged over contiguous blocks of the recording: its
held-out errors (`held_out`, the per-block log ratio t-tested: `one_sided_p`), the score test's
clusters (`score_blocks`), and one p from both tests (`combined`, Simes' rule); per joint, what a
candidate removes from the error left there (`held_out_per_joint`, `on_joints`: relevance
relative to what is left).
"""

from __future__ import annotations

from dataclasses import dataclass

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


def held_out_per_joint(st: Stats, folds) -> np.ndarray:
    """Per block and joint, the squared error of the fit on the other blocks (blocks, n): `held_out`
    split by joint (`st` built by `Stats.of`, which keeps its rows)."""
    assert st.X is not None and st.tau is not None, "per-joint errors need the statistics' rows"
    train, test = (np.array(m) for m in zip(*folds, strict=True))
    C = st.coefs(train)
    seg = np.searchsorted(st.starts, np.arange(st.tau.shape[0]), side="right") - 1
    out = np.zeros((len(folds), st.tau.shape[1]))
    for k in range(len(folds)):
        rows = test[k][seg]
        r = st.tau[rows] - st.X[rows] @ C[k]
        out[k] = np.sum(r * r, axis=0)
    return out


# Relevance on one joint, relative to what is left there (`on_joints`): a model that is right to a
# few tenths of a percent leaves a quantizer's or a filter's pattern that a tenth of can be fitted
# significantly, so the share must be large; a share of the joint's own torque as small as this
# is no physical effect on any recording the calibration holds.
LEFT = 0.25  # of the joint's remaining error, held out
FLOOR = 0.001  # of the joint's recorded torque (RMS), at least


@dataclass(frozen=True)
class OnJoint:
    """What a candidate (or a step) removes from one joint's error, held out."""

    joint: int  # 0-based
    left: float  # the share of the joint's remaining error it removes
    share: float  # the share of the joint's recorded torque (RMS) it accounts for
    p_value: float  # its per-block log ratio t-tested on this joint alone (`one_sided_p`)

    def relevant(self, level: float, min_share: float) -> bool:
        """Significant on this joint at `level`, and either `min_share` of its torque or, where the
        model already explains nearly all of it, `LEFT` of what is left (at least `FLOOR` of it)."""
        big = self.share >= min_share or (self.left >= LEFT and self.share >= FLOOR)
        return bool(self.p_value < level and big)

    def says(self) -> str:
        """One phrase: what it removes on this joint."""
        return (
            f"on joint {self.joint + 1} it removes {100 * self.left:.0f} % of what is left held out "
            f"({100 * self.share:.2g} % of that joint's torque, p {self.p_value:.2g})"
        )


def on_joints(before: np.ndarray, after: np.ndarray, torque: np.ndarray) -> list[OnJoint]:
    """Per joint, from the held-out errors before and after (blocks, n) and the joints' recorded
    torque Σ τ² (n,): what the change removes there (joints without error or torque left out)."""
    out = []
    for j in range(before.shape[1]):
        b, a = float(before[:, j].sum()), float(after[:, j].sum())
        if not (b > 0 and torque[j] > 0):
            continue
        left = 1 - float(np.sqrt(a / b))
        share = float(np.sqrt(max(b - a, 0.0) / torque[j]))
        out.append(OnJoint(j, left, share, one_sided_p(before[:, j], after[:, j])))
    return out
