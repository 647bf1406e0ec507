"""The candidates of a diagnosis step: every effect the model lacks, as the effect allows
(`offered`), each judged over contiguous blocks of the recording (`judge`; a structural mode in
its own frequency band: `compliance`).

A candidate's evidence is typed (`Judged`, `Measured`); its report's `detail` is built from it.
A candidate is *significant* when its combined p (the score test of its columns and its held-out
errors, `manus.adaptive.diagnosis.significance`) is under the step's level, it predicts the
held-out blocks better than the model without it, and it is relevant: it explains at least
`min_share` of the recorded torque (RMS: √(e_before² − e_after²) in rel_error units), or removes
at least `MOST` of the current error (or, judged after every candidate by `verdict`, it is relevant
on a joint relative to what is left there). It is *proposable* when it is also physical: its fitted
parameters obey its effect's rules, its searched value does not sit on the edge of its search
range, and the recording can identify it (columns not already explained by the model's own).
Otherwise it is reported with the reason (`problems`), not proposed.

An effect that is an alternative to one the model holds (`Effect.replaces`: smooth friction,
whose limit w → 0 is Coulomb's sign) is searched and score-tested on top of it, and judged, fitted
and proposed in its place unless keeping both predicts the held-out blocks significantly better
(`judge`); its detail then says what it `replaces`.
"""

from __future__ import annotations

import contextlib
from dataclasses import dataclass, field, replace
from typing import ClassVar, NamedTuple

import numpy as np

from manus.adaptive.diagnosis import modes
from manus.adaptive.diagnosis.context import Context
from manus.adaptive.diagnosis.scores import block_scores, detectable, score_p
from manus.adaptive.diagnosis.significance import SIGNIFICANCE, combined, one_sided_p, score_blocks
from manus.adaptive.identify.columns import Columns
from manus.adaptive.identify.fit import model_from
from manus.adaptive.identify.prepare import align
from manus.adaptive.identify.result import Fit
from manus.adaptive.identify.search import Grid, delay_of, grid
from manus.plants.effects import ORDER, VOCABULARY, Effect, Model, Span

MODE_MIN_REDUCTION = 0.05  # a mode must remove this share of the frequency response's misfit
MOST = 0.5  # a candidate under `min_share` of the torque is relevant still when it removes this share of the error


@dataclass(frozen=True)
class Judged:
    """What a candidate judged by its columns (or, a delay, by its held-out errors) shows."""

    params: dict[str, float]  # its own parameters as fitted
    found: dict  # its non-linear parameter as found (`Effect.describe`)
    per_joint: list[float]  # per joint, the share of the model's error it removes
    brings: tuple[str, ...]  # the effects it brings with it (a spring's preload: the offset)
    held: tuple[str, ...]  # its parameters held at their physical bound
    explains: float  # the share of the recorded torque (RMS) it accounts for
    p_values: dict[str, float]  # per test of `SIGNIFICANCE` it took
    score_test: str | None = None  # how its score test's blocks were judged; None: no score test (a delay)
    detectable: float = np.inf  # the share of the torque (RMS) it would have to explain to be found (`detectable`)
    replaces: tuple[str, ...] = ()  # the model's effects it is proposed in place of (smooth friction: coulomb)

    @property
    def detection_limit(self) -> float | None:
        """`detectable` as reported: None without a score test or where nothing can be tested."""
        if self.score_test is None or not np.isfinite(self.detectable):
            return None
        return round(self.detectable, 5)

    def report(self) -> dict:
        """The candidate's `detail` in the JSON."""
        out: dict = {k: round(v, 6) for k, v in self.params.items()}
        out.update(self.found)
        out["per_joint_error_reduction"] = self.per_joint
        if self.brings:
            out["brings"] = list(self.brings)
        if self.replaces:
            out["replaces"] = list(self.replaces)
        if self.held:
            out["held_at_bound"] = list(self.held)
        out["explains"] = round(self.explains, 5)
        out["p_values"] = {k: float(f"{v:.3g}") for k, v in self.p_values.items()}
        if self.score_test is not None:  # how its blocks were judged (`score_p`) and how many there were
            out["score_test"] = self.score_test
            out["detectable"] = self.detection_limit
        return out


