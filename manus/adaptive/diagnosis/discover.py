"""The discovery loop (`manus discover`): diagnose, add the verdict, refit, repeat.

Starting from a model, each step diagnoses the current fit (`manus.adaptive.diagnosis.verdict`), adds the
verdict's effect with its non-linear parameter as found (its spec, e.g. `cogging:39` or
`delay:1ms`) and refits, the searched parameters the loop found searched again with the new
effect in the model (`_refine`: a cogging order chosen while a smooth load was missing can be
off by a few; the values a user gave stay as written). A step must change the error: on the
diagnosis's own held-out blocks, the refitted model must remove a relevant share of the error, as
a candidate must (`kept`: `min_share` of the torque, half of the error, or on a joint a relevant
share of what is left there). A step that does not is undone, said in the notes, and the next
significant candidate of the same diagnosis is tried (by held-out error). The loop stops when no
significant candidate is left (the verdict is null), when none of them changes the error, after
`max_steps` additions, or when only a structural mode is left: it lives above the identification
band and has no inverse-dynamics columns, so it is recorded as a step (with the frequency
response's f and ζ) but cannot be refitted, and the loop ends there.

The recording is prepared once (`manus.adaptive.identify.prepare`): every step sees the same
rows, so the errors of successive steps are comparable.
"""

from __future__ import annotations

from collections.abc import Callable
from dataclasses import dataclass, field

import numpy as np

from manus.adaptive.diagnosis.candidates import MOST, Candidate, columns_ahead
from manus.adaptive.diagnosis.significance import held_out_per_joint, on_joints
from manus.adaptive.diagnosis.verdict import Diagnosis, diagnose
from manus.adaptive.identify.columns import Columns
from manus.adaptive.identify.fit import fit, model_from
from manus.adaptive.identify.prepare import Data, prepare
from manus.adaptive.identify.result import Fit
from manus.plants.errors import ModelError
from manus.plants.recording import Recording

MAX_STEPS = 6


@dataclass
class Step:
    """One addition: the effect, its fitted parameters, the error after, and the diagnosis that
    proposed it (whose `base` is the fit before the addition; its verdict, or the next significant
    candidate where the verdict changed nothing and was undone)."""

    index: int  # 1-based
    effect: str
    spec: str
    params: dict  # the added effect's linear parameters (value, std) and non-linear ones
    rel_error_before: float
    rel_error: float  # after the refit (unchanged for compliance, which is not refitted)
    model: str  # the model's spec after the addition
    diagnosis: Diagnosis
    fit: Fit | None  # the refit (None for compliance)
    note: str = ""
    added: Candidate | None = None  # the candidate added, where it is not the diagnosis's verdict (that one was undone)

    @property
    def verdict(self) -> Candidate:
        """The candidate the step added."""
        v = self.added or self.diagnosis.verdict
        assert v is not None, "a step adds a candidate of its diagnosis"
        return v

    def report(self) -> dict:
        """The step in `manus discover`'s JSON."""
        out = {
            "step": self.index,
            "effect": self.effect,
            "spec": self.spec,
            "params": self.params,
            "rel_error_before": self.rel_error_before,
            "rel_error": self.rel_error,
            "model": self.model,
            "error_reduction": self.verdict.error_reduction,
            "p_value": self.verdict.p_value,
            "candidates": [c.report() for c in self.diagnosis.candidates],
            "judged_by": self.diagnosis.judged_by,
        }
        if self.note:
            out["note"] = self.note
        return out


@dataclass(repr=False)
class Discovery:
    """The loop's run: the starting fit, its steps, the last diagnosis and why it stopped."""

    start: Fit  # the starting model, fitted
    steps: list[Step]
    final: Diagnosis | None  # the last diagnosis (its verdict null unless the loop was capped)
    # "nothing significant missing" | "nothing significant changes the error" | "step cap"
    # | "compliance (not refitted)" | "every effect in the model"
    stopped: str
    notes: list[str] = field(default_factory=list)

    def __repr__(self) -> str:
        """One line (`report()` holds the steps)."""
        return f"<Discovery {self.model}: {len(self.steps)} steps, stopped: {self.stopped}>"

    @property
    def unexplained(self) -> dict:
        """What the last diagnosis found left in the residual that no effect explains."""
        last = self.final or (self.steps[-1].diagnosis if self.steps else None)
        return last.unexplained if last is not None else {}

    @property
    def model(self) -> str:
        """The final model's spec."""
        return self.steps[-1].model if self.steps else self.start.model.spec

    @property
    def rel_error(self) -> float:
        """The final model's rel_error."""
        return self.steps[-1].rel_error if self.steps else self.start.rel_error

    @property
    def final_fit(self) -> Fit:
        """The final model's fit."""
        fits = [s.fit for s in self.steps if s.fit is not None]
        return fits[-1] if fits else self.start

    def report(self) -> dict:
        """The JSON contract of `manus discover` (docs/cli.md)."""
        return {
            "start": {"model": self.start.model.spec, "rel_error": self.start.rel_error},
            "steps": [s.report() for s in self.steps],
            "model": self.model,
            "rel_error": self.rel_error,
            "rel_error_per_joint": self.final_fit.rel_error_per_joint,
            **({"consistency": self.final_fit.consistency_report()} if self.final_fit.consistency else {}),
            "stopped": self.stopped,
            "samples": int(self.start.data.rows.size),
            "cutoff_hz": self.start.data.cutoff_hz,
            "hold": self.start.data.hold,
            "method": self.final_fit.method,
            "method_why": self.final_fit.why,
            "params": self.final_fit.report()["params"],
            "unexplained": self.unexplained,
            "detection_limits": self.final.detection_limits if self.final is not None else {},
            **({"judged_by": self.final.judged_by} if self.final is not None else {}),
            "notes": self.notes,
        }


