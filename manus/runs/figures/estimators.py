"""Figures of the velocity estimators: estimates against the reference over time (like thesis
Figs. 3-24 and 3-26, with a zoom) and each estimator's frequency response (like Fig. 3-25).
`draw_*` builds a figure, `*_figure` writes it."""

from __future__ import annotations

from pathlib import Path
from typing import TYPE_CHECKING

import numpy as np

from manus.runs.figures.common import (
    PRISMATIC,
    REVOLUTE,
    envelope,
    labelled,
    panels,
    recording_units,
    save,
    styled,
    tidy,
)

if TYPE_CHECKING:
    from matplotlib.figure import Figure

ZOOM_SECONDS = 0.2


def _number(x, spec: str) -> str:
    return "-" if x is None else format(x, spec)


def zoom_window(reference: np.ndarray, dt: float, start: int, stop: int) -> slice:
    """ZOOM_SECONDS around the sharpest turn of the reference (largest |q̈|): where lag and
    quantization both show."""
    acc = np.abs(np.gradient(reference[start:stop], axis=0)).max(axis=1)
    centre = start + int(np.argmax(acc))
    half = int(round(0.5 * ZOOM_SECONDS / dt))
    lo = int(np.clip(centre - half, 0, max(0, len(reference) - 2 * half)))
    return slice(lo, lo + 2 * half)


def _prismatic(report: dict, joint: int, prismatic: bool | None) -> bool:
    """Whether `joint` is prismatic: `prismatic` when given, else the report's `prismatic` (per
    joint) when it has one, else revolute."""
    if prismatic is not None:
        return prismatic
    kinds = report.get("prismatic") or ()
    return bool(kinds[joint]) if joint < len(kinds) else False


@styled
def draw_estimates(t: np.ndarray, estimates: dict, report: dict, joint: int, prismatic: bool | None = None) -> Figure:
    """One row per estimator of `report` (`manus.estimators.compare`'s): the whole recording, and
    a zoom where the reference turns sharpest; the reference in black. `joint` is 0-based; its
    velocity is in m/s when it is prismatic (`prismatic`, else the report's per-joint `prismatic`),
    in rad/s otherwise."""
    rows = report["estimators"]
    ref = estimates["reference"]
    start, stop = report["scored_samples"]
    zoom = zoom_window(ref, report["dt"], start, stop)
    label = "true velocity" if report["truth"] else "offline reference"
    u = PRISMATIC if _prismatic(report, joint, prismatic) else REVOLUTE
    step = report["step"]
    fig, axes = panels(
        len(rows),
        2,
        (5.6, 1.9),
        f"{Path(report['recording']).name}: velocity estimates of joint {joint + 1}, {1 / report['dt']:g} Hz",
        note=f"Encoder step {step['value']:.3g} {u.position} ({step['source']}). Reference: {report['reference']}. "
        f"Right: {1e3 * ZOOM_SECONDS:g} ms around the reference's sharpest turn (shaded on the left).",
        widths=(2.2, 1.0),
    )
    for ax, row in zip(axes, rows, strict=True):
        v = estimates[row["name"]][:, joint]
        for a, sl in ((ax[0], slice(None)), (ax[1], zoom)):
            a.plot(*envelope(t[sl], v[sl]), lw=0.6, color="C0", label="estimate")
            a.plot(*envelope(t[sl], ref[sl, joint]), lw=0.9, color="k", ls="--", label=label)
            a.set_ylabel(labelled(f"q̇{joint + 1}", u.velocity))
            a.set_xlabel("t [s]")
        knob = row.get("knob")
        text = f"{row['name']}" + (f"  {knob['name']}={knob['value']:.3g}" if knob else "")
        ax[0].set_title(
            f"{text}: RMS error {_number(row['rms_error'], '.3g')} {u.velocity}, "
            f"lag {_number(row['lag_ms'], '.2f')} ms",
            loc="left",
        )
        ax[1].set_title("zoom", loc="left")
        ax[0].axvspan(t[zoom][0], t[zoom][-1], color="0.9", zorder=-1)  # where the zoom is
    axes[0, 0].legend(loc="upper right")
    tidy(axes)
    return fig


def estimates_figure(
    t: np.ndarray, estimates: dict, report: dict, out: Path, joint: int, prismatic: bool | None = None
) -> str:
    """`draw_estimates` written as `out/estimates_joint<joint + 1>.png`; returns its path."""
    return save(draw_estimates(t, estimates, report, joint, prismatic), out, f"estimates_joint{joint + 1}.png")