@dataclass(frozen=True)
class Measured:
    """What a structural mode shows in the measured frequency response (`modes.detect`)."""

    mode: modes.Mode
    band_hz: tuple[float, float]  # where the response was fitted (`modes.band`)
    brings: ClassVar[tuple[str, ...]] = ()
    detection_limit: ClassVar[None] = None  # (judged otherwise: no detection limit)

    def report(self) -> dict:
        """The candidate's `detail` in the JSON."""
        m = self.mode
        return {
            "f_hz": round(m.f_hz, 1),
            "zeta": m.zeta,
            "motor_fraction": round(m.motor_fraction, 3),
            "measured_in": "frequency response {:g}-{:g} Hz".format(*self.band_hz),
            "resonance_peak": m.resonant,
            "coherent_to_hz": round(m.coherent_hz, 1),
        }


@dataclass
class Candidate:
    """One effect judged as missing from the model; the verdict's choice writes its notes,
    aliases, readings and overlaps."""

    effect: str
    spec: str
    error_reduction: float
    cv_error_reduction: float
    p_value: float
    significant: bool
    joint: int  # 1-based: where its own parameters are most significant (else where it removes most)
    evidence: Judged | Measured
    n_params: int
    cv_sse: np.ndarray  # (blocks,) held-out squared error with the candidate
    fit: Fit | None = None
    mode: modes.Mode | None = None
    overlaps: str | None = None
    note: str = ""
    problems: list[str] = field(default_factory=list)  # why it is not proposed although significant
    aliases: list[str] = field(default_factory=list)  # candidates that are the same columns here
    readings: list[str] = field(default_factory=list)  # of the verdict: candidates that explain the same here

    @property
    def proposable(self) -> bool:
        """Significant, and nothing stops it from being proposed."""
        return self.significant and not self.problems

    def fitted(self) -> Fit:
        """The model with this candidate, fitted on every row (a structural mode, judged in its
        frequency band, has none)."""
        assert self.fit is not None, f"{self.effect} was judged in its frequency band: it has no fit"
        return self.fit

    def found(self) -> Effect:
        """Its effect with its non-linear parameter as found (in `fitted`'s model)."""
        e = self.fitted().model.get(self.effect)
        assert e is not None, f"{self.effect} is in its own fit"
        return e

    @property
    def brings(self) -> tuple[str, ...]:
        """The effects it brings with it."""
        return self.evidence.brings

    @property
    def detection_limit(self) -> float | None:
        """The share of the recorded torque (RMS) it would have to explain to be found 4 times in
        5 (None: judged otherwise)."""
        return self.evidence.detection_limit

    @property
    def detail(self) -> dict:
        """Its evidence as the report writes it."""
        return self.evidence.report()

    def report(self) -> dict:
        """The candidate in `manus diagnose`'s JSON."""
        out = {
            "effect": self.effect,
            "spec": self.spec,
            "joint": self.joint,
            "error_reduction": round(self.error_reduction, 4),
            "significant": self.significant,
            "detail": self.detail,
            "cv_error_reduction": round(self.cv_error_reduction, 4),
            "p_value": float(f"{self.p_value:.3g}"),
            "n_params": self.n_params,
        }
        if self.problems:
            out["not_proposed"] = self.problems
        if self.aliases:
            out["same_as"] = self.aliases
        if self.readings:
            out["reads_as"] = self.readings
        if self.overlaps:
            out["overlaps"] = self.overlaps
        if self.note:
            out["note"] = self.note
        return out


class Offer(NamedTuple):
    """A candidate as the model allows it (`offered`)."""

    effect: Effect  # the effect (its first value where its parameter is searched)
    values: tuple[Effect, ...]  # the values searched (one: nothing to search)
    brings: tuple[Effect, ...]  # the effects it brings that the model lacks
    replaces: tuple[str, ...] = ()  # the model's effects it may take the place of (`judge`)


def offered(model: Model, span: Span, prismatic) -> tuple[list[Offer], list[str]]:
    """Every candidate this model allows, and notes on those it does not: every effect of the
    vocabulary the model lacks (and one it holds that can grow: a cogging of one more order), as
    the effect itself allows: one that does not apply to these joints (gravity on a prismatic
    axis), or that is offered only on top of another the model lacks (Stribeck without Coulomb),
    is not tried; one that brings another with it (a spring's preload is an offset) is tried with
    it; one that is an alternative to an effect the model holds (smooth friction to Coulomb's sign)
    may take its place (`judge`), unless another effect of the model is offered only on top of
    that one (Stribeck on Coulomb)."""
    s = model.structure
    out, notes = [], []
    for name in ORDER:
        held = model.get(name)
        e0 = held if held is not None else VOCABULARY[name]()
        if held is not None:
            values = held.grow(span.of(held))
            if not values:
                continue
            e0 = values[0]
        else:
            values = e0.space(span.of(e0)) if not e0.modal else ()
            if not (e0.modal or e0.timing) and not values and type(e0).space is not Effect.space:
                notes.append(
                    f"{name}: the recording spans too little to search its parameter (travel or speed too small)"
                )
                continue
            values = values or (e0,)
        why = e0.applies(s, prismatic)
        if why:
            notes.append(f"{name}: not tried: {why}")
            continue
        lacking = [r for r in e0.requires if not model.has(r)]
        if lacking:
            notes.append(
                f"{name}: offered only on top of {', '.join(lacking)} (otherwise it would be "
                f"{', '.join(lacking)} under another name)"
            )
            continue
        brought = tuple(VOCABULARY[b]() for b in e0.brings if not model.has(b))
        replaced = tuple(r for r in e0.replaces if model.has(r) and not any(r in e.requires for e in model.effects))
        out.append(Offer(e0, tuple(values), brought, replaced))
    return out, notes


