"""manus from Python (a notebook, a script). `read`, `fit`, `diagnose`, `discover` and
`estimators` take a path (any file `manus` reads, a ROS 2 bag), a `Recording` or a pandas
DataFrame, and compute what the command of the same name does. Their results

- print a short summary (`str`) and show themselves as HTML in a notebook (`_repr_html_`);
- hold the command's JSON as a dict (`report`; `to_json()` is what `manus CMD --json
  --no-figures` prints);
- draw their figures as matplotlib Figures (`figure(kind)`, `kinds()`), writing files only when
  asked (`save_figures(out)`).

JAX computes in float64 (`manus.config`, set when manus is imported).
"""

from __future__ import annotations

import abc
import html
import os
from collections.abc import Callable
from pathlib import Path
from typing import TYPE_CHECKING, Any, ClassVar, TypeVar

from manus.plants.errors import ManusError
from manus.plants.recording import Recording
from manus.runs import analyses, progress, text

if TYPE_CHECKING:
    from matplotlib.figure import Figure


def read(source, **options) -> Recording:
    """A recording from a file, a ROS 2 bag or a DataFrame, `options` as
    `manus.plants.recording.read` takes them (`columns`, a column map `t=stamp:ms,q1=pos`;
    `meta`, metadata such as `sample_rate_hz`; a bag's `topic`, `joints`, `command_topic`;
    `robot`). A `Recording` is returned as it is."""
    from manus.plants import recording

    if isinstance(source, Recording):
        if options:
            raise ManusError("read: a Recording is read already: give the file or the DataFrame to apply options")
        return source
    return recording.read(source, **options)


class Result(abc.ABC):
    """A command's result: its JSON (`report`), its text, its HTML, its figures. A kind of result
    says its text (`_text`), which figures it draws (`kinds`) and draws one (`_draw`)."""

    command: ClassVar[str] = ""

    def __init__(self, report: dict):
        self.report = report

    def to_json(self) -> str:
        """The command's JSON (`manus CMD --json --no-figures`): strict, NaN written as null."""
        return text.json_text(self.report)

    @abc.abstractmethod
    def _text(self) -> str: ...

    def __str__(self) -> str:
        return self._text()

    def __repr__(self) -> str:
        first = self._text().splitlines()[0] if self._text() else ""
        return f"<manus {self.command}: {first}>"

    def _repr_html_(self) -> str:
        return f"<pre>{html.escape(self._text())}</pre>"

    @abc.abstractmethod
    def kinds(self) -> list[str]:
        """The figures `figure` draws."""

    def figure(self, kind: str | None = None) -> Figure:
        """One figure (`kinds()`; the first when `kind` is not given) as a matplotlib Figure."""
        kinds = self.kinds()
        if not kinds:
            raise ManusError(f"{self.command}: this result has no figure")
        kind = kinds[0] if kind is None else kind
        if kind not in kinds:
            raise ManusError(f"{self.command}: no figure {kind!r}; the figures are {', '.join(kinds)}")
        return self._draw(kind)

    @abc.abstractmethod
    def _draw(self, kind: str) -> Figure: ...

    def save_figures(self, out: str | os.PathLike, prefix: str = "") -> dict[str, str]:
        """Every figure written into `out` as PNG (atomically), by kind."""
        from manus.runs.figures.common import save

        return {k: save(self._draw(k), Path(out), f"{prefix}{self.command}_{k}.png") for k in self.kinds()}


def _table_html(rows: list[list], header: list[str]) -> str:
    head = "".join(f"<th>{html.escape(str(h))}</th>" for h in header)
    body = "".join("<tr>" + "".join(f"<td>{html.escape(str(c))}</td>" for c in r) + "</tr>" for r in rows)
    return f"<table><thead><tr>{head}</tr></thead><tbody>{body}</tbody></table>"


class FitResult(Result):
    """`manus fit`'s result: the fitted model (`fit`, a `manus.adaptive.Fit`) and its report.
    `parameters` gives the values by name; `figure("compare")` runs the model free in the
    simulator (once) and draws it against the measurements."""

    command = "fit"

    def __init__(self, analysis: analyses.FitAnalysis):
        super().__init__(analysis.report)
        self.analysis = analysis
        self.fit = analysis.fit

    @property
    def parameters(self) -> dict[str, float]:
        """The fitted linear parameters by name."""
        return {k: p["value"] for k, p in self.report["params"].items()}

    def _text(self) -> str:
        return text.fit_text(self.report)

    def _repr_html_(self) -> str:
        r = self.report
        head = (
            f"<p><b>manus fit</b> {html.escape(r['spec'])}: rel_error <b>{100 * r['rel_error']:.2f} %</b> on "
            f"{r['samples']} rows ({html.escape(r['method'])}; torque low-passed at {r['cutoff_hz']:.1f} Hz)</p>"
        )
        notes = [f"breaks physics: {v}" for v in r.get("violations", [])]
        fits = ", ".join(f"{x:.1f} %" for x in r["fit_percent"]["torque"])
        return (
            head
            + _table_html(text.param_rows(r["params"]), text.PARAM_HEADER)
            + f"<p>torque fit (NRMSE) per joint: {fits}</p>"
            + "".join(f"<p>{html.escape(n)}</p>" for n in notes)
        )

    def kinds(self) -> list[str]:
        return ["compare"]

    def _draw(self, kind: str) -> Figure:
        from manus.experiments.freerun import free_run_or_reason
        from manus.runs.figures.fit import draw_compare

        if self.analysis.run is None:
            self.analysis.run = free_run_or_reason(self.fit)
        return draw_compare(self.fit, self.analysis.run)