@styled
def draw_response(freqs_hz: np.ndarray, responses: dict, title: str = "") -> Figure:
    """|H| and phase lag of each estimator's velocity against the true velocity, on a logarithmic
    frequency axis; dotted lines at 2 and 5 Hz (thesis §3.7)."""
    fig, axes = panels(
        2,
        1,
        (8.0, 3.1),
        title or "frequency response of the velocity estimators",
        note="Dotted: 2 and 5 Hz, the band of a person's motion (thesis §3.7).",
    )
    mag, lag = axes[0, 0], axes[1, 0]
    for i, (name, H) in enumerate(responses.items()):
        style = {"color": f"C{i % 10}", "ls": "-" if i < 10 else "--", "lw": 1.0, "label": name}
        mag.semilogx(freqs_hz, 20 * np.log10(np.maximum(np.abs(H), 1e-6)), **style)
        lag.semilogx(freqs_hz, -np.degrees(np.angle(H)), **style)
    for ax in (mag, lag):
        for f in (2.0, 5.0):
            ax.axvline(f, color="0.6", lw=0.7, ls=":")
        ax.set_xlabel("frequency [Hz]")
    mag.set_ylabel("|q̂̇ / q̇| [dB]")
    mag.set_ylim(-40, 10)
    mag.set_title("magnitude", loc="left")
    lag.set_ylabel("phase lag [°]")
    lag.set_ylim(-45, 180)
    lag.set_title("phase lag", loc="left")
    mag.legend(ncol=3, loc="lower left")
    tidy(axes)
    return fig


def response_figure(freqs_hz: np.ndarray, responses: dict, out: Path, title: str = "") -> str:
    """`draw_response` written as `out/estimators_frequency_response.png`; returns its path."""
    return save(draw_response(freqs_hz, responses, title), out, "estimators_frequency_response.png")


def _responses(rec, report: dict) -> tuple[np.ndarray, dict, str]:
    """Each estimator's frequency response on `rec`'s sample rate and at its largest joint's swing:
    (frequencies [Hz], {name: H}, the figure's title)."""
    from manus.estimators.response import frequency_response

    freqs = np.geomspace(0.5, 0.45 / rec.dt, 40)
    swing = np.std(rec.q, axis=0)
    amplitude = float(np.max(swing))
    responses = {}
    for row in report["estimators"]:
        knob = {row["knob"]["name"]: row["knob"]["value"]} if "knob" in row else {}
        responses[row["name"]] = frequency_response(
            row["name"], freqs, rec.dt, amplitude, step=report["step"]["value"], **knob
        )
    unit = recording_units(rec)[int(np.argmax(swing))].position
    return freqs, responses, f"frequency response at amplitude {amplitude:.3g} {unit} (model-based: model exact)"


def _grid(rec, estimates: dict) -> np.ndarray:
    """The sample grid of the estimates (lost samples filled)."""
    return rec.t[0] + rec.dt * np.arange(len(estimates["reference"]))


def draw_estimator(rec, report: dict, estimates: dict, kind: str) -> Figure:
    """One of `manus estimators`' figures of recording `rec`: `estimates<j>` (joint j, 1-based:
    `draw_estimates` in its units) or `response` (`draw_response`)."""
    if kind == "response":
        return draw_response(*_responses(rec, report))
    j = int(kind.removeprefix("estimates")) - 1
    return draw_estimates(_grid(rec, estimates), estimates, report, j, recording_units(rec)[j] is PRISMATIC)


estimator_figure = draw_estimator  # (the name `manus.runs.api` calls)


def estimator_figures(rec, report: dict, estimates: dict, out) -> dict:
    """`manus estimators`' figures written into `out`: the estimates of each joint (in its units:
    `rec.prismatic`), and every estimator's frequency response; their paths."""
    t = _grid(rec, estimates)
    units = recording_units(rec)
    paths: dict[str, list[str] | str] = {
        "estimates": [
            estimates_figure(t, estimates, report, out, j, units[j] is PRISMATIC) for j in range(rec.n_joints)
        ]
    }
    freqs, responses, title = _responses(rec, report)
    paths["frequency_response"] = response_figure(freqs, responses, out, title)
    return paths
