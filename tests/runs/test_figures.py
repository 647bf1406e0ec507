"""The figures (manus.runs.figures): the shared machinery (a long series drawn as what each pixel
column shows keeps every column's extremes, a grid of panels laid out in inches without a layout
pass), and every kind of figure built from small real inputs: a `matplotlib.figure.Figure` made
without pyplot and in its own style; every panel that shows data labelled on both axes, a torque in
N·m on a revolute joint and a force in N on a prismatic one; every text inside the figure, a long
note under the panels, the saved PNG no wider than the figure was made; a search spanning decades on
a logarithmic axis; a correlogram's title saying what its curve does against its band."""

import inspect
import io
import re
from dataclasses import replace

import matplotlib
import numpy as np
import pytest
from matplotlib.backends.backend_agg import FigureCanvasAgg
from matplotlib.figure import Figure
from matplotlib.image import imread
from matplotlib.text import Text

from manus.runs.figures import common, converge, diagnose, estimators, fit, stability, sysid, worker
from manus.runs.figures.common import (
    DPI,
    GAP,
    PRISMATIC,
    REVOLUTE,
    draw_recording,
    envelope,
    panels,
    parameter_unit,
    plot_recording,
    save,
    spread_scale,
    tidy,
)

LONG = " ".join(f"a long note of many words, number {k}, that must wrap under the panels" for k in range(40))


def test_envelope_keeps_each_columns_minimum_and_maximum_and_a_one_sample_spike():
    n, columns = 100_000, 500
    t = np.arange(n) * 1e-3
    y = np.sin(2 * np.pi * 3.3 * t) + 0.01 * np.random.default_rng(0).normal(size=n)
    y[61_234] = 7.0  # one sample: plain subsampling to 1000 points would miss it
    te, ye = envelope(t, y, columns)
    assert te.size == ye.size == 2 * columns
    assert np.all(np.diff(te) >= 0)  # in time order
    # every column (n / columns samples) by a plain reshape: its extremes are the envelope's
    cols = y.reshape(columns, -1)
    pairs = ye.reshape(columns, 2)
    np.testing.assert_array_equal(pairs.min(axis=1), cols.min(axis=1))
    np.testing.assert_array_equal(pairs.max(axis=1), cols.max(axis=1))
    assert ye.max() == 7.0 and te[np.argmax(ye)] == t[61_234]
    few_t, few_y = t[:1999], y[:1999]  # under 4 samples a column: drawn whole
    assert all(a is b for a, b in zip(envelope(few_t, few_y, columns), (few_t, few_y), strict=True))


def test_panels_size_the_figure_in_inches_and_save_writes_that_many_pixels(tmp_path):
    fig, axes = panels(3, 2, (5.0, 3.0), "a title\nof two lines")
    assert axes.shape == (3, 2)
    w, h = fig.get_size_inches()
    # 2 panels of 5 in with their gaps, 3 of 3 in, plus the margins and the title's two lines
    assert abs(w - 10.2) < 1e-9 and abs(h - 9.58) < 1e-9
    for ax in axes.flat:
        ax.plot(np.arange(10), np.arange(10) ** 2)
    axes[0, 0].semilogy(np.arange(1, 10), np.exp(np.arange(1, 10)))
    tidy(axes)
    assert len(axes[1, 1].yaxis.get_major_locator().tick_values(0, 81)) <= 7
    image = imread(save(fig, tmp_path, "grid.png", tight=False))
    assert image.shape[:2] == (round(100 * h), round(100 * w))  # not cropped: laid out as made
    # the panels stay inside the figure and do not overlap
    boxes = [ax.get_position() for ax in axes.flat]
    assert all(0 < b.x0 < b.x1 < 1 and 0 < b.y0 < b.y1 < 1 for b in boxes)
    assert boxes[0].x1 < boxes[1].x0 and boxes[2].y1 < boxes[0].y0


def test_a_long_note_goes_under_the_panels_and_the_figure_keeps_its_width():
    plain, _ = panels(1, 2, (5.0, 3.0), "title")
    fig, axes = panels(1, 2, (5.0, 3.0), "title", note=LONG)
    assert fig.get_size_inches()[0] == plain.get_size_inches()[0]
    assert fig.get_size_inches()[1] > plain.get_size_inches()[1] + 1.0  # the note's lines, under the panels
    for ax in axes.flat:
        ax.plot([0, 1], [0, 1])
        ax.set(xlabel="x [m]", ylabel="y [m]")
    tidy(axes)
    _check_layout(fig)