class DiagnosisResult(Result):
    """`manus diagnose`'s result: the model's fit (`base`), the diagnosis (`diagnosis`) and its
    report; `verdict` is the missing effect's spec (None: nothing significant is missing).
    Figures: the residual (`resid`), each candidate's evidence (by its effect's name), what no
    effect explains (`unexplained`, where something is left)."""

    command = "diagnose"

    def __init__(self, analysis: analyses.DiagnosisAnalysis):
        super().__init__(analysis.report)
        self.base, self.diagnosis = analysis.base, analysis.diagnosis

    @property
    def verdict(self) -> str | None:
        return self.report["verdict_spec"]

    def _text(self) -> str:
        return text.diagnosis_text(self.report)

    def _repr_html_(self) -> str:
        r = self.report
        rows = [row[:8] for row in text.candidate_rows(r["candidates"], r["verdict"])]
        verdict = r["verdict_spec"] or "null (nothing significant is missing)"
        return (
            f"<p><b>manus diagnose</b> {html.escape(r['spec'])}: rel_error {100 * r['rel_error']:.2f} %</p>"
            + _table_html(
                rows, ["candidate", "removes %", "held out %", "p", "p score", "p held out", "significant", "joint"]
            )
            + f"<p>verdict: <b>{html.escape(verdict)}</b></p>"
            + f"<p>{html.escape(text.unexplained_line(r.get('unexplained') or {}))}</p>"
            + "".join(f"<p>{html.escape(n)}</p>" for n in r["notes"])
        )

    def kinds(self) -> list[str]:
        left = ["unexplained"] if (self.report.get("unexplained") or {}).get("significant") else []
        return ["resid", *(c.effect for c in self.diagnosis.candidates), *left]

    def _draw(self, kind: str) -> Figure:
        from manus.runs.figures.diagnose import draw_evidence, draw_resid, draw_unexplained

        if kind == "resid":
            return draw_resid(self.base)
        if kind == "unexplained":
            fig = draw_unexplained(self.diagnosis)
            if fig is None:
                raise ManusError("diagnose: nothing is left unexplained to draw")
            return fig
        c = next(c for c in self.diagnosis.candidates if c.effect == kind)
        return draw_evidence(self.base, c, self.diagnosis.verdict)


class DiscoveryResult(Result):
    """`manus discover`'s result: the loop (`discovery`, a `manus.adaptive.Discovery`) and its
    report; `model` is the final model's spec. Figures: the error falling (`waterfall`), each
    step's evidence (`step1`, ...), the final model's residual (`resid`) and its free run against
    the measurements (`compare`)."""

    command = "discover"

    def __init__(self, analysis: analyses.DiscoveryAnalysis):
        super().__init__(analysis.report)
        self.discovery = analysis.discovery
        self._run: Any = None

    @property
    def model(self) -> str:
        return self.report["model"]

    def _text(self) -> str:
        return text.discovery_text(self.report)

    def _repr_html_(self) -> str:
        r = self.report
        return (
            "<p><b>manus discover</b></p>"
            + _table_html(text.step_rows(r), text.STEP_HEADER)
            + f"<p>stopped: {html.escape(r['stopped'])}; final model <b>{html.escape(r['model'])}</b>, rel_error "
            f"{100 * r['rel_error']:.2f} %</p>"
            + f"<p>{html.escape(text.unexplained_line(r.get('unexplained') or {}))}</p>"
        )

    def kinds(self) -> list[str]:
        d = self.discovery
        return [
            "waterfall",
            *(f"step{s.index}" for s in d.steps),
            *(["resid"] if d.final is not None else []),
            "compare",
        ]

    def _draw(self, kind: str) -> Figure:
        from manus.runs.figures.diagnose import draw_evidence, draw_resid
        from manus.runs.figures.fit import draw_compare, draw_waterfall

        d = self.discovery
        if kind == "waterfall":
            return draw_waterfall(d)
        if kind == "resid" and d.final is not None:
            return draw_resid(d.final.base)
        if kind == "compare":
            from manus.experiments.freerun import free_run_or_reason

            if self._run is None:
                self._run = free_run_or_reason(d.final_fit)
            return draw_compare(d.final_fit, self._run)
        s = next(s for s in d.steps if f"step{s.index}" == kind)
        return draw_evidence(s.diagnosis.base, s.verdict, s.diagnosis.verdict)


