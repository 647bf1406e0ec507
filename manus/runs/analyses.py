"""What `manus fit`, `diagnose` and `discover` compute and report, as the commands and the Python
API (`manus.runs.api`) both run it: the analysis and its JSON, no file written. The commands add
their figures; the API draws them when asked."""

from __future__ import annotations

import contextlib
import json
import math
import warnings
from collections.abc import Callable, Iterator
from dataclasses import dataclass, field
from pathlib import Path
from typing import TYPE_CHECKING, Any

from manus.estimators.compare import FITTED
from manus.runs.progress import Bar, note
from manus.runs.text import describe

if TYPE_CHECKING:
    from manus.adaptive import Diagnosis, Discovery, Fit
    from manus.plants.recording import Recording
    from manus.runs.report import Section


def _time_base(rec: Recording, out: dict) -> dict:
    """`out` with the recording's time-base repair (repeated rows, jittered stamps or a resampled
    rate found and repaired as it was read), where there was one."""
    if rec.time_base:
        out["time_base"] = rec.time_base.report()
    return out


@contextlib.contextmanager
def _noted() -> Iterator[list[str]]:
    """The notes (`RecordingNote`) an analysis raises about its recording (another reading of it
    that fits far better, a torque in another unit), collected for its JSON as they are shown
    (the command prints each as a line when it is raised), each time it is raised."""
    from manus.plants.errors import RecordingNote

    said: list[str] = []
    with warnings.catch_warnings():
        warnings.simplefilter("always", RecordingNote)
        shown = warnings.showwarning

        def show(message, category, *rest, **kw):
            if issubclass(category, RecordingNote):
                said.append(str(message))
            shown(message, category, *rest, **kw)

        warnings.showwarning = show
        yield said


@dataclass
class FitAnalysis:
    """A fitted model and `manus fit`'s JSON; the free run once `simulate` ran it."""

    fit: Fit
    report: dict
    run: Any = None  # the free run (`manus.experiments.freerun.FreeRun`), or why there is none (str)

    def simulate(self, open_loop: bool = False) -> None:
        """The fitted model run free in the simulator (`manus.experiments.freerun`), its figures of
        merit added to the report."""
        from manus.experiments.freerun import free_run_or_reason

        note("free run of the fitted model in the simulator ...")
        self.run = free_run_or_reason(self.fit, open_loop)
        self._report_run()

    def skip_run(self, why: str) -> None:
        """No free run, and why, in the report."""
        self.run = why
        self._report_run()

    def _report_run(self) -> None:
        if isinstance(self.run, str):
            self.report["free_run"] = {"mode": None, "how": self.run}
        else:
            self.report["free_run"] = self.run.report()
            self.report["fit_percent"]["position"] = self.run.fit_q.tolist()


def fit_recording(rec: Recording, model: str, cutoff_hz: float | None = None, method: str = "auto") -> FitAnalysis:
    """`manus fit`'s analysis: the model identified, its report with the torque's fit per joint."""
    from manus.adaptive import fit
    from manus.experiments.freerun import nrmse_fit

    note(f"fitting {model} ...")
    with _noted() as said:
        f = fit(rec, model, cutoff_hz=cutoff_hz, method=method)
    out = f.report()
    out["notes"] = said
    out["fit_percent"] = {"torque": nrmse_fit(f.data.tau(f.delay), f.predicted()).tolist()}
    _time_base(rec, out)
    if "urdf_values" in out:  # a serial chain: the physically consistent stage of the fit, in full
        out["consistent"] = f.consistency or {"error": "physically consistent parameters are a rigid model's"}
    return FitAnalysis(f, out)


@dataclass
class DiagnosisAnalysis:
    """The model's fit, its diagnosis and `manus diagnose`'s JSON."""

    base: Fit
    diagnosis: Diagnosis
    report: dict


def diagnose_recording(
    rec: Recording,
    model: str,
    cutoff_hz: float | None = None,
    method: str = "auto",
    fitted: Callable[[Fit], None] | None = None,
    judged: Callable[[Diagnosis], None] | None = None,
) -> DiagnosisAnalysis:
    """`manus diagnose`'s analysis: the model fitted (`fitted` is told, to start its figure), then
    each effect it lacks judged, a progress bar counting them (`judged` is told the diagnosis
    then, before what is left unexplained is looked at)."""
    from manus.adaptive import Columns, diagnose, fit, prepare
    from manus.adaptive.diagnosis.candidates import columns_ahead

    note(f"diagnosing {model}: fitting it, then with each missing effect in turn ...")
    data = prepare(rec, cutoff_hz)
    cols = Columns(data)
    with _noted() as said, columns_ahead(cols, model):  # (the candidates' columns, beside the fit)
        base = fit(data, model, columns=cols, method=method, readings=True)
    if fitted is not None:
        fitted(base)
    bar = Bar("candidates judged", "candidate")
    d = diagnose(data, model, columns=cols, method=method, fitted=base, told=bar)
    d.notes[:0] = said
    if judged is not None:
        judged(d)
    return DiagnosisAnalysis(base, d, _time_base(rec, d.report()))


