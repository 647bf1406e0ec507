"""Every estimator over one recording: scored against the truth (or the offline reference), and
optionally each one's knob tuned on the recording first. What `manus estimators` reports.

Tuning searches the knob of `registry.KNOBS` (rescaled to the recording's encoder step) on a log
grid of 13 points, then twice more on 13 points between the neighbours of the best one (a
resolution of ~1/50 of the range); every grid is one vectorised scan of the estimator over the
recording, compiled once. The criterion is the RMS error against the true velocity when the
recording has one; without it, the whiteness of the estimator's one-step prediction residual
(`scoring.whiteness`), which needs no reference at all, rather than the offline estimate, which
would reward whichever estimator imitates the offline filter's own smoothing.

The model-based estimators (`registry.MODEL_BASED`) run on the model `compare` is handed
(`EstimatorModel`: the model, every one of its parameters, and where they came from, which the
report states under "model"). `manus estimators` hands it a model fitted to the recording, or
one a fit's JSON gives (`manus.runs.cmd_estimators`: identification, `manus.adaptive`, is a
layer above this one). Where the model says why there is none (`EstimatorModel.refused`: the fit
was refused; or its parameters break physics), the model-based estimators are left out of the
ranking, each with that reason (the report's "left_out"), and the others still ranked. Called
without a model, `compare` runs them on the nominal model's own parameters, and the report says
that model was not fitted.
"""

from __future__ import annotations

import math
from dataclasses import dataclass, field
from typing import NamedTuple

import equinox as eqx
import jax
import jax.numpy as jnp
import numpy as np

from manus.estimators import offline, scoring
from manus.estimators.base import run
from manus.estimators.linear import THESIS_STEP
from manus.estimators.registry import MODEL_BASED, NAMES, NOMINAL_MODEL, knob_range, make
from manus.plants.effects import Model
from manus.plants.errors import ManusError
from manus.plants.gaps import gaps, on_grid, spoiled
from manus.plants.recording import Recording, smallest_step

START_SECONDS = 0.1  # skipped when scoring: every estimator starts from rest
GRID_POINTS, GRID_ROUNDS = 13, 3


def encoder_step(rec: Recording) -> tuple[float, str]:
    """(Δ, where it came from): the metadata, else the grid the positions sit on, else an
    equivalent step √12 σ from the measurement noise σ above 100 Hz (unquantized data)."""
    if rec.position_step:
        return rec.position_step, "metadata"
    q = rec.q - rec.q[0]
    step = smallest_step(q)
    if step and np.all(np.abs(q / step - np.round(q / step)) < 1e-3):
        return step, "grid"
    noise = np.std(rec.q - offline.lowpass(rec.q, rec.dt, min(100.0, 0.4 / rec.dt)), axis=0).max()
    if not noise > 0:
        return THESIS_STEP, "default"
    return float(math.sqrt(12) * noise), "noise"


FITTED = "fitted on this recording"
NOT_FITTED = "the nominal model's own parameters (not fitted to this recording)"


@dataclass
class EstimatorModel:
    """The model the model-based estimators run on: `model` with every parameter in `params`,
    and where they came from (`origin`: "fitted on this recording", a fit's JSON file, "--param",
    or `NOT_FITTED`), with the fit's torque `rel_error` and `method` where there was one, and the
    names `--param` set by hand (`by_hand`), and the fitted value of each parameter set at its
    physical bound (`at_bound`: below it by less than two standard deviations). Or, `refused`,
    why there is none: the model-based estimators are then left out of the ranking with that
    reason."""

    origin: str
    spec: str
    model: Model | None = None
    params: dict[str, float] = field(default_factory=dict)
    rel_error: float | None = None
    method: str | None = None
    by_hand: tuple[str, ...] = ()
    at_bound: dict[str, float] = field(default_factory=dict)
    refused: str | None = None

    @classmethod
    def nominal(cls, rec: Recording) -> EstimatorModel:
        """rigid,viscous,coulomb of the recording's structure at its defaults: fitted to nothing."""
        model = Model(rec.structure, NOMINAL_MODEL)
        return cls(NOT_FITTED, model.spec, model, model.defaults())

    def why_not(self) -> str | None:
        """Why the model-based estimators cannot run on this model (None: they can)."""
        if self.refused or self.model is None:
            return self.refused or "no model"
        absent = [k for k in self.model.names if k not in self.params]
        if absent:
            return f"the model {self.spec} lacks the parameter(s) {', '.join(absent)}"
        bad = self.model.violations(self.params)
        if bad:  # a model that breaks physics predicts nothing an estimator can follow
            return f"the model's parameters ({self.origin}) break physics: {'; '.join(bad)}"
        return None

    def knobs(self) -> dict:
        """What `registry.make` takes for the model-based estimators."""
        return {"model": self.model, "params": self.params}

    def report(self) -> dict:
        """The report's "model": where it came from, its spec, parameters and fit (or why there is none)."""
        out: dict = {"from": self.origin, "spec": self.spec}
        why = self.why_not()
        if why:
            return {**out, "error": why}
        out["params"] = {k: float(v) for k, v in self.params.items()}
        out["rel_error"] = self.rel_error
        if self.method:
            out["method"] = self.method
        if self.by_hand:
            out["set_by_hand"] = list(self.by_hand)
        if self.at_bound:
            out["at_bound"] = {k: float(v) for k, v in self.at_bound.items()}
        return out


