"""Where does a model fail, and which physical effect is missing? (`manus diagnose`)

Every effect of the vocabulary not yet in the model is a candidate. For each, the model plus the
candidate is fitted (its non-linear parameter searched) and judged three ways:

- `error_reduction`: the fraction of the current error (rel_error) that adding it removes;
- held-out blocks: the recording is cut into `blocks` contiguous pieces; each is predicted by a
  fit on the others (leaving out a guard of one filter length at the seams). The 1 kHz residual
  is strongly autocorrelated, so a naive F-test over 20 000 samples calls everything
  significant; the blocks are long enough to be nearly independent, and a one-sided t-test on
  the per-block improvements is honest;
- relevance: an effect must remove at least `min_reduction` of the current error to be proposed
  (a real but negligible improvement is reported, not proposed).

The verdict is chosen in three steps:

1. the significant candidate with the lowest held-out error;
2. the one-standard-error rule: a simpler candidate (fewer parameters) whose held-out error is
   within one standard error of it (over the blocks) is preferred: an offset and a gravity term
   on a small swing fit alike, and the offset is the simpler story;
3. the nested rule (docs/effects.md: effects overlap, and where one contains another the simpler
   explanation comes first): when the base model plus the chosen effect reproduces a simpler
   significant candidate's columns exactly (relative residual under `NESTED_RTOL` on the rows
   used), that candidate is proposed instead, even when the bigger one fits better; the bigger
   one is tested again at the next step, on top of the simpler one, where only what it adds
   counts. The case in point: asymmetry's direction-dependent Coulomb term dFc |sgn q̇| is a
   constant wherever the joint moves (standstill rows are left out), so with coulomb it is the
   offset; asymmetry = offset + a direction-dependent viscous term. On EMPS asymmetry's held-out
   error is 23.5 % below the offset's, but the offset is proposed first and asymmetry follows
   (its viscous part is significant on its own). Approximate containment does not count: a
   tilted plane's cos/sin reproduce an offset only to O(swing²), and there the one-standard-error
   rule decides on the evidence. Both candidates say so in their `note` (`nested_in` on the verdict).

Candidates that explain the same thing as the verdict are marked `overlaps` (with the verdict
added, they remove little more), with a note saying which fits better and by how much.

`compliance` is judged in the frequency band where it lives (see `manus.adaptive.modes`).
"""

from __future__ import annotations

from dataclasses import dataclass, field

import numpy as np
from scipy import stats

from manus.adaptive import fit as fitting
from manus.adaptive import modes
from manus.plants.effects import ORDER, VOCABULARY, Model
from manus.plants.errors import ModelError
from manus.plants.recording import Recording

BLOCKS = 10
ALPHA = 0.01
MIN_REDUCTION = 0.05
MIN_ROWS_PER_BLOCK = 10
NESTED_RTOL = 1e-4  # a candidate whose columns the verdict's model reproduces this closely is nested in it


@dataclass
class Candidate:
    effect: str
    spec: str
    error_reduction: float
    cv_error_reduction: float
    p_value: float
    significant: bool
    joint: int  # 1-based: the joint where it removes most
    detail: dict
    n_params: int
    cv_sse: np.ndarray  # (blocks,) held-out squared error with the candidate
    fit: fitting.Fit | None = None
    mode: modes.Mode | None = None
    overlaps: str | None = None
    note: str = ""
    nested_in: str | None = None  # the verdict was chosen before this bigger candidate that contains it

    def report(self) -> dict:
        out = {"effect": self.effect, "joint": self.joint, "error_reduction": round(self.error_reduction, 4),
               "significant": self.significant, "detail": self.detail,
               "cv_error_reduction": round(self.cv_error_reduction, 4), "p_value": float(f"{self.p_value:.3g}")}
        if self.overlaps:
            out["overlaps"] = self.overlaps
        if self.nested_in:
            out["nested_in"] = self.nested_in
        if self.note:
            out["note"] = self.note
        return out