def test_a_search_spanning_decades_is_drawn_on_a_logarithmic_axis():
    cases = {
        "log": np.geomspace(5e-5, 0.05, 40),  # a smooth-friction width: 3 decades
        "symlog": np.linspace(0.0, 100.0, 201),  # a delay from 0 to 100 ms (0.5 ms steps)
        "linear": np.geomspace(127.0, 3230.0, 160),  # cogging orders: 1.4 decades
    }
    for scale, values in cases.items():
        ax = Figure().subplots()
        assert spread_scale(ax, values) == scale
        assert ax.get_xscale() == scale
    assert spread_scale(Figure().subplots(), np.linspace(-1.0, 100.0, 9)) == "linear"  # signed: no log


def test_units_of_every_parameter_of_the_vocabulary_are_the_models():
    from manus.plants.effects import ORDER, Model
    from manus.plants.structures import Axis, Manus2

    for structure, kinds, units in (
        (Manus2(), (False, False), [REVOLUTE, REVOLUTE]),
        (Axis(), (True,), [PRISMATIC]),
        (Axis(), (False,), [REVOLUTE]),
    ):
        for effect in ORDER:
            for name, unit in Model(structure, effect).units(kinds).items():
                assert parameter_unit(name, units) == unit, (structure.name, kinds, name)


# -- real inputs -----------------------------------------------------------------------------------


@pytest.fixture(scope="module")
def axis_discovery():
    """A prismatic axis at 200 Hz with an offset hidden, through `discover`: its first step's
    diagnosis (candidates with searches: delay from 0 to 100 ms, smooth, Stribeck, cogging) and the
    final one."""
    from manus.adaptive import discover
    from manus.experiments import calibration

    c = calibration.case(0, "offset", rates=(200,))
    assert c.rec.prismatic == (True,)
    return discover(c.rec, c.start, max_steps=2)


@pytest.fixture(scope="module")
def arm_fit(arm_recording):
    """The simulated arm (revolute joints), fitted."""
    from manus.adaptive import fit as identify

    return identify(arm_recording, "rigid,viscous,coulomb")


def _renderer(fig):
    canvas = FigureCanvasAgg(fig)
    canvas.draw()
    return canvas.get_renderer()


def _title(ax, loc: str) -> Text:
    """A panel's left or right title (matplotlib keeps them beside `Axes.title`, the centred one)."""
    return getattr(ax, f"_{loc}_title")


def _data_axes(fig):
    return [ax for ax in fig.axes if ax.get_visible() and ax.axison and ax.has_data()]


def _check_layout(fig, slack_px: float = 1.0) -> None:
    """Every panel with data labelled on both axes; every title, label, legend and figure text
    inside the figure's width; a panel's title no wider than its panel and the gap after it; the
    figure's note under every panel; the PNG saved with a tight box no wider than the figure."""
    assert isinstance(fig, Figure)
    assert fig.canvas.manager is None  # not pyplot's
    renderer = _renderer(fig)
    width_px = fig.get_size_inches()[0] * fig.dpi
    axes = _data_axes(fig)
    assert axes
    for ax in axes:
        assert ax.get_xlabel().strip() and ax.get_ylabel().strip(), (ax.get_title(loc="left"), ax.get_xlabel())
        box = ax.get_window_extent(renderer)
        for title in (_title(ax, "left"), ax.title, _title(ax, "right")):
            if title.get_text():
                extent = title.get_window_extent(renderer)
                assert extent.x1 <= min(box.x1 + GAP[0] * fig.dpi, width_px) + slack_px, title.get_text()
    texts = [t for t in fig.findobj(Text) if t.get_visible() and t.get_text().strip()]
    owned = set()
    for ax in fig.axes:  # tick labels are laid out by their axis: those of ticks out of view are not drawn
        for axis in (ax.xaxis, ax.yaxis):
            owned |= {id(t) for tick in axis.majorTicks + axis.minorTicks for t in (tick.label1, tick.label2)}
    for t in texts:
        if id(t) in owned:
            continue
        extent = t.get_window_extent(renderer)
        assert -slack_px <= extent.x0 and extent.x1 <= width_px + slack_px, t.get_text()[:60]
    lowest = min(ax.get_window_extent(renderer).y0 for ax in fig.axes if ax.get_visible())
    for t in fig.texts:
        if t.get_text().strip() and t.get_position()[1] < 0.5:  # the note
            assert t.get_window_extent(renderer).y1 < lowest
    buffer = io.BytesIO()
    fig.savefig(buffer, format="png", bbox_inches="tight")
    buffer.seek(0)
    assert imread(buffer).shape[1] <= 1.05 * width_px
    buffer = io.BytesIO()
    fig.savefig(buffer, format="png")
    buffer.seek(0)
    h, w = imread(buffer).shape[:2]
    assert (w, h) == (round(width_px), round(fig.get_size_inches()[1] * fig.dpi))