@dataclass
class DiscoveryAnalysis:
    """The loop's section (its discovery and, once drawn, its figures) and `manus discover`'s JSON."""

    section: Section
    report: dict = field(default_factory=dict)

    @property
    def discovery(self) -> Discovery:
        return self.section.discovery


def discover_recording(
    rec: Recording,
    model: str,
    cutoff_hz: float | None = None,
    method: str = "auto",
    max_steps: int = 6,
    figures: Path | None = None,
) -> DiscoveryAnalysis:
    """`manus discover`'s analysis: the loop, a line per step and a bar over each step's
    candidates; its figures drawn into `figures` when given."""
    from manus.runs import report

    stem = Path(rec.path).stem
    note(f"discovering from {model} ...")
    with _noted() as said:
        sec = report.discover_section(
            rec,
            model,
            figures or Path("."),
            f"discover_{stem}_",
            f"{Path(rec.path).name} from `{model}`",
            cutoff_hz=cutoff_hz,
            max_steps=max_steps,
            figures=figures is not None,
            method=method,
        )
    sec.discovery.notes[:0] = said
    return DiscoveryAnalysis(sec, _time_base(rec, report.section_result(sec)))


@dataclass
class EstimatorsAnalysis:
    """`manus estimators`' JSON and each estimator's estimates (for the figures)."""

    report: dict
    estimates: dict


def estimators_recording(
    rec: Recording,
    names: tuple[str, ...],
    tune: bool = False,
    cutoff_hz: float = 30.0,
    effects: str | None = None,
    fit_json: str | None = None,
    by_hand: dict[str, float] | None = None,
) -> EstimatorsAnalysis:
    """`manus estimators`' analysis: the estimators `names` scored on `rec` (tuned first with
    `tune`; against the true velocity, else the offline reference at `cutoff_hz`), the
    model-based ones on a model fitted on `rec` (`estimator_model`)."""
    from manus.estimators import MODEL_BASED
    from manus.estimators.compare import compare

    note(
        describe(rec)
        + f", {'with' if rec.has_truth else 'without'} a true velocity"
        + (", tuning each knob" if tune else "")
    )
    model = None
    if any(n in MODEL_BASED for n in names):
        model = estimator_model(rec, effects, fit_json, by_hand or {})
    report, estimates = compare(rec, names, tune, cutoff_hz, model, progress=lambda name: note(f"  {name} ..."))
    return EstimatorsAnalysis(_time_base(rec, report), estimates)


def estimator_model(rec, effects: str | None, fit_json: str | None, by_hand: dict[str, float]):
    """The model-based estimators' model on `rec` (`EstimatorModel`): the model and parameters of
    the fit JSON `fit_json`, else `effects` (default rigid,viscous,coulomb) fitted on `rec` (not
    when `by_hand` gives every parameter); `by_hand` (--param) replaces single parameters. Where
    the recording refuses the fit, the model says why (the model-based estimators are left out);
    bad input is a one-line `ManusError`."""
    from manus.estimators.compare import EstimatorModel
    from manus.estimators.registry import NOMINAL_MODEL
    from manus.plants.effects import Model
    from manus.plants.errors import ManusError

    effects = effects or NOMINAL_MODEL
    if fit_json:
        model, params, stds, rel_error, method = read_fit(fit_json, rec)
    else:  # what a fit identifies: a serial chain's base parameters
        model, params, stds, rel_error, method = Model(rec.structure.identified_form(), effects), {}, {}, None, None
    if not model.has("rigid"):
        raise ManusError(
            f"the model {model.spec}: the model-based estimators need the 'rigid' effect (the inertia) to predict with"
        )
    unknown = sorted(set(by_hand) - set(model.names))
    if unknown:
        raise ManusError(
            f"--param {', '.join(unknown)}: not a parameter of the model {model.spec} on this recording "
            f"(it has {', '.join(model.names)})"
        )
    if not fit_json and set(by_hand) >= set(model.names):  # every parameter given: nothing to fit
        return EstimatorModel("--param", model.spec, model, dict(by_hand), by_hand=tuple(by_hand))
    if not fit_json:
        from manus.adaptive import fit

        note(f"fitting {effects} on the recording for the model-based estimators ...")
        try:
            f = fit(rec, effects)  # as `manus fit REC --model EFFECTS` fits it
        except ManusError as e:  # the recording cannot identify it: the model-based estimators are left out
            return EstimatorModel(FITTED, effects, refused=f"{effects} cannot be identified from this recording: {e}")
        model, params, stds = f.model, f.params, f.stds  # (with the non-linear parameters as searched)
        rel_error, method = float(f.rel_error), f.method
    params, moved = at_bounds(model, params, stds)
    return EstimatorModel(
        fit_json or FITTED, model.spec, model, {**params, **by_hand}, rel_error, method, tuple(by_hand), moved
    )