def effect_params(f: Fit, effect: str) -> dict:
    """The fitted parameters of one effect of `f`: {name: {"value", "std"}} plus its
    non-linear parameters (order, vs, delay_ms) as plain numbers."""
    e = f.model.get(effect)
    assert e is not None, f"{effect} is in the fitted model"
    report = f.report()["params"]
    out = {k: report[k] for k in e.names(f.model.structure)}
    for b in e.brings:  # what it brought with it (a spring's preload: the offset)
        brought = f.model.get(b)
        if brought is not None:
            out.update({k: report[k] for k in brought.names(f.model.structure)})
    out.update(e.describe())
    return out


def _refine(data: Data, cols: Columns, current: Fit, given: set[str], method: str) -> tuple[Fit, str]:
    """The model's searched non-linear parameters searched again, each with every other effect
    in the model (a cogging order found while a smooth load was still missing can be off by a
    few). Values the user gave, and grown ones outside their effect's search space (a delay per
    joint, several cogging orders), stay. The refit is kept when it fits better and no value
    lands on the edge of its range. Returns the fit and what moved ("" when nothing)."""
    span = data.span()
    grids = {e.name: {v.spec for v in e.space(span.of(e))} for e in current.model.effects if e.name not in given}
    free = [e for e in current.model.effects if len(grids.get(e.name, ())) > 1 and e.spec in grids[e.name]]
    if not free:
        return current, ""
    keep = {e.name for e in current.model.effects} - {e.name for e in free}
    again = fit(data, current.model, fixed=keep, columns=cols, method=method)
    found = [(e, again.model.get(e.name)) for e in free]
    changed = [(a, b) for a, b in found if b is not None and b.spec != a.spec]
    if not changed or not again.rel_error < current.rel_error or any(b.edge(span.of(b)) for _, b in changed):
        return current, ""
    return again, ", ".join(f"{a.spec} -> {b.spec}" for a, b in changed)


def to_try(d: Diagnosis) -> list[Candidate]:
    """The candidates a step may add, in the order it tries them: the verdict, then the other
    proposable candidates by held-out error, a structural mode (which removes nothing from the
    torque error) last."""
    if d.verdict is None:
        return []
    rest = [c for c in d.candidates if c.proposable and c is not d.verdict and c.effect not in d.verdict.aliases]
    rest.sort(key=lambda c: (c.mode is not None, float(np.sum(c.cv_sse))))
    return [d.verdict, *rest]


def kept(d: Diagnosis, before: Fit, after: Fit) -> tuple[bool, str]:
    """Whether the step from `before` to `after` changes the error, on the held-out blocks of the
    diagnosis `d` that proposed it, as a candidate must to count: it removes `min_share` of the
    torque (RMS), `MOST` of the error, or on a joint a relevant share of what is left there
    (`OnJoint.relevant` at the diagnosis's level); and what it changed (a phrase)."""
    ctx = d.context
    assert ctx is not None, "a diagnosis keeps the context it judged in"
    if d.judged is not None:  # judged by output error: its held-out position errors
        return d.judged.kept(after, ctx.min_share)
    b = held_out_per_joint(ctx.stats(before.model, before.delay), ctx.folds)
    a = held_out_per_joint(ctx.stats(after.model, after.delay), ctx.folds)
    torque = np.sum(ctx.data.tau(before.delay) ** 2, axis=0)
    sb, sa, yy = float(b.sum()), float(a.sum()), float(torque.sum()) or 1.0
    share = float(np.sqrt(max(sb - sa, 0.0) / yy))
    removed = 1 - float(np.sqrt(sa / sb)) if sb > 0 else 0.0
    said = f"held-out error {100 * np.sqrt(sb / yy):.3g} % -> {100 * np.sqrt(sa / yy):.3g} %"
    if sa < sb and (share >= ctx.min_share or removed >= MOST):
        return True, said
    there = [j for j in on_joints(b, a, torque) if j.relevant(d.alpha, ctx.min_share)]
    if sa < sb and there:
        return True, f"{said}; {max(there, key=lambda j: j.left).says()}"
    return False, said


