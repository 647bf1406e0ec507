"""What is left: structure in a model's residual that no effect of the vocabulary explains (the
`unexplained` of `manus diagnose`).

Per held-out block, the model is fitted on the other blocks and its residual taken on every row;
a smooth function of one variable (piecewise-linear hats on quantile knots) is fitted to the
training rows' residual of one joint and judged on the held-out block's: each joint's position,
velocity, position by direction of motion (for every joint's residual: a friction acting on a
relative velocity shows on both) and position times the model's torque (a torque ripple), time,
and a sinusoid at the training residual's spectral peak. The per-block improvement is tested as
a candidate's held-out errors are (log ratio, t-test: `significance.one_sided_p`), at `alpha`
over the number of variables tested (Bonferroni); a function must also remove at least
`UNEXPLAINED_MIN` of the remaining error held out, and account for at least `min_share` of the
recorded torque (RMS, as a candidate effect must: on a model that is right to 0.3 % of the torque,
a tenth of what is left is a quantizer's pattern, not a missing effect).
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from manus.adaptive.diagnosis.context import Context
from manus.adaptive.diagnosis.significance import one_sided_p
from manus.adaptive.identify.prepare import Data
from manus.adaptive.identify.result import Fit

UNEXPLAINED_MIN = 0.10  # a smooth function must remove this share of the remaining error
KNOTS = 10  # hat functions per smooth function of position or velocity


def _hats(x: np.ndarray, knots: np.ndarray) -> np.ndarray:
    """Piecewise-linear hat functions of x on `knots` (a smooth function's basis), (rows, m)."""
    x = np.clip(x, knots[0], knots[-1])
    out = np.zeros((x.size, knots.size))
    i = np.clip(np.searchsorted(knots, x, side="right") - 1, 0, knots.size - 2)
    w = (x - knots[i]) / np.maximum(knots[i + 1] - knots[i], 1e-300)
    out[np.arange(x.size), i] = 1 - w
    out[np.arange(x.size), i + 1] = w
    return out


def _smooth_basis(x: np.ndarray, m: int = KNOTS) -> np.ndarray | None:
    knots = np.unique(np.quantile(x, np.linspace(0, 1, m)))
    return _hats(x, knots) if knots.size >= 3 else None


RIPPLE = "position x torque"  # the model's torque times a function of position (a motor's torque ripple)


def _bases(data: Data, fitted: np.ndarray) -> dict:
    """Candidate smooth structures of the residual: name -> basis (rows, m). `fitted` (rows, n):
    the model's torque, for a torque that ripples with position (τ·(1 + ε(q)): the residual is
    the torque times a function of position; the model's torque, not the recorded one, whose
    noise would correlate with the residual's)."""
    rows = data.rows
    out = {}
    n = data.n_joints
    for i in range(n):
        q, qd = data.q[rows, i], data.qd[rows, i]
        for what, x in (("position", q), ("velocity", qd)):
            B = _smooth_basis(x)
            if B is not None:
                out[(what, i)] = B
        B = _smooth_basis(q, KNOTS // 2)
        if B is not None:
            up = (qd > 0)[:, None]
            out[("position x direction", i)] = np.concatenate([B * up, B * ~up], 1)
            out[(RIPPLE, i)] = B * fitted[:, [i]]
    t = data.rec.t[rows]
    out[("time", None)] = _hats(t, np.linspace(t[0], t[-1], KNOTS))
    return out


@dataclass(frozen=True)
class Tested:
    """One smooth function of one variable, fitted to one joint's residual on the training
    blocks and judged on the held-out ones (values as reported: `fraction` to 4 places, `share`
    to 5)."""

    joint: int  # 1-based: the joint whose residual it is fitted to
    variable: str  # "position", "velocity", ..., "time", "frequency"
    of_joint: int | None  # 1-based: the joint whose variable it is (None: time, frequency)
    fraction: float  # the share of the remaining error it removes held out
    p_value: float
    share: float  # the share of the recorded torque (RMS) it accounts for

    @property
    def against(self) -> str:
        """The variable, naming its joint where that is another than the residual's."""
        if self.of_joint is None or self.of_joint == self.joint:
            return self.variable
        return f"{self.variable} of joint {self.of_joint}"

    def counts(self, level: float, min_share: float) -> bool:
        """Significant at `level`, and relevant: it removes `UNEXPLAINED_MIN` of the error and
        accounts for `min_share` of the torque."""
        return bool(self.p_value < level and self.fraction >= UNEXPLAINED_MIN and self.share >= min_share)


def residual_structure(ctx: Context, f: Fit, alpha: float) -> dict:
    """Structure left in the residual of `f` that a smooth function of one variable removes on
    the held-out blocks of `ctx` (see the module docstring), judged at `alpha` and relevant at
    `ctx.min_share`: the JSON `unexplained`."""
    data, starts, folds, min_share = ctx.data, ctx.starts, ctx.folds, ctx.min_share
    Y = ctx.cols.model(f.model)
    tau = data.tau(f.delay)
    st = ctx.stats(f.model, f.delay)
    seg_of_row = np.searchsorted(starts, np.arange(data.rows.size), side="right") - 1
    resid = []
    for train, test in folds:
        theta = st.theta(st.coef(train))
        resid.append((tau - Y @ theta, train[seg_of_row], test[seg_of_row]))
    torque = float(np.sum(tau**2)) or 1.0
    bases = _bases(data, f.predicted())
    t = data.rec.t[data.rows]
    n = data.n_joints
    # each basis's held-out squared errors on every joint's residual at once (`_held_out`); the
    # sinusoid's basis is each joint's own
    errors = {key: _held_out(B, resid) for key, B in bases.items()}
    tests: list[Tested] = []
    for j in range(n):
        for what, i in [*bases, ("frequency", None)]:
            if what != "frequency":
                with_, without = (x[:, j] for x in errors[(what, i)])
            else:
                per_block = [_sinusoid(t, r[tr, j], tr) for r, tr, _ in resid]
                with_, without = (x[:, 0] for x in _held_out(per_block, [(r[:, [j]], tr, te) for r, tr, te in resid]))
            if not without.sum() > 0:
                continue
            frac = 1 - float(np.sqrt(with_.sum() / without.sum()))
            tests.append(
                Tested(
                    j + 1,
                    what,
                    None if i is None else i + 1,
                    round(frac, 4),
                    one_sided_p(without, with_),
                    round(float(np.sqrt(max(without.sum() - with_.sum(), 0.0) / torque)), 5),
                )
            )
    if not tests:
        return {"significant": False, "joint": None, "against": None, "fraction": 0.0, "p_value": 1.0}
    m = len(tests)
    counts = [x.counts(alpha / m, min_share) for x in tests]
    b = max(range(m), key=lambda k: (counts[k], tests[k].fraction))
    best = tests[b]
    out = {
        "significant": counts[b],
        "joint": best.joint,
        "against": best.against,
        "fraction": best.fraction,
        "p_value": float(f"{best.p_value:.3g}"),
        "tests": m,
        "variable": best.variable,
        "of_joint": best.of_joint,
        "share": best.share,
    }
    if not counts[b] and best.p_value < alpha / m:  # real, but too small to count
        out["below_relevance"] = UNEXPLAINED_MIN
        out["min_share"] = min_share
    if any(counts):
        out["also"] = [
            {"joint": x.joint, "against": x.against, "fraction": x.fraction}
            for k, x in enumerate(tests)
            if counts[k] and k != b
        ][:6]
    return out


def _held_out(B, resid: list) -> tuple[np.ndarray, np.ndarray]:
    """Per held-out block and residual column (blocks, m): the squared error of a smooth
    function fitted on the block's training rows, on its own rows, and the residual's own
    squared error there. `B`: the basis (rows, q), or one per block (None: no basis there, both 0);
    `resid`: per block (residual (rows, m), training rows, its own rows)."""
    m = resid[0][0].shape[1]
    with_, without = np.zeros((len(resid), m)), np.zeros((len(resid), m))
    for b, (r, tr, te) in enumerate(resid):
        Bk = B[b] if isinstance(B, list) else B
        if Bk is None:
            continue
        c = np.linalg.lstsq(Bk[tr], r[tr], rcond=1e-10)[0]
        e = r[te] - Bk[te] @ c
        for j in range(m):
            with_[b, j], without[b, j] = e[:, j] @ e[:, j], r[te, j] @ r[te, j]
    return with_, without


def what_removes(u: dict) -> str:
    """The structure an `unexplained` result names, as a phrase ("a smooth function of velocity")."""
    if u.get("variable") == "frequency":
        return "a sinusoid at the residual's spectral peak"
    if u.get("variable") == RIPPLE:
        return (
            f"joint {u.get('of_joint') or u.get('joint')}'s modelled torque times a smooth function of its "
            "position (a torque ripple)"
        )
    return f"a smooth function of {u.get('against')}"


def _sinusoid(t: np.ndarray, r_train: np.ndarray, train: np.ndarray) -> np.ndarray | None:
    """sin/cos at the training residual's spectral peak (a periodic disturbance not tied to a
    joint's position), evaluated on every row."""
    tt = t[train]
    if tt.size < 16:
        return None
    dt = float(np.median(np.diff(t)))
    f = np.fft.rfftfreq(8 * tt.size, dt)
    grid = np.interp(np.arange(tt[0], tt[-1], dt), tt, r_train)
    spec = np.abs(np.fft.rfft(grid - grid.mean(), 8 * tt.size))
    lo = max(1, int(np.ceil(3 / (tt[-1] - tt[0]) / (f[1] - f[0]))))  # at least three periods in the record
    if spec.size <= lo + 1:
        return None
    f0 = f[lo + int(np.argmax(spec[lo:]))]
    w = 2 * np.pi * f0 * t
    return np.stack([np.sin(w), np.cos(w)], 1)