def _torque_label(label: str, prismatic: bool) -> None:
    if prismatic:
        assert label.endswith("[N]"), label
    else:
        assert label.endswith("[N·m]"), label


def test_the_recording_figure_in_each_joints_units(arm_recording, axis_discovery, tmp_path):
    fig = draw_recording(arm_recording)
    _check_layout(fig)
    axes = np.array(fig.axes).reshape(3, 2)
    for i in range(2):
        assert axes[0, i].get_ylabel() == f"q{i + 1} [rad]" and axes[1, i].get_ylabel() == f"q̇{i + 1} [rad/s]"
        _torque_label(axes[2, i].get_ylabel(), prismatic=False)
    axis = draw_recording(axis_discovery.start.data.rec)
    assert axis.axes[0].get_ylabel() == "q1 [m]"
    _torque_label(axis.axes[-1].get_ylabel(), prismatic=True)
    w = round(fig.get_size_inches()[0] * DPI)
    assert imread(plot_recording(arm_recording, tmp_path / "rec.png")).shape[1] == w


def test_compare_on_revolute_and_prismatic_joints_with_a_long_reason(arm_fit, arm_recording, axis_discovery, tmp_path):
    from manus.experiments.freerun import FreeRun

    rec = arm_recording
    q_ref = np.stack([rec.extra["qref1"], rec.extra["qref2"]], 1)
    run = FreeRun(
        rec.t,
        rec.q,
        rec.q + 1e-4 * np.sin(rec.t)[:, None],
        "closed loop",
        "impedance control replayed",
        np.array([99.0, 98.0]),
        q_ref,
        np.array([80.0, 70.0]),
    )
    fig = fit.draw_compare(arm_fit, run)
    _check_layout(fig)
    axes = np.array(fig.axes).reshape(2, 3)
    for i in range(2):
        _torque_label(axes[i, 0].get_ylabel(), prismatic=False)
        assert axes[i, 1].get_ylabel() == f"q{i + 1} [rad]"
        assert axes[i, 2].get_ylabel().endswith("[rad]")
    axis = fit.draw_compare(axis_discovery.start, LONG)  # no free run: the reason, however long, in the note
    _check_layout(axis)
    _torque_label(axis.axes[0].get_ylabel(), prismatic=True)
    assert axis.get_size_inches()[0] == pytest.approx(6.2 + 0.2)
    path = fit.compare_figure(axis_discovery.start, LONG, tmp_path, "c.png")
    assert imread(path).shape[1] == round(axis.get_size_inches()[0] * DPI)


def test_waterfall(axis_discovery, tmp_path):
    assert axis_discovery.steps
    fig = fit.draw_waterfall(axis_discovery, "a recording")
    _check_layout(fig)
    assert fig.axes[0].get_xticklabels()[1].get_text() == f"+ {axis_discovery.steps[0].spec}"
    assert fit.waterfall_figure(axis_discovery, tmp_path).endswith("waterfall.png")


def _correlogram(ax, skip_zero: bool) -> tuple[int, int]:
    """(bars outside the band, bars) as drawn on a correlogram panel."""
    segments = ax.collections[0].get_segments()
    x = np.array([s[0, 0] for s in segments])
    y = np.array([s[1, 1] for s in segments])
    band = next(p for p in ax.patches if p.get_label().startswith("99 %"))
    top = band.get_y() + band.get_height()
    if skip_zero:
        y = y[x != 0]
    return int(np.sum(np.abs(y) > top)), y.size