def discover(
    rec: Recording | Data,
    model: str,
    cutoff_hz: float | None = None,
    max_steps: int = MAX_STEPS,
    progress: Callable[[str], None] | None = None,
    method: str = "auto",
    on_step: Callable[[Step], None] | None = None,
    **diagnose_options,
) -> Discovery:
    """Run the loop from `model` (text, e.g. "rigid,viscous,coulomb"). `progress` receives a line
    per step; `on_step` each step as it is added (its figure may be drawn while the loop goes
    on); `diagnose_options` go to `diagnose` (blocks, alpha, min_share, told)."""
    if max_steps < 1:
        raise ModelError(f"max_steps must be at least 1 (got {max_steps})")
    say = progress or (lambda line: None)
    added = on_step or (lambda step: None)
    data = rec if isinstance(rec, Data) else prepare(rec, cutoff_hz)
    cols = Columns(data)
    with columns_ahead(cols, model):  # (the first diagnosis's candidates' columns, beside the fit)
        start = fit(data, model, columns=cols, method=method, readings=True)
    given = model_from(model, data.rec.structure)[1]  # values the user wrote stay as written
    current = start
    spec = start.model.spec
    steps: list[Step] = []
    notes: list[str] = [data.lost] if data.lost else []
    say(f"start: {spec}, rel_error {100 * start.rel_error:.2f} %")
    while True:
        try:
            d = diagnose(data, spec, columns=cols, method=method, fitted=current, **diagnose_options)
        except ModelError as e:
            if steps and "already holds every effect" in str(e):
                notes.append(str(e))
                return Discovery(start, steps, None, "every effect in the model", notes)
            raise
        if d.verdict is None:
            say(f"step {len(steps) + 1}: nothing significant is missing")
            return Discovery(start, steps, d, "nothing significant missing", notes)
        if len(steps) >= max_steps:
            say(f"step cap ({max_steps}) reached; the next verdict would be {d.verdict.spec}")
            notes.append(f"stopped at the step cap ({max_steps}); the next verdict was {d.verdict.spec}")
            return Discovery(start, steps, d, "step cap", notes)
        before = current.rel_error
        tried = None
        for v in to_try(d):
            if v.mode is not None:
                break
            trial = (  # its effect as found (judged by positions: the OE fit it was judged by)
                v.fitted() if d.judged is not None else fit(data, v.fitted().model.spec, columns=cols, method=method)
            )
            trial, moved = _refine(data, cols, trial, given, method)
            keep, said = kept(d, current, trial)
            if keep:
                tried = (v, trial, moved)
                break
            notes.append(
                f"step {len(steps) + 1}: {v.spec} undone, it does not change the error ({said}); "
                "the next significant candidate is tried"
            )
            say(f"step {len(steps) + 1}: + {v.spec} changes nothing ({said}): undone")
        else:
            return Discovery(start, steps, d, "nothing significant changes the error", notes)
        if tried is None:  # a structural mode: measured in its own band, no columns
            params = dict(v.detail)
            steps.append(
                Step(
                    len(steps) + 1,
                    v.effect,
                    v.spec,
                    params,
                    before,
                    before,
                    f"{spec},{v.spec}",
                    d,
                    None,
                    "a structural mode found in the frequency response above the identification band; "
                    "it has no inverse-dynamics columns, so the torque error is unchanged",
                    v,
                )
            )
            say(f"step {len(steps)}: + {v.spec} (frequency response; not refitted)")
            added(steps[-1])
            return Discovery(start, steps, None, "compliance (not refitted)", notes)
        v, current, moved = tried
        spec = current.model.spec
        steps.append(
            Step(
                len(steps) + 1,
                v.effect,
                v.spec,
                effect_params(current, v.effect),
                before,
                current.rel_error,
                spec,
                d,
                current,
                f"searched again with {v.effect} in the model: {moved}" if moved else "",
                v,
            )
        )
        say(f"step {len(steps)}: + {v.spec}, rel_error {100 * before:.2f} % -> {100 * current.rel_error:.2f} %")
        added(steps[-1])