@dataclass
class Diagnosis:
    base: fitting.Fit
    candidates: list[Candidate]
    verdict: Candidate | None
    base_cv_sse: np.ndarray
    notes: list[str] = field(default_factory=list)

    def report(self) -> dict:
        return {"model": self.base.model.effect_names, "spec": self.base.model.spec,
                "rel_error": self.base.rel_error, "cutoff_hz": self.base.data.cutoff_hz,
                "candidates": [c.report() for c in self.candidates],
                "verdict": self.verdict.effect if self.verdict else None,
                "verdict_spec": self.verdict.spec if self.verdict else None, "notes": self.notes}


def _blocks(data: fitting.Data, k: int):
    """Held-out folds over the used rows: (train mask, test mask) per block."""
    t = data.rows
    edges = np.linspace(t[0], t[-1] + 1, k + 1)
    guard = int(np.ceil(1.0 / (data.cutoff_hz * data.dt)))
    folds = []
    for a, b in zip(edges[:-1], edges[1:]):
        test = (t >= a) & (t < b)
        train = (t < a - guard) | (t >= b + guard)
        folds.append((train, test))
    return folds


def held_out_sse(Y: np.ndarray, tau: np.ndarray, folds) -> np.ndarray:
    """Per block, the squared error of a least-squares fit on the other blocks."""
    rows, n, P = Y.shape
    out = np.zeros(len(folds))
    # normal equations on the scaled columns, solved by SVD (rank-deficient models keep their
    # minimum-norm solution); einsum, not BLAS, for the tall products (see search.Projection)
    scale = np.sqrt(np.einsum("rnp,rnp->p", Y, Y) / (rows * n)) + 1e-300
    Ys = Y / scale
    for k, (train, test) in enumerate(folds):
        G = np.einsum("rnp,rnq->pq", Ys[train], Ys[train])
        b = np.einsum("rnp,rn->p", Ys[train], tau[train])
        coef = np.linalg.lstsq(G, b, rcond=1e-12)[0]
        e = tau[test] - np.einsum("rnp,p->rn", Ys[test], coef)
        out[k] = np.einsum("rn,rn->", e, e)
    return out


def _one_sided_p(gain: np.ndarray) -> float:
    """p of 'the mean per-block improvement is positive' (t-test over blocks)."""
    if np.allclose(gain, 0):
        return 1.0
    sd = gain.std(ddof=1)
    if sd == 0:
        return 0.0 if gain.mean() > 0 else 1.0
    return float(stats.t.sf(gain.mean() / (sd / np.sqrt(gain.size)), gain.size - 1))


def _n_params(model_effect, structure) -> int:
    return len(model_effect.names(structure)) + len(model_effect.describe())


