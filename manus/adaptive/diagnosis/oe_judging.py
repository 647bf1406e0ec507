"""Candidates judged by the error output error fits (`manus diagnose` where the fit is OE).

Where the fit a diagnosis starts from is output error (`manus.adaptive.identify.output_error`),
or where `auto` would fit output error to the model with one of its candidates (the encoder's
quantization noise in q̈ makes up `NOISE_SHARE` of what identifies an inertial parameter: its
torque error is mostly that noise), every candidate is judged by the error OE fits, the
positions simulated from the recorded command over the same windows, each restarted from the
measured position (`judging`, `rejudge`). A candidate is then the OE fit of the model with it,
and its evidence is what `manus.adaptive.diagnosis.candidates` asks of a candidate judged by the
torque, in positions:

- *held-out errors*: the windows are cut into contiguous blocks (as many as the torque's
  held-out blocks, at most one per window); for each block the model is fitted on the others
  and the block's positions predicted, its windows' initial velocities fitted on their own
  positions (each window restarts from its measured state). The fit on the other blocks is the
  full fit's Gauss–Newton linearisation refitted there (`Linear`: the simulation's Jacobian at
  the OE fit, the windows' velocities projected out, as the least-squares statistics of the
  torque are refitted per fold, `lsq.Stats`): exact where the positions are linear in the
  parameters, one Gauss–Newton step from the full fit otherwise (a block is a small share of the
  data, so its fit moves the parameters little). The per-block log ratio of squared errors is
  t-tested over the blocks (`significance.one_sided_p`);
- the *score test* of the candidate's parameters (`scores.block_scores`, `score_p`): the
  simulation's Jacobian in them at the model's OE fit with the candidate at zero (its null),
  the velocities projected out, against the model's position residual, summed per block, one-sided
  in the parameters whose physics fixes their sign. A candidate that moves the command (a delay)
  or takes another effect's place (smooth friction in Coulomb's) has held-out errors only;
- relevance: a share `min_share` of what the dynamics must explain in the windows, √(e_before²
  − e_after²), or `MOST` of the error. What the dynamics must explain is the positions less the
  straight line each window's measured start and own velocity give (`dynamic_motion`): the
  positions' analogue of the torque, which is what the acceleration asks of the model (a share
  of the whole motion would count the part every model's free velocity follows).

The two p's are combined by Simes' rule at the step's level, as for the torque. The
candidate's non-linear parameter is the one its torque search found (a cogging order, a
Stribeck velocity, a delay), not searched again on positions. A step of `manus discover`
changes the error where the refitted model removes a relevant share of the held-out position
error (`PositionJudging.kept`).
"""

from __future__ import annotations

from dataclasses import dataclass, field, replace

import numpy as np

from manus.adaptive.diagnosis.candidates import MOST, Candidate, Judged
from manus.adaptive.diagnosis.context import Context
from manus.adaptive.diagnosis.scores import block_scores, score_p
from manus.adaptive.diagnosis.significance import SIGNIFICANCE, combined, one_sided_p
from manus.adaptive.identify.columns import Columns
from manus.adaptive.identify.fit import fit
from manus.adaptive.identify.lsq import Stats
from manus.adaptive.identify.output_error import (
    OutputErrorFit,
    Problem,
    Windows,
    _velocities,
    oe_reason,
    quantization,
    window_samples,
)
from manus.adaptive.identify.result import Fit
from manus.plants.errors import ModelError

TORQUE = "torque"
POSITION = "position (output error)"
# Output error's Jacobian costs one simulation of every window per parameter: where `auto` would turn
# to it only for some candidate, a model with more parameters than this (a 6–7-joint chain's ~80) is
# judged by the torque.
AFFORDABLE = 30


@dataclass(frozen=True)
class Linear:
    """One model's OE fit linearised on the windows: per window k, the residual r_k = q_sim − q
    and the Jacobian J_k in the free parameters, each with the window's own initial velocity
    projected out (P⊥_k = I − J_v (J_vᵀJ_v)⁻¹ J_vᵀ); as least-squares statistics (`stats`) of
    y = Jθ − r over the windows (one segment each), so that a fit on some windows and its squared
    error on others are `Stats.coefs` and `Stats.sses`."""

    fit: OutputErrorFit
    free: tuple[str, ...]
    lower: np.ndarray  # (P,) the free parameters' lower bounds
    stats: Stats
    r: np.ndarray  # (K, W·n) the residual, velocities projected out

    def held_out(self, test: np.ndarray) -> np.ndarray:
        """Per block (test: (blocks, windows) masks), the squared position error of the fit on the
        other blocks."""
        return self.stats.sses(self.stats.coefs(~test, self.lower), test)