def test_resid_titles_follow_the_band_and_carry_units(arm_fit, axis_discovery, tmp_path):
    words = []
    for f, prismatic in ((axis_discovery.start, True), (arm_fit, False)):
        fig = diagnose.draw_resid(f)
        _check_layout(fig)
        axes = np.array(fig.axes).reshape(-1, 3)
        for i in range(f.data.n_joints):
            for ax, skip_zero in ((axes[2 * i, 0], True), (axes[2 * i, 1], False)):
                out, bars = _correlogram(ax, skip_zero)
                title = ax.get_title(loc="left")
                assert ("within its 99 % band" in title) == (out == 0), title
                if out:
                    assert f"{out} of {bars} lags outside 99 %" in title, title
                words.append(out > 0)
            for ax in (axes[2 * i, 2], axes[2 * i + 1, 0], axes[2 * i + 1, 1]):
                _torque_label(ax.get_ylabel(), prismatic)
        assert "judged on held-out blocks" in fig.texts[1].get_text().replace("\n", " ")
    assert any(words)  # (a curve leaves its band here: the words are tested both ways)
    assert diagnose.resid_figure(axis_discovery.start, tmp_path).endswith("resid.png")


def test_evidence_figures_the_delay_search_on_a_log_axis_and_reuse(axis_discovery, tmp_path):
    d = axis_discovery.steps[0].diagnosis
    by = {c.effect: c for c in d.candidates}
    delay = by["delay"]
    fig = diagnose.draw_evidence(d.base, delay, d.verdict)
    _check_layout(fig)
    search = fig.axes[-1]
    assert search.get_xlabel().startswith("delay [ms]")
    assert search.get_xscale() in ("log", "symlog")

    def to_axes(ms: float) -> float:
        return search.transAxes.inverted().transform(search.transData.transform((ms, 0.0)))[0]

    assert to_axes(1.0) - to_axes(0.0) > 0.1 and to_axes(2.0) - to_axes(1.0) > 0.05  # 1 ms is plainly visible
    _torque_label(fig.axes[0].get_ylabel(), prismatic=True)
    assert fig.axes[0].get_xlabel() == "dτ1/dt [N/s]"
    smooth = diagnose.draw_evidence(d.base, by["smooth"], d.verdict)
    assert smooth.axes[-1].get_xscale() == "log" and smooth.axes[-1].get_xlabel().endswith("[m/s]")
    noted = diagnose.draw_evidence(d.base, replace(by["offset"], note=LONG), d.verdict)  # one panel, a long note
    _check_layout(noted)
    assert noted.get_size_inches()[0] == pytest.approx(5.0 + 0.2)
    mode = diagnose.draw_evidence(d.base, by["compliance"], d.verdict)
    _check_layout(mode)
    assert mode.axes[0].get_ylabel().endswith("[1/kg]")
    # drawn on a reused figure (`evidence_figures`), the file is the fresh figure's, pixel for pixel
    shown = [by["smooth"], by["delay"]]
    paths = diagnose.evidence_figures(d.base, d.verdict, shown, tmp_path, "r_")
    fresh = save(diagnose.draw_evidence(d.base, by["delay"], d.verdict), tmp_path, "fresh.png")
    np.testing.assert_array_equal(imread(paths["delay"]), imread(fresh))


def test_unexplained_says_what_its_verdict_rests_on(axis_discovery, tmp_path):
    final = axis_discovery.final
    assert final is not None
    fig = diagnose.draw_unexplained(final)
    assert fig is not None
    _check_layout(fig)
    ax = fig.axes[0]
    _torque_label(ax.get_ylabel(), prismatic=True)
    assert ax.get_xlabel().endswith(("[m]", "[m/s]", "[s]"))
    assert "held-out" in fig.texts[1].get_text().replace("\n", " ")
    assert diagnose.unexplained_figure(final, tmp_path, "u.png") == str(tmp_path / "u.png")