def diagnose(rec: Recording | fitting.Data, model: Model | str, cutoff_hz: float | None = None,
             blocks: int = BLOCKS, alpha: float = ALPHA, min_reduction: float = MIN_REDUCTION,
             columns: fitting.Columns | None = None) -> Diagnosis:
    """Fit `model` to the recording, then try every effect it lacks (see the module docstring).
    A loop over one prepared recording can pass its `columns` (a `fitting.Columns` of the same
    data) so that each effect's columns are computed once for every step."""
    structure = (rec.rec if isinstance(rec, fitting.Data) else rec).structure
    # the text is checked before any work (unknown names, a full model); fit gets it as given, as
    # text fixes the non-linear parameters written with an argument (cogging:39)
    parsed = Model(structure, model) if isinstance(model, str) else model
    if not [name for name in ORDER if not parsed.has(name)]:
        raise ModelError(f"the model {parsed.spec} already holds every effect of the vocabulary: "
                         "nothing is left to propose")
    data = rec if isinstance(rec, fitting.Data) else fitting.prepare(rec, cutoff_hz)
    if columns is not None and columns.data is not data:
        raise ModelError("diagnose: the columns given were computed on other data")
    cols = columns or fitting.Columns(data)
    base = fitting.fit(data, model, columns=cols)
    present = set(base.model.effect_names)
    missing = [name for name in ORDER if name not in present]
    if blocks < 3:
        raise ModelError(f"blocks must be at least 3 for a held-out test (got {blocks})")
    if data.rows.size < MIN_ROWS_PER_BLOCK * blocks:
        raise ModelError(f"{data.rec.path}: too short to diagnose: {data.rows.size} usable rows, where {blocks} "
                         f"held-out blocks need at least {MIN_ROWS_PER_BLOCK * blocks} "
                         f"({len(data.rec) * data.dt:.3g} s recorded at a {data.cutoff_hz:.3g} Hz cut-off)")
    folds = _blocks(data, blocks)
    s = base.model.structure
    base_sse = held_out_sse(cols.model(base.model), data.tau(base.delay), folds)
    base_joint = np.sum(base.residual**2, axis=0)
    cands: list[Candidate] = []
    notes: list[str] = []
    for name in missing:
        if name == "compliance":
            c = _compliance(data, base, blocks, alpha, min_reduction)
            if c is None:
                notes.append("compliance: the recording cannot show a structural mode (sampled too slowly or too short)")
            else:
                cands.append(c)
            continue
        effect = VOCABULARY[name]()
        f = fitting.fit(data, base.model.with_effect(effect), columns=cols, fixed=present)
        sse = held_out_sse(cols.model(f.model), data.tau(f.delay), folds)
        reduction = 1 - f.rel_error / base.rel_error if base.rel_error > 0 else 0.0
        cv_red = 1 - float(np.sqrt(sse.sum() / base_sse.sum()))
        p = _one_sided_p(base_sse - sse)
        joint = int(np.argmax(base_joint - np.sum(f.residual**2, axis=0))) + 1
        e = f.model.get(name)
        detail = {k: round(v, 6) for k, v in f.params.items() if k in e.names(s)}
        detail.update(e.describe())
        detail["per_joint_error_reduction"] = [
            round(1 - float(np.sqrt(np.sum(f.residual[:, i] ** 2) / base_joint[i])), 4) if base_joint[i] > 0 else 0.0
            for i in range(data.n_joints)]
        cands.append(Candidate(name, e.spec, reduction, cv_red, p, bool(p < alpha and reduction >= min_reduction),
                               joint, detail, _n_params(e, s), sse, fit=f))
    cands.sort(key=lambda c: -c.cv_error_reduction)
    verdict = _choose(cands, base_sse)
    if verdict is not None:
        verdict = _nested_first(cols, base, verdict, cands)
        _mark_overlaps(data, cols, base, verdict, cands, folds, min_reduction)
        cands.sort(key=lambda c: (c is not verdict, c.overlaps is not None, -c.cv_error_reduction))
    return Diagnosis(base, cands, verdict, base_sse, notes)


def _compliance(data, base, blocks, alpha, min_reduction) -> Candidate | None:
    q = data.rec.q
    tau = fitting.align(data.rec.tau, base.delay / data.dt + (0.5 if data.rec.meta.get("command_hold") == "zoh" else 0))
    mode = modes.detect(q, tau, data.dt, blocks)
    if mode is None:
        return None
    p = _one_sided_p(mode.err_rigid - mode.err_mode)
    significant = bool(mode.resonant and p < alpha and mode.reduction >= min_reduction)
    detail = {"f_hz": round(mode.f_hz, 1), "zeta": mode.zeta, "motor_fraction": round(mode.motor_fraction, 3),
              "measured_in": f"frequency response {modes.BAND[0]:g}-{min(modes.BAND[1], 0.45 / data.dt):g} Hz",
              "resonance_peak": mode.resonant}
    note = "" if mode.resonant else "no resonance peak in the measured response: no evidence of a mode"
    return Candidate("compliance", mode.effect().spec, mode.reduction, mode.reduction, p, significant,
                     mode.joint + 1, detail, 2, mode.err_mode, mode=mode, note=note)


def _choose(cands: list[Candidate], base_sse) -> Candidate | None:
    """Best held-out error among the significant; a simpler one within one standard error wins.
    (Compliance is measured in its own band, so it only wins when nothing else is significant.)"""
    sig = [c for c in cands if c.significant and c.effect != "compliance"]
    if not sig:
        comp = [c for c in cands if c.significant]
        return comp[0] if comp else None
    best = min(sig, key=lambda c: c.cv_sse.sum())
    for c in sorted(sig, key=lambda c: (c.n_params, c.cv_sse.sum())):
        diff = c.cv_sse - best.cv_sse
        se = np.sqrt(diff.size) * diff.std(ddof=1) if diff.size > 1 else 0.0
        if c.n_params < best.n_params and diff.sum() <= se:
            return c
    return best