def _linearise(f: OutputErrorFit, start: dict[str, float] | None = None, scale: dict | None = None):
    """(problem, θ, r⊥, X⊥) of `f`'s model at `start` (default: `f`'s parameters), its windows'
    velocities fitted there."""
    params = f.params if start is None else start
    steps = scale if scale is not None else {k: max(abs(v), np.nan_to_num(s)) for k, v, s in _triples(f)}
    problem = Problem(f.data, f.model, params, set(f.redundant), steps)
    theta = problem.vector(params)
    qd0, r, Jv = _velocities(problem, theta, np.asarray(problem.w.qd0, float), rounds=6)
    Jt = problem.by_theta(theta, qd0, r)
    n = Jv.shape[-1]
    P = np.linalg.pinv(np.einsum("kip,kiq->kpq", Jv, Jv) + 1e-300 * np.eye(n))
    proj = lambda A: A - np.einsum("kip,kpq,kqj->kij", Jv, P, np.einsum("kip,ki...->kp...", Jv, A))
    r_perp = proj(r[..., None])[..., 0]
    X = proj(Jt)
    return problem, theta, r_perp, X


def _triples(f: Fit):
    return ((k, v, s) for (k, v), s in zip(f.params.items(), f.std, strict=True))


def _stats(X: np.ndarray, y: np.ndarray, n: int) -> Stats:
    K, Wn, P = X.shape
    W = Wn // n
    return Stats.of(X.reshape(K * W, n, P), y.reshape(K * W, n), np.arange(K) * W)


def linear(f: OutputErrorFit) -> Linear:
    """`f` linearised at its own parameters (`Linear`)."""
    problem, theta, r, X = _linearise(f)
    y = np.einsum("kip,p->ki", X, theta) - r
    return Linear(f, problem.free, problem.lower, _stats(X, y, f.data.n_joints), r)


@dataclass
class PositionJudging:
    """What the candidates of one step are judged on where they are judged by OE's error: the
    base model's OE fit linearised, the blocks of windows, and why."""

    why: str  # why the candidates are judged by positions (`judged_why`)
    reason: str  # why output error fits this recording: each candidate's OE fit's `method_why`
    cols: Columns
    base: Linear
    test: np.ndarray  # (blocks, windows)
    base_sse: np.ndarray  # (blocks,) the base model's held-out position errors
    motion: float  # what the dynamics must explain (`dynamic_motion`)
    fits: dict[str, Linear] = field(default_factory=dict)  # by model spec

    def of(self, spec: str, method: str = "oe") -> Linear:
        """The OE fit of the model `spec` on these windows, linearised (kept by spec)."""
        if spec not in self.fits:
            try:
                f = fit(self.base.fit.data, spec, columns=self.cols, method=method)
                if not isinstance(f, OutputErrorFit):
                    raise ModelError(f"output error did not fit {spec} ({f.why})")
                self.fits[spec] = linear(replace(f, why=self.reason))
            except np.linalg.LinAlgError as e:  # (a simulation that leaves the data: its steps are not finite)
                raise ModelError(f"its minimisation failed ({e})") from e
        return self.fits[spec]

    def rel(self, sse: np.ndarray | float) -> float:
        """A sum of squared position errors as a share of what the dynamics must explain (RMS)."""
        return float(np.sqrt(np.sum(sse) / self.motion)) if self.motion > 0 else np.inf

    def kept(self, after: Fit, min_share: float) -> tuple[bool, str]:
        """Whether the model of `after` removes a relevant share of the base model's held-out
        position error (`min_share` of what the dynamics must explain, or `MOST` of the error), and a
        phrase."""
        lin = self.fits.get(after.model.spec)
        try:
            if lin is None or lin.fit is not after:
                lin = linear(after) if isinstance(after, OutputErrorFit) else self.of(after.model.spec)
        except (ModelError, np.linalg.LinAlgError) as e:
            return False, f"output error cannot fit it ({e})"
        sb, sa = float(self.base_sse.sum()), float(lin.held_out(self.test).sum())
        share = float(np.sqrt(max(sb - sa, 0.0) / self.motion)) if self.motion > 0 else 0.0
        removed = 1 - float(np.sqrt(sa / sb)) if sb > 0 else 0.0
        said = f"held-out position error {100 * self.rel(sb):.3g} % -> {100 * self.rel(sa):.3g} % of the dynamic motion"
        return bool(sa < sb and (share >= min_share or removed >= MOST)), said