@dataclass
class Setup:
    """What every estimator on this recording shares."""

    dt: float
    step: float
    n_joints: int
    model_knobs: dict = field(default_factory=dict)  # model=, params=, structure= for the model-based

    def make(self, name: str, **knobs):
        extra = self.model_knobs if name in MODEL_BASED else {}
        return make(name, dt=self.dt, n_joints=self.n_joints, step=self.step, **extra, **knobs)


_run = eqx.filter_jit(run)
_run_batch = eqx.filter_jit(eqx.filter_vmap(run, in_axes=(eqx.if_array(0), None, None)))


def _stack(modules):
    """Estimators differing only in array values -> one with a leading batch axis on them."""
    static = eqx.partition(modules[0], eqx.is_array)[1]
    stacked = jax.tree.map(lambda *xs: jnp.stack(xs), *[eqx.filter(m, eqx.is_array) for m in modules])
    return eqx.combine(stacked, static)


class HostEstimate(NamedTuple):
    """An estimator's output over a recording, on the host (numpy)."""

    q: np.ndarray
    qd: np.ndarray
    qdd: np.ndarray | None = None


def run_estimator(estimator, q: np.ndarray, tau: np.ndarray) -> HostEstimate:
    out = _run(estimator, jnp.asarray(q), jnp.asarray(tau))
    return HostEstimate(np.asarray(out.q), np.asarray(out.qd), None if out.qdd is None else np.asarray(out.qdd))


def tune(
    setup: Setup, name: str, q: np.ndarray, tau: np.ndarray, reference: np.ndarray | None, start: int, stop: int
) -> dict | None:
    """The best knob value of estimator `name` on (q, tau): against `reference` (the truth) when
    given, else by whiteness. Returns {"knob", "value", "criterion", "objective", "at_limit"} (the
    best value at an end of the searched range: the optimum may lie beyond it) or None."""
    spec = knob_range(name, setup.step)
    if spec is None:
        return None
    knob, low, high, log = spec
    to, back = (np.log, np.exp) if log else ((lambda x: x), (lambda x: x))
    lo, hi = to(low), to(high)
    best: tuple[float, float] | None = None
    for _ in range(GRID_ROUNDS):
        values = back(np.linspace(lo, hi, GRID_POINTS))
        out = _run_batch(
            _stack([setup.make(name, **{knob: float(v)}) for v in values]), jnp.asarray(q), jnp.asarray(tau)
        )
        if reference is not None:
            objective = np.sqrt(np.mean((np.asarray(out.qd)[:, start:stop] - reference[start:stop]) ** 2, axis=(1, 2)))
        else:
            eps = scoring.prediction_residual(
                q[start:stop],
                np.asarray(out.q)[:, start:stop],
                np.asarray(out.qd)[:, start:stop],
                None if out.qdd is None else np.asarray(out.qdd)[:, start:stop],
                setup.dt,
            )
            objective = scoring.whiteness(eps)
        objective = np.where(np.isfinite(objective), objective, np.inf)
        i = int(np.argmin(objective))
        best = (float(values[i]), float(objective[i]))
        spacing = (hi - lo) / (GRID_POINTS - 1)
        lo, hi = max(to(low), to(values[i]) - spacing), min(to(high), to(values[i]) + spacing)
    assert best is not None  # GRID_ROUNDS > 0
    at_limit = bool(np.isclose(best[0], low, rtol=1e-9) or np.isclose(best[0], high, rtol=1e-9))
    return {
        "knob": knob,
        "value": best[0],
        "criterion": "rms_error" if reference is not None else "whiteness",
        "objective": best[1],
        "at_limit": at_limit,
    }


def reference_velocity(rec: Recording, cutoff_hz: float) -> tuple[np.ndarray, bool, int, int]:
    """(reference velocity, is it the truth, first and last+1 sample to score)."""
    start = int(round(START_SECONDS / rec.dt))
    if rec.qd is not None:  # the recording has the truth
        return rec.qd, True, start, len(rec)
    edge = offline.edge(rec.dt, cutoff_hz)
    return offline.differentiate(rec.q, rec.dt, cutoff_hz)[1], False, max(start, edge), len(rec) - edge