def at_bounds(model, params: dict[str, float], stds: dict[str, float]) -> tuple[dict[str, float], dict[str, float]]:
    """(params with each one below its effect's physical lower bound by less than two standard
    deviations set at the bound, {name: fitted value} of those moved): the fit cannot tell them from
    the bound (e.g. Coulomb friction fitted on an axis without it), and an estimator's model must
    keep every bound. One beyond two standard deviations is left: the model breaks physics."""
    s, out, moved = model.structure, dict(params), {}
    for e in model.effects:
        for k, lo in zip(e.names(s), e.lower_bounds(s), strict=True):
            v, sd = out.get(k), stds.get(k)
            sd = sd if sd is not None and math.isfinite(sd) else 0.0
            if v is not None and math.isfinite(lo) and v < lo <= v + 2 * sd:
                moved[k], out[k] = v, float(lo)
    return out, moved


def read_fit(path: str, rec):
    """(model, params, stds, rel_error, method) of the fit JSON at `path` (what `manus fit --json`
    prints), on `rec`'s structure; a one-line `ManusError` for a missing or unreadable file, a JSON
    that is not a fit's, or a fit of another structure or joint count."""
    from manus.plants.effects import Model
    from manus.plants.errors import ManusError

    try:
        r = json.loads(Path(path).read_text(encoding="utf-8"))
    except FileNotFoundError:
        raise ManusError(f"--model-from {path}: no such file") from None
    except (OSError, UnicodeDecodeError) as e:
        raise ManusError(f"--model-from {path}: cannot be read ({e})") from None
    except json.JSONDecodeError as e:
        raise ManusError(f"--model-from {path}: not valid JSON ({e.msg}, line {e.lineno})") from None
    if not (isinstance(r, dict) and isinstance(r.get("spec"), str) and isinstance(r.get("params"), dict)):
        raise ManusError(
            f"--model-from {path}: not a fit's JSON (`manus fit REC --model EFFECTS --json`: no spec and params)"
        )
    params, stds = {}, {}
    for k, p in r["params"].items():
        v = p.get("value") if isinstance(p, dict) else p
        if isinstance(v, bool) or not isinstance(v, (int, float)):
            raise ManusError(f"--model-from {path}: parameter {k} has no numeric value")
        params[k] = float(v)
        sd = p.get("std") if isinstance(p, dict) else None
        if isinstance(sd, (int, float)) and not isinstance(sd, bool):
            stds[k] = float(sd)
    joints = r.get("rel_error_per_joint")
    if isinstance(joints, list) and len(joints) != rec.n_joints:
        raise ManusError(
            f"--model-from {path}: a fit of {len(joints)} joint(s), the recording {rec.path} has {rec.n_joints}"
        )
    try:
        model = Model(rec.structure.identified_form(), r["spec"])
    except ManusError as e:
        raise ManusError(f"--model-from {path}: its spec {r['spec']!r}: {e}") from None
    absent = [k for k in model.names if k not in params]
    extra = [k for k in params if k not in model.names]
    if extra:
        raise ManusError(
            f"--model-from {path}: parameter(s) {', '.join(extra)} are not of {model.spec} on this recording's "
            f"{rec.structure_name} of {rec.n_joints} joint(s) ({', '.join(model.names)}): a fit of another structure"
        )
    if absent:
        raise ManusError(f"--model-from {path}: the fit lacks the parameter(s) {', '.join(absent)} of {model.spec}")
    rel_error = r.get("rel_error")
    method = r.get("method")
    return (
        model,
        params,
        stds,
        float(rel_error) if isinstance(rel_error, (int, float)) else None,
        method if isinstance(method, str) else None,
    )