def columns_ahead(cols: Columns, model: Model | str) -> contextlib.AbstractContextManager[None]:
    """The columns `judge` will search on top of `model` (every linear effect it lacks, each with
    the values of its space, in the order they are judged), computed beside the block that fits
    the model (`Columns.ahead`). An effect the model holds that can grow is left to its step: its
    values follow the fit."""
    m, _ = model_from(model, cols.data.rec.structure)
    offers, _ = offered(m, cols.data.span(), cols.data.rec.prismatic)
    return cols.ahead([list(o.values) for o in offers if o.effect.linear and not m.has(o.effect.name)])


def judge(ctx: Context, offer: Offer) -> Candidate:
    """One candidate: searched inside each fold, judged on the held-out blocks, fitted on every row.
    A parameter of its own that breaks its physical bound on some joint (a Stribeck level on a
    joint without one) is held at the bound and the candidate judged again without it; the
    candidate breaks physics only when nothing of it is left.

    Its p combines the score test of its columns (the largest statistic over its search space,
    the values whose fit within its physical bounds leaves something off them; one-sided in the
    coefficients its physics signs) and its held-out errors (for each block, its non-linear
    parameter searched and the model fitted on the other blocks only); a delay, which moves the
    torque and has no columns, takes the held-out errors alone.

    A candidate that may replace effects of the model (`Offer.replaces`: smooth friction, whose
    limit w → 0 is Coulomb's sign) is searched and score-tested on top of them (does the recording
    show a finite width beyond the sign?), then judged in their place: the model without them
    predicts the held-out blocks with it (its width chosen in each fold as before), and it is
    proposed there unless keeping them predicts significantly better (`_in_place`)."""
    data, cols, base = ctx.data, ctx.cols, ctx.base
    e0, values, brought, replaceable = offer
    s = base.model.structure
    rest = base.model
    for b in brought:
        rest = rest.with_effect(b)
    under = rest.without(e0.name) if base.model.has(e0.name) else rest
    train, test = ctx.train, ctx.test
    held: tuple = ()
    for _ in range(2):
        keep = np.array([k not in held for k in e0.names(s)]) if held else None
        # (a linear candidate's score test needs every value's statistics: the search uses them too)
        g = grid(data, cols, under, e0, ctx.starts, values, ctx.icols, keep, exact=e0.linear, base=ctx.stats(under))
        # the search inside each fold, on its training blocks; its held-out error (within the bounds the choice
        # was made in)
        chosen_in, sse = g.held_out(train, test)
        best, errs = g.choose(ctx.whole)
        chosen = g.values[best]
        f = ctx.fit(under.with_effect(chosen), held)
        own_names = [k for k in chosen.names(s) if k not in held]
        bad = [k for k in chosen.beyond_bounds(s, f.params, f.stds) if k in own_names]
        if held or not bad or len(bad) == len(own_names):
            break
        held = tuple(bad)
    if len(values) > 1:
        yy = float(np.sum(data.tau(delay_of(rest)) ** 2)) or 1.0
        f = replace(f, search={e0.name: ([v.describe() for v in values], np.sqrt(np.maximum(errs, 0) / yy))})
    tests: dict[str, float] = {}
    score_test, limit = None, np.inf
    if e0.linear:  # its columns' score, judged over the blocks (the search redone in each draw)
        names = list(under.names) + [k for k in chosen.names(s) if k not in held]
        tested = np.array([k not in base.model.names for k in names])
        groups = score_blocks(ctx.folds, data, f.residual)
        # the values searched whose fit leaves some of the candidate's columns off their physical
        # bound (the others explain nothing physical: their statistic would be the wrong sign's)
        free = g.free(ctx.whole)
        scores = [block_scores(g.exact(i), tested, groups) for i in range(len(g.values))]
        assert g.lower is not None, "a linear effect's grid holds its bounds"
        signed = np.isfinite(g.lower)[tested]  # (its columns whose physics fixes their sign: a one-sided test)
        judged = [x for x, ok in zip(scores, free, strict=True) if ok]
        tests["score"], _, how = score_p(judged, ctx.alpha / len(SIGNIFICANCE), signed=signed)
        score_test = f"{how}, {groups.shape[0]} blocks"
        # the share of the torque it would have to explain to be found (80 %), and to count
        share = detectable(scores, ctx.alpha / len(SIGNIFICANCE)) / max(float(g.exact(0).yy.sum()), 1e-300)
        limit = max(float(np.sqrt(share)), ctx.min_share)
    replaces, swap = (), ""
    if replaceable:
        replaces, swap, swapped = _in_place(ctx, under, replaceable, g, chosen_in, chosen, held, sse)
        if swapped is not None:
            f, sse = replace(swapped[0], search=f.search), swapped[1]
    reduction = 1 - f.rel_error / base.rel_error if base.rel_error > 0 else 0.0
    cv_red = 1 - float(np.sqrt(sse.sum() / ctx.base_sse.sum())) if ctx.base_sse.sum() > 0 else 0.0
    tests["held_out"] = one_sided_p(ctx.base_sse, sse)
    p = combined(tests)
    own = [chosen, *brought]
    names = [n for e in own for n in e.names(s) if n not in held]
    n_params = len(names) + (1 if len(values) > 1 else 0)
    base_joint = np.sum(base.residual**2, axis=0)
    per_joint = [
        round(1 - float(np.sqrt(np.sum(f.residual[:, i] ** 2) / base_joint[i])), 4) if base_joint[i] > 0 else 0.0
        for i in range(data.n_joints)
    ]
    explained = float(np.sqrt(max(base.rel_error**2 - f.rel_error**2, 0.0)))
    evidence = Judged(
        {k: v for k, v in f.params.items() if k in names},
        chosen.describe(),
        per_joint,
        tuple(b.name for b in brought),
        held,
        explained,
        tests,
        score_test,
        limit,
        replaces,
    )
    significant = bool(p < ctx.alpha and (explained >= ctx.min_share or reduction >= MOST) and cv_red > 0)
    problems = [v for e in own for v in e.violations(s, f.params, f.stds)]
    edge = chosen.edge(ctx.span.of(chosen)) if len(values) > 1 else None
    if edge:
        problems.append(edge)
    lost = [n for n in names if n in f.redundant]
    if lost:
        problems.append(
            f"not identifiable from this recording: {', '.join(lost)} "
            f"{'is' if len(lost) == 1 else 'are'} explained by the model's own columns on these rows"
        )
    spec = ",".join(e.spec for e in (*brought, chosen))
    note = (
        (
            f"{', '.join(held)} held at {'its' if len(held) == 1 else 'their'} physical bound (fitted free, "
            f"{'it breaks' if len(held) == 1 else 'they break'} the effect's rule)"
        )
        if held
        else ""
    )
    note = "; ".join(x for x in (note, swap) if x)
    joint = _own_joint(cols, f, own, data.n_joints)
    joint = int(np.argmax(per_joint)) if joint is None else joint
    return Candidate(
        e0.name,
        chosen.spec if not brought else spec,
        reduction,
        cv_red,
        p,
        significant,
        joint + 1,
        evidence,
        n_params,
        sse,
        fit=f,
        problems=problems,
        note=note,
    )