class EstimatorsResult(Result):
    """`manus estimators`' result: every estimator scored on the recording (`report`), `best`
    its best, and the estimates (`estimates`, by name). Figures: each joint's estimates
    (`estimates1`, ...) and every estimator's frequency response (`response`)."""

    command = "estimators"

    def __init__(self, analysis: analyses.EstimatorsAnalysis, rec: Recording):
        super().__init__(analysis.report)
        self.estimates, self.recording = analysis.estimates, rec

    @property
    def best(self) -> str:
        return self.report["best"]

    def _text(self) -> str:
        return text.estimators_text(self.report)

    def _repr_html_(self) -> str:
        r = self.report
        rows = [
            [e["name"], *(f"{x:.3g}" if x is not None else "-" for x in (e["rms_error"], e["max_error"], e["lag_ms"]))]
            for e in r["estimators"]
        ]
        m = r.get("model")
        said = f"<p>{html.escape(text.model_line(m))}</p>" if m is not None and "error" not in m else ""
        return (
            f"<p><b>manus estimators</b> on {html.escape(str(r['recording']))}: "
            f"best <b>{html.escape(r['best'])}</b></p>"
            + _table_html(rows, ["estimator", "RMS", "max", "lag [ms]"])
            + said
        )

    def kinds(self) -> list[str]:
        return [*(f"estimates{j + 1}" for j in range(self.recording.n_joints)), "response"]

    def _draw(self, kind: str) -> Figure:
        from manus.runs.figures.estimators import estimator_figure

        return estimator_figure(self.recording, self.report, self.estimates, kind)


R = TypeVar("R", bound=Result)


def _guarded(command: str, work: Callable[[], R]) -> R:
    """`work` with what the recording's reading noted shown as the command shows it (a line on
    stderr)."""
    with progress.notes_as_lines(command):
        return work()


def fit(source, model: str, *, cutoff_hz: float | None = None, method: str = "auto", **read_options) -> FitResult:
    """`manus fit`: identify `model`'s parameters (e.g. "rigid,viscous,coulomb") from a
    recording (`source` and `read_options` as `read` takes them)."""

    def work() -> FitResult:
        rec = read(source, **read_options)
        return FitResult(analyses.fit_recording(rec, model, cutoff_hz=cutoff_hz, method=method))

    return _guarded("fit", work)


def diagnose(
    source, model: str, *, cutoff_hz: float | None = None, method: str = "auto", **read_options
) -> DiagnosisResult:
    """`manus diagnose`: where `model` fails on a recording and which physical effect is missing."""

    def work() -> DiagnosisResult:
        rec = read(source, **read_options)
        return DiagnosisResult(analyses.diagnose_recording(rec, model, cutoff_hz=cutoff_hz, method=method))

    return _guarded("diagnose", work)


def discover(
    source, model: str, *, cutoff_hz: float | None = None, method: str = "auto", max_steps: int = 6, **read_options
) -> DiscoveryResult:
    """`manus discover`: the loop from `model`: diagnose, add the verdict, refit, until nothing
    significant is missing."""
    if max_steps < 1:
        raise ManusError(f"max_steps {max_steps}: at least 1")

    def work() -> DiscoveryResult:
        rec = read(source, **read_options)
        a = analyses.discover_recording(rec, model, cutoff_hz=cutoff_hz, method=method, max_steps=max_steps)
        return DiscoveryResult(a)

    return _guarded("discover", work)


def estimators(
    source,
    *,
    only: list[str] | None = None,
    tune: bool = False,
    cutoff_hz: float = 30.0,
    model: str | None = None,
    model_from: str | os.PathLike | None = None,
    **read_options,
) -> EstimatorsResult:
    """`manus estimators`: every velocity estimator (or `only` these) scored on a recording, each
    knob tuned first with `tune`; the model-based ones on `model` (default rigid,viscous,coulomb)
    fitted on the recording, or on the fit JSON `model_from`."""
    from manus.estimators import NAMES

    names = tuple(only) if only else NAMES
    unknown = [n for n in names if n not in NAMES]
    if unknown:
        raise ManusError(f"unknown estimator {unknown[0]!r}: the estimators are {', '.join(NAMES)}")
    if not cutoff_hz > 0:
        raise ManusError("cutoff_hz must be positive")

    def work() -> EstimatorsResult:
        rec = read(source, **read_options)
        fit_json = None if model_from is None else str(model_from)
        return EstimatorsResult(analyses.estimators_recording(rec, names, tune, cutoff_hz, model, fit_json), rec)

    return _guarded("estimators", work)