def dynamic_motion(data) -> float:
    """Σ over OE's windows and joints of the positions' squared distance from the straight line
    through the measured start with the slope that fits them best: what a model must explain
    beyond each window's free initial velocity."""
    w = Windows.of(data, window_samples(data), 1)
    m = w.q - w.q0[:, None, :]  # (K, W, n)
    t = np.arange(1, w.size + 1, dtype=float)[None, :, None]
    line = t * (np.sum(t * m, axis=1, keepdims=True) / np.sum(t * t))
    return float(np.sum((m - line) ** 2))


def judging(ctx: Context, cands: list[Candidate], method: str) -> tuple[PositionJudging | None, str]:
    """The position judging of this step (`PositionJudging`), or None (judged by the torque), and a
    note for the diagnosis (where output error was needed and could not be had: why). Judged by positions where the base
    fit is OE, or where `method` is "auto", the model has at most `AFFORDABLE` parameters and `auto`
    would fit OE to the model with a candidate (`output_error.oe_reason` on the candidate's
    least-squares fit)."""
    data, cols, base = ctx.data, ctx.cols, ctx.base
    why = reason = ""
    if base.method == "oe":
        why, reason = f"the model's fit is output error ({base.why})", base.why
    elif method == "auto" and base.method == "ls":
        if len(base.names) > AFFORDABLE:
            return None, ""
        for c in cands:
            if c.fit is None or c.fit.method != "ls":
                continue
            reason = oe_reason(data, c.fit, quantization(data, cols, c.fit))
            if reason:
                why = reason = f"with {c.spec}, {reason}"
                break
    if not why:
        return None, ""
    try:
        f = base if isinstance(base, OutputErrorFit) else fit(data, base.model.spec, columns=cols, method="oe")
        if not isinstance(f, OutputErrorFit):
            raise ModelError(f.why)
        lin = linear(f)
    except (ModelError, np.linalg.LinAlgError) as e:
        return None, f"the candidates are judged by the torque: output error cannot fit {base.model.spec} ({e})"
    K = lin.r.shape[0]
    G = int(min(len(ctx.folds), K))
    test = np.zeros((G, K), bool)
    for g, idx in enumerate(np.array_split(np.arange(K), G)):
        test[g, idx] = True
    judged = PositionJudging(why, reason, cols, lin, test, lin.held_out(test), dynamic_motion(data))
    judged.fits[f.model.spec] = lin
    return judged, (
        "the candidates are judged by output error's held-out position errors; what is left in the residual "
        "(unexplained) is still tested on the torque error"
    )


def rejudge(ctx: Context, pj: PositionJudging, cands: list[Candidate]) -> None:
    """Each candidate with a fit judged again by its OE fit's position errors (see the module
    docstring): its fit, error reductions, held-out errors, p, significance, problems and note
    replaced (a search value on the edge of its range stays a problem); a structural mode (judged
    in its frequency band) stays as it is."""
    base = pj.base
    for c in cands:
        if c.fit is None or not isinstance(c.evidence, Judged):
            continue
        spec = c.fitted().model.spec
        try:
            lin = pj.of(spec)
        except ModelError as e:
            c.significant = False
            c.problems = [f"output error cannot fit {spec}: {e}"]
            c.note = "; ".join(x for x in (c.note, "output error cannot fit it: not judged by positions") if x)
            continue
        f = lin.fit
        sse = lin.held_out(pj.test)
        tests: dict[str, float] = {"held_out": one_sided_p(pj.base_sse, sse)}
        score = _score(ctx, pj, c, f)
        if score is not None:
            tests["score"] = score
        p = combined(tests)
        b_rel, c_rel = pj.rel(np.sum(base.r**2)), pj.rel(np.sum(lin.r**2))  # (in-sample)
        reduction = 1 - c_rel / b_rel if b_rel > 0 else 0.0
        explains = float(np.sqrt(max(b_rel**2 - c_rel**2, 0.0)))
        cv_red = 1 - float(np.sqrt(sse.sum() / pj.base_sse.sum())) if pj.base_sse.sum() > 0 else 0.0
        per_joint = [
            round(1 - a / b, 4) if b > 0 else 0.0 for a, b in zip(f.position_rms, base.fit.position_rms, strict=True)
        ]
        s = f.model.structure
        own = [e for e in f.model.effects if not base.fit.model.has(e.name)]
        names = [k for e in own for k in e.names(s)]
        c.evidence = replace(
            c.evidence,
            params={k: v for k, v in f.params.items() if k in names},
            per_joint=per_joint,
            explains=explains,
            p_values=tests,
            score_test=f"position, {pj.test.shape[0]} blocks" if score is not None else None,
            detectable=np.inf,
        )
        c.fit = f
        c.error_reduction, c.cv_error_reduction, c.p_value, c.cv_sse = reduction, cv_red, p, sse
        c.note = ""  # (what the torque's judging said: its held parameters, its place; `replaces` stays)
        c.significant = bool(p < ctx.alpha and (explains >= ctx.min_share or reduction >= MOST) and cv_red > 0)
        problems = [v for e in own for v in e.violations(s, f.params, f.stds)]
        lost = [k for k in names if k in f.redundant]
        if lost:
            problems.append(f"not identifiable from this recording: {', '.join(lost)}")
        edge = [x for x in c.problems if "edge of its search range" in x]  # (the torque search's value)
        c.problems = problems + edge