def _in_place(
    ctx: Context,
    under: Model,
    replaceable: tuple[str, ...],
    g: Grid,
    chosen_in: np.ndarray,
    chosen: Effect,
    held: tuple,
    sse: np.ndarray,
) -> tuple[tuple[str, ...], str, tuple[Fit, np.ndarray] | None]:
    """The candidate in place of the model's effects `replaceable` (see `judge`): the model
    without them, with the candidate's value chosen in each fold by the search on top of them,
    fitted within its bounds on the fold's training blocks and judged on its block, against the
    model keeping them (fitted within their bounds too). Returns (the effects it replaces, a note,
    (its fit on every row, its held-out errors) or None where keeping them predicts the held-out
    blocks significantly better, one-sided at the step's level)."""
    s = under.structure
    reduced = under
    for r in replaceable:
        reduced = reduced.without(r)
    keep = np.array([k not in held for k in chosen.names(s)])
    bounds = np.asarray(chosen.lower_bounds(s), float)[keep]
    base = ctx.stats(reduced)
    lower = np.r_[np.full(len(reduced.names), -np.inf), bounds]
    train, test = ctx.train, ctx.test
    alone = np.zeros(len(ctx.folds))
    for i in np.unique(chosen_in):
        v = g.values[i]
        ez = None if ctx.icols is None else ctx.icols.effect(v)[..., keep]
        st, on = base.extend(ctx.cols.effect(v)[..., keep], ez), chosen_in == i
        alone[on] = st.sses(st.coefs(train[on], lower), test[on])
    # keeping them, each fold's fit within their bounds too (Coulomb's level below zero is no sharp core)
    assert g.lower is not None, "a linear effect's grid holds its bounds"
    both = g.lower.copy()
    for r in replaceable:
        e = under.get(r)
        assert e is not None, f"{r} is in the model it may be replaced in"
        for k, lo in zip(e.names(s), e.lower_bounds(s), strict=True):
            both[under.names.index(k)] = lo
    kept = np.zeros(len(ctx.folds))
    for i in np.unique(chosen_in):
        st, on = g.exact(int(i)), chosen_in == i
        kept[on] = st.sses(st.coefs(train[on], both), test[on])
    names = ", ".join(replaceable)
    p = one_sided_p(alone, kept)
    if p < ctx.alpha:
        note = (
            f"{names} kept beside it: together they predict the held-out blocks significantly better than "
            f"{chosen.spec} in {'its' if len(replaceable) == 1 else 'their'} place (p {p:.2g})"
        )
        return (), note, None
    note = (
        f"in place of {names}: with {chosen.spec} in the model, {names} predicts the held-out blocks no "
        f"better (p {p:.2g})"
    )
    return tuple(replaceable), note, (ctx.fit(reduced.with_effect(chosen), held), alone)


