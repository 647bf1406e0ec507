"""Figures of the velocity estimators: estimates against the reference over time (like thesis
Figs. 3-24 and 3-26, with a zoom) and each estimator's frequency response (like Fig. 3-25)."""

from __future__ import annotations

from pathlib import Path

import numpy as np

from manus.runs.figures.common import pyplot, save

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


def estimates_figure(t: np.ndarray, estimates: dict, report: dict, out: Path, joint: int) -> str:
    """One row per estimator: the whole recording, and a zoom; the reference in black."""
    plt = pyplot()
    rows = report["estimators"]
    ref = estimates["reference"]
    start, stop = report["scored_samples"]
    zoom = zoom_window(ref, report["dt"], start, stop)
    label = "true velocity" if report["truth"] else "offline reference"
    fig, axes = plt.subplots(
        len(rows),
        2,
        figsize=(11, 1.55 * len(rows) + 0.6),
        sharex="col",
        squeeze=False,
        gridspec_kw={"width_ratios": (2.2, 1)},
    )
    for ax, row in zip(axes, rows, strict=True):
        v = estimates[row["name"]][:, joint]
        for a, sl in ((ax[0], slice(None)), (ax[1], zoom)):
            a.plot(t[sl], v[sl], lw=0.6, color="C0", label="estimate")
            a.plot(t[sl], ref[sl, joint], lw=0.9, color="k", ls="--", label=label)
        knob = row.get("knob")
        text = f"{row['name']}" + (f"  {knob['name']}={knob['value']:.3g}" if knob else "")
        ax[0].set_title(
            f"{text}   RMS {_number(row['rms_error'], '.3g')}, lag {_number(row['lag_ms'], '.2f')} ms",
            fontsize=8,
            loc="left",
        )
        ax[0].set_ylabel("q̇")
        ax[0].axvspan(t[zoom][0], t[zoom][-1], color="0.9", zorder=-1)  # where the zoom is
    axes[0, 0].legend(loc="upper right", fontsize=7)
    axes[-1, 0].set_xlabel("t [s]")
    axes[-1, 1].set_xlabel("t [s] (zoom)")
    fig.suptitle(
        f"{Path(report['recording']).name}: velocity estimates of joint {joint + 1}, "
        f"{1 / report['dt']:g} Hz, encoder step {report['step']['value']:.3g} ({report['step']['source']})",
        fontsize=9,
    )
    fig.tight_layout()
    return save(fig, out, f"estimates_joint{joint + 1}.png")


def response_figure(freqs_hz: np.ndarray, responses: dict, out: Path, title: str = "") -> str:
    """|H| and phase lag of each estimator's velocity against the true velocity."""
    plt = pyplot()
    fig, (mag, lag) = plt.subplots(2, 1, figsize=(8, 6.5), sharex=True)
    for i, (name, H) in enumerate(responses.items()):
        style = {"color": f"C{i % 10}", "ls": "-" if i < 10 else "--", "lw": 1.0, "label": name}
        mag.semilogx(freqs_hz, 20 * np.log10(np.maximum(np.abs(H), 1e-6)), **style)
        lag.semilogx(freqs_hz, -np.degrees(np.angle(H)), **style)
    for ax in (mag, lag):
        for f in (2.0, 5.0):
            ax.axvline(f, color="0.6", lw=0.7, ls=":")
    mag.set_ylabel("|q̂̇ / q̇| [dB]")
    mag.set_ylim(-40, 10)
    lag.set_ylabel("phase lag [°]")
    lag.set_ylim(-45, 180)
    lag.set_xlabel("frequency [Hz] (dotted: 2 and 5 Hz, thesis §3.7)")
    mag.legend(fontsize=7, ncol=3)
    mag.set_title(title or "frequency response of the velocity estimators", fontsize=9)
    fig.tight_layout()
    return save(fig, out, "estimators_frequency_response.png")


def estimator_figures(rec, report: dict, estimates: dict, out) -> dict:
    """`manus estimators`' figures: the estimates of each joint, and every estimator's frequency response."""
    from manus.estimators.response import frequency_response

    t = rec.t[0] + rec.dt * np.arange(len(estimates["reference"]))  # the sample grid (lost samples filled)
    paths: dict[str, list[str] | str] = {
        "estimates": [estimates_figure(t, estimates, report, out, j) for j in range(rec.n_joints)]
    }
    freqs = np.geomspace(0.5, 0.45 / rec.dt, 40)
    amplitude = float(np.max(np.std(rec.q, axis=0)))
    responses = {}
    for row in report["estimators"]:
        knob = {row["knob"]["name"]: row["knob"]["value"]} if "knob" in row else {}
        responses[row["name"]] = frequency_response(
            row["name"], freqs, rec.dt, amplitude, step=report["step"]["value"], **knob
        )
    paths["frequency_response"] = response_figure(
        freqs, responses, out, f"frequency response at amplitude {amplitude:.3g} (model-based: model exact)"
    )
    return paths