def compare(
    rec: Recording,
    names=NAMES,
    tune_knobs: bool = False,
    cutoff_hz: float = 30.0,
    model: EstimatorModel | None = None,
    progress=None,
) -> tuple[dict, dict]:
    """Run and score every estimator in `names` on the recording, the model-based ones on `model`
    (default: `EstimatorModel.nominal`, which the report says was not fitted; where `model` says
    why there is none, they are left out of the ranking with that reason, under "left_out").

    Returns (report, estimates): the report is JSON-ready (docs/cli.md), `estimates[name]` the
    velocity estimate (T, n) of each estimator ranked, with `estimates["reference"]` the reference.
    """
    unknown = [n for n in names if n not in NAMES]
    if unknown:
        raise ManusError(f"unknown estimator {unknown[0]!r}: the estimators are {', '.join(NAMES)}")
    if len(rec) < 50:
        raise ManusError(f"{rec.path}: {len(rec)} samples are too few to compare estimators")
    lost = gaps(rec)
    described = lost.describe(rec) if lost else ""
    rec, filled = on_grid(rec)  # the estimators run across a gap filled: a lost sample is no jump in their input
    step, step_source = encoder_step(rec)
    reference, truth, start, stop = reference_velocity(rec, cutoff_hz)
    guard = offline.edge(rec.dt, cutoff_hz)
    scored = ~spoiled(filled, np.gradient(reference, rec.dt, axis=0), rec.dt, step, guard)  # recorded samples only
    model_based = [n for n in names if n in MODEL_BASED]
    if model_based and model is None:
        model = EstimatorModel.nominal(rec)
    why = model.why_not() if model_based and model is not None else None
    if why:  # no model for them: left out of the ranking, the others ranked
        names = [n for n in names if n not in MODEL_BASED]
    knobs = model.knobs() if model_based and model is not None and not why else {}
    setup = Setup(rec.dt, step, rec.n_joints, knobs)
    if stop - start < 50:
        raise ManusError(f"{rec.path}: too short to score after dropping the start-up and filter edges")
    sl = slice(start, stop)
    still = np.abs(reference) < scoring.still_threshold(reference[sl])
    rows, estimates = [], {"reference": reference}
    for name in names:
        if progress:
            progress(name)
        tuned = tune(setup, name, rec.q, rec.tau, reference if truth else None, start, stop) if tune_knobs else None
        estimator = setup.make(name, **({tuned["knob"]: tuned["value"]} if tuned else {}))
        out = run_estimator(estimator, rec.q, rec.tau)
        estimates[name] = out.qd
        if np.all(np.isfinite(out.qd)):
            m = scored[sl]
            row = {"name": name, **scoring.score(out.qd[sl][m], reference[sl][m], rec.dt, still[sl][m])}
        else:  # reported, not raised: the other estimators' results stand
            row = {
                "name": name,
                "error": "diverged (non-finite estimate)",
                "rms_error": None,
                "max_error": None,
                "moving": None,
                "still": None,
                "lag_ms": None,
                "noise_50hz": None,
            }
        spec = knob_range(name, step)
        if spec is not None:
            value = tuned["value"] if tuned else float(np.asarray(getattr(estimator, spec[0])))  # knob = field
            row["knob"] = {"name": spec[0], "value": value, "tuned": bool(tuned)}
            if tuned:
                row["knob"].update({k: tuned[k] for k in ("criterion", "objective", "at_limit")})
        rows.append(row)
    report = {
        "recording": rec.path,
        "samples": len(rec),
        "joints": rec.n_joints,
        "dt": rec.dt,
        "truth": truth,
        "reference": "truth" if truth else f"offline zero-phase ({cutoff_hz:g} Hz)",
        "scored_samples": [start, stop],
        "step": {"value": step, "source": step_source},
        "still_threshold": scoring.still_threshold(reference[sl]).tolist(),
        "tuned": tune_knobs,
        "estimators": rows,
        **({"model": model.report()} if model_based and model is not None else {}),
        **({"left_out": [{"name": n, "reason": why} for n in model_based]} if why else {}),
        **(
            {
                "gaps": f"{described}: filled for the estimators (positions by a cubic spline); "
                f"{int((~scored).sum())} sample{'s' if (~scored).sum() != 1 else ''} not scored (the filled ones, "
                f"and {1e3 * guard * rec.dt:.3g} ms either side of a gap where "
                "the fill may miss by more than an encoder step)"
            }
            if lost
            else {}
        ),
        "best": min(
            (r for r in rows if r["rms_error"] is not None), key=lambda r: r["rms_error"], default={"name": None}
        )["name"],
    }
    return report, estimates