def test_builders_leave_the_callers_matplotlib_settings_alone(axis_discovery):
    keys = ("font.size", "axes.grid", "grid.alpha", "figure.dpi", "axes.titley", "legend.fontsize")
    before = {k: matplotlib.rcParams[k] for k in keys}
    with matplotlib.rc_context({"font.size": 14.0, "axes.grid": False}):
        fig = diagnose.draw_resid(axis_discovery.start)
    assert {k: matplotlib.rcParams[k] for k in keys} == before
    ax = fig.axes[0]
    assert _title(ax, "left").get_fontsize() == 9.0
    assert ax.xaxis.get_major_ticks()[0].label1.get_fontsize() == 9.0  # in the figures' style, not the caller's
    assert fig.canvas.manager is None
    for module in (common, converge, diagnose, estimators, fit, stability, sysid, worker):
        assert not re.search(r"matplotlib\.pyplot|import pyplot|matplotlib\.use\(", inspect.getsource(module))


def test_estimator_figures(arm_recording, tmp_path):
    from manus.estimators.compare import compare

    report, estimates = compare(arm_recording, names=("first_difference", "filtered_first_difference"))
    t = arm_recording.t
    fig = estimators.draw_estimates(t, estimates, report, 1)
    _check_layout(fig)
    assert all(ax.get_ylabel() == "q̇2 [rad/s]" for ax in fig.axes)
    assert estimators.draw_estimates(t, estimates, report, 0, prismatic=True).axes[0].get_ylabel() == "q̇1 [m/s]"
    freqs = np.geomspace(0.5, 450.0, 12)
    response = estimators.draw_response(freqs, {"a": 1 / (1 + 1j * freqs / 50), "b": np.exp(-1j * freqs / 100)})
    _check_layout(response)
    assert all(ax.get_xscale() == "log" for ax in response.axes)
    by_kind = estimators.draw_estimator(arm_recording, report, estimates, "estimates2")
    assert by_kind.axes[0].get_ylabel() == "q̇2 [rad/s]"
    paths = estimators.estimator_figures(arm_recording, report, estimates, tmp_path)
    assert len(paths["estimates"]) == 2 and paths["frequency_response"].endswith(".png")


def test_converge_figures(tmp_path):
    from manus.experiments import convergence
    from manus.plants import Model, Simulator
    from manus.plants.structures import Manus2

    plant = Simulator(Model(Manus2(), "rigid,viscous,coulomb"), torque_noise=0.005)
    model = Model(Manus2(), "rigid,viscous,coulomb")
    controller = convergence.controller_for(plant, model, "gradient", "kalman_cv")
    tr = convergence.run_trials(plant, controller, convergence.trajectory("complex", model), 2, 1.0)
    fig = converge.draw_tracking(tr, "complex")
    _check_layout(fig)
    axes = np.array(fig.axes).reshape(2, 2)
    assert axes[0, 0].get_ylabel().endswith("[rad]")
    _torque_label(axes[1, 1].get_ylabel(), prismatic=False)
    _torque_label(converge.draw_tracking(tr, prismatic=(True, True)).axes[-1].get_ylabel(), prismatic=True)
    params = converge.draw_parameters(tr, "complex")
    _check_layout(params)
    units = model.units()
    for ax, name in zip(params.axes, tr.names, strict=False):
        assert ax.get_ylabel() == f"{name} [{units[name]}]"
    assert params.axes[len(tr.names)].get_yscale() == "log"
    assert converge.plot_tracking(tr, tmp_path / "t.png").endswith("t.png")
    assert converge.plot_estimates(tr, tmp_path / "e.png").endswith("e.png")