def _own_joint(cols: Columns, f: Fit, own: list[Effect], n: int) -> int | None:
    """The joint (0-based) whose own parameters of the candidate are the most significant: the
    sum of (θ/σ)² over the parameters whose column acts on that joint alone. Where the residual
    falls on every joint (in a coupled chain a missing term bends the shared inertial parameters,
    and every joint's error drops), this still names where the effect acts. None when no
    parameter belongs to one joint (a delay; the arm's coupling term): the caller falls back on
    the per-joint error reduction."""
    score = np.zeros(n)
    for e in own:
        if not e.linear:
            continue
        on = np.abs(cols.effect(e)).max(axis=0) > 0  # (n, p): the joints each column acts on
        for k, name in enumerate(e.names(f.model.structure)):
            joints = np.flatnonzero(on[:, k])
            v, sd = f.params.get(name), f.stds.get(name)
            if joints.size == 1 and v is not None and sd is not None and np.isfinite(sd) and sd > 0:
                score[joints[0]] += (v / sd) ** 2
    return int(np.argmax(score)) if score.max() > 0 else None


def compliance(ctx: Context) -> Candidate | str:
    """The structural mode (`compliance`), judged in the frequency band where it lives
    (`manus.adaptive.diagnosis.modes`: the measured response's fit with the mode against the
    rigid one over its own blocks); where the recording cannot show one, why (a sentence)."""
    data, delay = ctx.data, ctx.base.delay
    mode = data.once(  # (the same at every step of a loop: the recording's, at the model's delay)
        ("mode", np.asarray(delay, float).tobytes()),
        lambda: modes.detect(  # its own blocks: the frequency resolution needs long ones
            data.rec.q,
            align(data.rec.tau, delay / data.dt),  # (the hold is part of `modes.sampling`)
            data.dt,
        ),
    )
    if isinstance(mode, str):
        return mode
    p = one_sided_p(mode.err_rigid, mode.err_mode)
    significant = bool(mode.resonant and p < ctx.alpha and mode.reduction >= MODE_MIN_REDUCTION)
    note = "" if mode.resonant else "no resonance peak in the measured response: no evidence of a mode"
    short = "" if mode.resonant else modes.coherent_only(mode.coherent_hz, 1 / data.dt)
    if short:
        note += f"; the response is {short}: a mode above that cannot show"
    problems = [why for why in (mode.edge(),) if why]
    return Candidate(
        mode.effect().name,
        mode.effect().spec,
        mode.reduction,
        mode.reduction,
        p,
        significant,
        mode.joint + 1,
        Measured(mode, modes.band(1 / data.dt)),
        2,
        mode.err_mode,
        mode=mode,
        note=note,
        problems=problems,
    )