def _score(ctx: Context, pj: PositionJudging, c: Candidate, f: OutputErrorFit) -> float | None:
    """p of the score test of the candidate's parameters on the base model's position residual
    (None where it has none: a delay, an effect in another's place, a model not nesting the
    base's)."""
    base = pj.base.fit
    new = [k for k in f.names if k not in base.params]
    if not new or any(k not in f.params for k in base.params):
        return None
    start = {k: base.params.get(k, 0.0) for k in f.names}
    scale = {k: max(abs(v), np.nan_to_num(s), 1e-9) for k, v, s in _triples(f)}
    try:
        problem, theta, r, X = _linearise(
            replace(f, redundant=sorted(set(f.redundant) | set(base.redundant))), start, scale
        )
    except (ModelError, np.linalg.LinAlgError):
        return None
    tested = np.array([k in new for k in problem.free])
    if not tested.any():
        return None
    y = np.einsum("kip,p->ki", X, theta) - r
    st = _stats(X, y, f.data.n_joints)
    scores = block_scores(st, tested, pj.test)
    signed = np.isfinite(problem.lower)[tested]
    return score_p([scores], ctx.alpha / len(SIGNIFICANCE), signed=signed)[0]


def overlaps(ctx: Context, pj: PositionJudging, verdict: Candidate, cands: list[Candidate]) -> None:
    """Other significant candidates the verdict already accounts for, in positions (the torque's
    overlap test, `verdict._mark_overlaps`, on OE's held-out position errors): the OE fit of the
    verdict's model with the candidate added removes no relevant share of the held-out position
    error that is significantly there (`_adds`). Where neither adds to the other, the two are
    readings the recording cannot tell apart (the verdict's `reads_as`)."""
    if verdict.fit is None or verdict.mode is not None:
        return
    with_v = pj.of(verdict.fitted().model.spec)
    same = []
    for c in cands:
        if c is verdict or not c.significant or c.fit is None or c.mode is not None or c.effect in verdict.aliases:
            continue
        if with_v.fit.model.has(c.effect):
            continue
        try:
            both = pj.of(with_v.fit.model.with_effect(c.found()).spec)
        except ModelError:
            continue
        extra, adds = _adds(ctx, pj, with_v, both)
        if adds:
            continue
        if not _adds(ctx, pj, pj.of(c.fitted().model.spec), both)[1]:
            same.append(c.spec)
        c.overlaps = verdict.effect
        c.note = "; ".join(
            x
            for x in (
                c.note,
                f"explains the same as {verdict.effect} in positions: with {verdict.effect} in the model it removes "
                f"{100 * extra:.2g} % of what the dynamics must explain held out, which is not significantly there",
            )
            if x
        )
    if same:
        verdict.readings = same
        verdict.note = "; ".join(
            x
            for x in (
                verdict.note,
                f"the positions hardly tell {verdict.spec} from {' or '.join(same)}: neither adds to the other a "
                f"relevant share of the held-out position error that is significantly there (the model's other "
                f"parameters, fitted with either, may differ)",
            )
            if x
        )


def _adds(ctx: Context, pj: PositionJudging, fitted: Linear, both: Linear) -> tuple[float, bool]:
    """The share of what the dynamics must explain that `both` removes held out beyond `fitted`,
    and whether it is relevant and significant (the held-out errors' t-test at the step's level)."""
    a, b = fitted.held_out(pj.test), both.held_out(pj.test)
    share = float(np.sqrt(max(a.sum() - b.sum(), 0.0) / pj.motion)) if pj.motion > 0 else 0.0
    removed = 1 - float(np.sqrt(b.sum() / a.sum())) if a.sum() > 0 else 0.0
    relevant = share >= ctx.min_share or removed >= MOST
    return share, bool(relevant and one_sided_p(a, b) < ctx.alpha)