def nested_in(cols: fitting.Columns, base_model: Model, outer: Candidate, inner: Candidate) -> float:
    """How far `inner`'s columns lie outside the span of the base model plus `outer` on these rows:
    the largest relative norm of a column's part orthogonal to that span (0: nested exactly)."""
    big = cols.model(base_model.with_effect(outer.fit.model.get(outer.effect)))
    small = cols.effect(inner.fit.model.get(inner.effect))
    rows, n, P = big.shape
    X, Z = big.reshape(rows * n, P), small.reshape(rows * n, -1)
    keep = np.sqrt(np.mean(X**2, axis=0)) > 0
    Q = np.linalg.qr(X[:, keep] / np.sqrt(np.mean(X[:, keep] ** 2, axis=0)))[0]
    norm = np.linalg.norm(Z, axis=0)
    out = np.linalg.norm(Z - Q @ (Q.T @ Z), axis=0)
    return float(np.max(np.where(norm > 0, out / np.where(norm > 0, norm, 1), 0.0)))


def _nested_first(cols, base, verdict: Candidate, cands: list[Candidate]) -> Candidate:
    """The nested rule: when the verdict contains a simpler significant candidate (the base model
    plus the verdict reproduces that candidate's columns exactly on these rows), the simpler one
    is proposed first; what the verdict adds beyond it is tested at the next step."""
    if verdict.fit is None:
        return verdict
    inner = [c for c in cands if c is not verdict and c.significant and c.fit is not None
             and c.n_params < verdict.n_params and nested_in(cols, base.model, verdict, c) < NESTED_RTOL]
    if not inner:
        return verdict
    simpler = min(inner, key=lambda c: (c.n_params, c.cv_sse.sum()))
    gap = 100 * abs(1 - np.sqrt(verdict.cv_sse.sum() / simpler.cv_sse.sum()))
    verdict.note = (f"contains {simpler.effect} (with the model's effects it reproduces {simpler.effect}'s columns "
                    f"exactly): the simpler {simpler.effect} ({simpler.n_params} parameters against "
                    f"{verdict.n_params}) is proposed first, although {verdict.effect}'s held-out error is "
                    f"{gap:.1f}% lower; what {verdict.effect} adds beyond it is tested at the next step")
    simpler.nested_in = verdict.effect
    simpler.note = (f"nested in {verdict.effect}, which fits {gap:.1f}% better held out: proposed first as the "
                    f"simpler explanation")
    return simpler


def _mark_overlaps(data, cols, base, verdict, cands, folds, min_reduction) -> None:
    """Other significant candidates that the verdict already accounts for."""
    if verdict.fit is None:
        return
    with_v = verdict.fit
    for c in cands:
        if c is verdict or not c.significant or c.fit is None:
            continue
        both = fitting.fit(data, with_v.model.with_effect(c.fit.model.get(c.effect)), columns=cols,
                           fixed=set(with_v.model.effect_names) | {c.effect})
        extra = 1 - both.rel_error / with_v.rel_error if with_v.rel_error > 0 else 0.0
        if extra < min_reduction:
            c.overlaps = verdict.effect
            gap = 100 * abs(1 - np.sqrt(verdict.cv_sse.sum() / c.cv_sse.sum()))
            head = (f"explains the same as {verdict.effect}: with {verdict.effect} in the model it removes only "
                    f"{100 * max(extra, 0):.1f}% more of the error; ")
            if verdict.nested_in == c.effect:
                c.note = head + c.note
            elif verdict.cv_sse.sum() <= c.cv_sse.sum():
                c.note = head + f"{verdict.effect} fits better (held-out error {gap:.1f}% lower)"
            else:
                c.note = head + (f"{c.effect} fits {gap:.1f}% better held out, within one standard error, so the "
                                 f"simpler {verdict.effect} ({verdict.n_params} parameters against {c.n_params}) is proposed")