def test_stability_figures(tmp_path):
    from manus.experiments.stability import analysis
    from manus.experiments.stability.search import stability_map
    from manus.experiments.stability.steptest import StepTest
    from manus.plants.closed_loop import simulate

    test = StepTest()
    smap = stability_map(test, np.array([0.0, 20.0]), np.array([500.0, 3000.0]), progress=False)
    curves = analysis.type1_curves(np.array([0.0, 10.0, 20.0]))
    summary = {"rate_hz": 1000.0, "springs": {"0": analysis.map_summary(smap, test.linear(), 1000.0)}}
    wide = smap._replace(ks=np.geomspace(30.0, 3e4, 2))  # a stiffness grid over 3 decades
    sens = {
        "tables": [
            {
                "label": "delay",
                "parameter": "delay",
                "rows": [
                    {"value": v, "probes": [{"probe": "k at b_c=20", "limit": 3000.0 - 1e6 * v, "kind": kind}]}
                    for v, kind in ((0.0, "type1"), (0.001, "type2"), (0.002, "type2"))
                ],
            }
        ]
    }
    test_short = test.with_(seconds=2.0)
    traj = simulate(test_short.plant(), test_short.controller(3000.0, 20.0), test_short.reference(), 2.0)
    figures = [
        stability.draw_stability_map(smap, curves),
        stability.draw_type1_curves(curves),
        stability.draw_appendix_d({0.0: smap}, summary),
        stability.draw_sensitivity(sens),
        stability.draw_step_response(traj, test_short, 3000.0, 20.0),
    ]
    for fig in figures:
        _check_layout(fig)
    assert figures[0].axes[0].get_ylabel() == "controller stiffness k [N/m]"
    assert stability.draw_stability_map(wide, curves).axes[0].get_yscale() == "log"
    assert figures[3].axes[0].get_xlabel() == "amplifier delay [ms]"
    assert stability.stability_map(smap, curves, tmp_path).endswith("stability_map.png")


def test_sysid_figures(tmp_path):
    from manus.experiments.sysid import study

    s = study(displacement=0.3, seconds=3)
    for fig in (sysid.draw_oscillations(s.traces, s.replays), sysid.draw_workspace(s.points, s.cartesian)):
        _check_layout(fig)
        assert all(ax.get_ylabel().endswith(("[rad]", "[m]")) for ax in _data_axes(fig))
    assert sysid.workspace(s.points, s.cartesian, tmp_path).endswith("sysid_cartesian.png")


def test_a_geared_motors_cogging_is_shown_against_the_motors_phase():
    """MANUS-2 behind 4:1 gears (`4 q1; 4 q2`), a cogging of 6 periods per motor revolution (24 per
    joint revolution) on the motors: diagnose names `cogging:6`, and its evidence panel folds the
    residual at the motor's phase N·θ (θ = 4 q), where the fitted term is one sinusoid of the phase
    (R² > 0.99; folded at N·q it is none: R² 0.05)."""
    import jax

    from manus.adaptive import diagnose as diagnosis
    from manus.adaptive.impedance import Impedance
    from manus.plants import Model, Simulator
    from manus.plants.closed_loop import simulate
    from manus.plants.effects import Cogging
    from manus.plants.recording import from_trajectory
    from manus.plants.references import MultiSine
    from manus.plants.structures import Manus2
    from manus.plants.transmission import stated

    statement = "4 q1; 4 q2"
    s = stated(Manus2(), statement)
    truth = {"a1": 0.349, "a2": 0.241, "a3": 0.246, "b1": 0.2 / 16, "b2": 0.15 / 16}
    truth |= {"A1": 0.03, "B1": 0.02, "A2": 0.02, "B2": -0.02}
    plant = Simulator(Model(s, (*Model(s, "rigid,viscous").effects, Cogging(order=6.0))), truth)
    assert plant.actuator is not None
    controller = Impedance(30.0, 1.0, n_joints=2, limit=plant.actuator.limit)
    traj = simulate(plant, controller, MultiSine((0.464, 2.409), 0.3, seed=5), 8.0, key=jax.random.PRNGKey(5))
    rec = from_trajectory(traj, plant.rate_hz, "manus2", 131072, {"transmission": statement})
    rec.qd, rec.extra = None, {}
    d = diagnosis(rec, "rigid,viscous")
    assert d.verdict is not None and d.verdict.spec == "cogging:6", [c.spec for c in d.candidates]
    ax = diagnose.draw_evidence(d.base, d.verdict, d.verdict).axes[0]
    assert ax.get_xlabel().startswith("phase N·θ1")
    term = next(line for line in ax.lines if "fitted" in str(line.get_label()))
    x, y = np.asarray(term.get_xdata(), float), np.asarray(term.get_ydata(), float)
    X = np.stack([np.sin(x), np.cos(x), np.ones_like(x)], 1)
    left = y - X @ np.linalg.lstsq(X, y, rcond=None)[0]
    assert 1 - np.sum(left**2) / np.sum((y - y.mean()) ** 2) > 0.99
