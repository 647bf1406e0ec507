"""What the commands and the Python API report, as text: plain tables, the lines several reports
share (a recording read, a model's parameters, the detection limits, what is left unexplained),
a fit, a diagnosis, a discovery and an estimators comparison, and any report as strict JSON
(`json_text`). What they say while they work is `manus.runs.progress`'s."""

from __future__ import annotations

import json
import math
from pathlib import Path


def describe(rec) -> str:
    """One line on what was read: samples, joints, the rate (stated or from the stamps), the
    structure, the units, where a column map or a bag gave them."""
    rate = "stated" if "sample_rate_hz" in rec.meta else "from its time stamps"
    units = "SI units" + (f"; columns {rec.meta['column_map']}" if "column_map" in rec.meta else "")
    source = f"; {rec.meta['source']}" if "source" in rec.meta and "joint_names" in rec.meta else ""
    joints = f" ({rec.meta['joint_names']})" if "joint_names" in rec.meta else ""
    return (
        f"{rec.path}: {len(rec)} samples of {rec.n_joints} joint(s){joints} at {rec.sample_rate_hz:g} Hz ({rate}), "
        f"structure {rec.structure_name}, {units}{source}"
    )


def table(rows: list[list], header: list[str]) -> str:
    """A plain text table, columns aligned."""
    cells = [[str(h) for h in header]] + [[str(c) for c in r] for r in rows]
    widths = [max(len(r[j]) for r in cells) for j in range(len(header))]
    fmt = lambda r: "  ".join(c.rjust(w) if j else c.ljust(w) for j, (c, w) in enumerate(zip(r, widths, strict=False)))
    return "\n".join([fmt(cells[0]), fmt(["-" * w for w in widths])] + [fmt(r) for r in cells[1:]])


def left(rows: list[list], columns: tuple[int, ...]) -> list[list]:
    """Pad the text of `columns` to a common width, so that `table` (which right-aligns every
    column but the first) shows them left-aligned."""
    rows = [list(r) for r in rows]
    for j in columns:
        w = max((len(str(r[j])) for r in rows), default=0)
        for r in rows:
            r[j] = str(r[j]).ljust(w)
    return rows


def format_params(params: dict) -> str:
    """A model's parameters on one line: value±std, or the value alone."""
    parts = []
    for k, v in params.items():
        if isinstance(v, dict):
            std = v.get("std")
            parts.append(f"{k}={v['value']:.4g}" + (f"±{std:.2g}" if std is not None else ""))
        elif isinstance(v, float):
            parts.append(f"{k}={v:.4g}")
        elif k not in ("measured_in",):
            parts.append(f"{k}={v}")
    return ", ".join(parts)


def limits_line(limits: dict) -> str:
    """One line on how large a missing effect must be for this recording to show it."""
    groups: dict[str, list[str]] = {}
    for name, v in sorted(limits.items(), key=lambda kv: kv[1]):
        groups.setdefault(f"{100 * v:.2g} %", []).append(name)
    items = "; ".join(f"{v} {', '.join(names)}" for v, names in groups.items())
    return (
        f"detection limits (the share of the torque's RMS a missing effect must explain, beyond the model's "
        f"own terms, to be found 4 times in 5): {items}"
    )


def unexplained_line(u: dict) -> str:
    """One line on the structure left in the residual that no effect of the vocabulary explains."""
    if not u:
        return "left in the residual: not tested"
    from manus.adaptive.diagnosis.leftover import what_removes

    what = what_removes(u)
    if u.get("significant"):
        return (
            f"left in the residual: something no effect of the vocabulary explains: {what} removes "
            f"{100 * u['fraction']:.0f} % of joint {u['joint']}'s remaining error held out (p = {u['p_value']:.2g})"
        )
    if u.get("below_relevance"):
        return (
            f"left in the residual: a small structure: {what} removes {100 * u['fraction']:.1f} % of joint "
            f"{u['joint']}'s remaining error held out (p = {u['p_value']:.2g}), under the "
            f"{100 * u['below_relevance']:.0f} % of the error or the {100 * u.get('min_share', 0):.1f} % of the "
            f"torque ({100 * u.get('share', 0):.2f} % here) that count"
        )
    return (
        f"left in the residual: no structure beyond noise (best: {u.get('against')} on joint {u.get('joint')}, "
        f"{100 * u.get('fraction', 0):.0f} %, p = {u.get('p_value', 1):.2g})"
    )


def candidate_rows(candidates: list[dict], verdict: str | None) -> list[list]:
    """One row per candidate of a diagnosis: what it removes, its tests, and its detail."""
    rows = []
    for c in candidates:
        skip = ("per_joint_error_reduction", "p_values", "score_test")
        detail = {k: v for k, v in c["detail"].items() if k not in skip}
        text = ", ".join(f"{k}={v:.4g}" if isinstance(v, float) else f"{k}={v}" for k, v in detail.items())
        flag = (
            "<- verdict"
            if c["effect"] == verdict
            else f"overlaps {c['overlaps']}"
            if c.get("overlaps")
            else "not proposed"
            if c.get("not_proposed")
            else ""
        )
        tests = c["detail"].get("p_values", {})
        score, held_out = (f"{tests[k]:.2g}" if k in tests else "-" for k in ("score", "held_out"))
        rows.append(
            [
                c["effect"],
                f"{100 * c['error_reduction']:.1f}",
                f"{100 * c['cv_error_reduction']:.1f}",
                f"{c['p_value']:.2g}",
                score,
                held_out,
                "yes" if c["significant"] else "no",
                c["joint"],
                text,
                flag,
            ]
        )
    return rows


def consistency_lines(r: dict) -> list[str]:
    """The physically consistent stage's line where it moved the estimate (a serial chain's `consistency`)."""
    c = r.get("consistency") or {}
    if "error" in c:
        return [f"  {c['error']}"]
    if not c.get("moved"):
        return []
    return [
        f"  the estimate breaks physics (rel_error {100 * c['ls_rel_error']:.2f} %): the model is the closest "
        f"physically consistent one, rel_error {100 * c['rel_error']:.2f} %"
    ]


def diagnosis_text(r: dict) -> str:
    """A diagnosis's JSON (`manus diagnose`) as text: the candidates, the notes, the verdict, what is left."""
    lines = [
        f"model {r['spec']}: rel_error {100 * r['rel_error']:.2f} % (torque low-passed at {r['cutoff_hz']:.1f} Hz; "
        f"{r['method']}; command hold {r['hold']})",
        *consistency_lines(r),
        *([f"  candidates judged by {r['judged_by']}: {r['judged_why']}"] if r.get("judged_why") else []),
        table(
            left([row[:8] + row[9:] + row[8:9] for row in candidate_rows(r["candidates"], r["verdict"])], (8, 9)),
            [
                "candidate",
                "removes %",
                "held out %",
                "p",
                "p score",
                "p held out",
                "significant",
                "joint",
                "",
                "detail",
            ],
        ),
    ]
    notes = [f"  {c['effect']}: {c['note']}" for c in r["candidates"] if c.get("note")] + [f"  {x}" for x in r["notes"]]
    notes += [
        f"  {c['effect']}: not proposed: {'; '.join(c['not_proposed'])}"
        for c in r["candidates"]
        if c.get("not_proposed") and c["significant"]
    ]
    if notes:
        lines += ["notes:"] + notes
    lines.append(f"verdict: {r['verdict_spec'] or 'null (nothing significant is missing)'}")
    if not r["verdict_spec"] and r.get("detection_limits"):
        lines.append(limits_line(r["detection_limits"]))
    lines.append(unexplained_line(r.get("unexplained") or {}))
    if "figures" in r:
        lines.append(f"residual figure: {r['figures']['resid']}")
        ev = r["figures"]["evidence"]
        if ev:
            lines.append(
                f"evidence figures ({len(ev)}): {Path(next(iter(ev.values()))).parent}/"
                f"{Path(next(iter(ev.values()))).name.rsplit('evidence_', 1)[0]}evidence_<effect>.png"
            )
    return "\n".join(line.rstrip() for text in lines for line in text.splitlines())


STEP_HEADER = ["step", "effect added", "parameters (value±std)", "rel_error %"]


def step_rows(r: dict) -> list[list]:
    """A discovery's JSON (`manus discover`) as the rows of its table of steps (`STEP_HEADER`)."""
    rows = [[0, f"(start) {r['start']['model']}", "", f"{100 * r['start']['rel_error']:.2f}"]]
    return rows + [
        [s["step"], s["spec"], format_params(s["params"]), f"{100 * s['rel_error']:.2f}"] for s in r["steps"]
    ]


def discovery_text(r: dict) -> str:
    """A discovery's JSON (`manus discover`) as text: the table of steps, why it stopped, what is left."""
    lines = [
        table(left(step_rows(r), (1, 2)), STEP_HEADER),
        f"stopped: {r['stopped']}; final model {r['model']}, rel_error {100 * r['rel_error']:.2f} %",
        *consistency_lines(r),
    ]
    lines += [f"  step {s['step']}: {s['note']}" for s in r["steps"] if s.get("note")]
    judged = [f"step {s['step']}" for s in r["steps"] if s.get("judged_by", "torque") != "torque"]
    judged += ["the last diagnosis"] if r.get("judged_by", "torque") != "torque" else []
    if judged:
        lines.append(f"  candidates judged by position (output error): {', '.join(judged)}")
    lines += [f"  {n}" for n in r["notes"]]
    lines.append(f"  fitted by {r['method']}: {r['method_why']}")
    if r["stopped"] == "nothing significant missing" and r.get("detection_limits"):
        lines.append("  " + limits_line(r["detection_limits"]))
    lines.append("  " + unexplained_line(r.get("unexplained") or {}))
    if "report" in r:
        lines.append(f"report: {r['report']}")
    return "\n".join(lines)


PARAM_HEADER = ["parameter", "value", "std", "std %", "unit"]


def param_rows(params: dict) -> list[list]:
    """A fit's parameters (its JSON's `params`) as table rows (`PARAM_HEADER`)."""
    rows = []
    for k, p in params.items():
        std = p["std"]
        rel = f"{100 * std / abs(p['value']):.2f}" if std is not None and p["value"] else "-"
        rows.append([k, f"{p['value']:.6g}", "-" if std is None else f"{std:.3g}", rel, p.get("unit", "")])
    return rows


def fit_text(r: dict) -> str:
    """A fit's JSON (`manus fit`) as text: the parameters, the fit, the free run, the notes."""
    urdf = r.get("urdf_values")  # a serial chain: each rigid base parameter as its URDF has it
    rows = [
        row + ([f"{urdf[k]:.6g}" if k in urdf else ""] if urdf else [])
        for k, row in zip(r["params"], param_rows(r["params"]), strict=True)
    ]
    lines = [
        f"model {r['spec']}: rel_error {100 * r['rel_error']:.2f} % on {r['samples']} rows "
        f"(torque low-passed at {r['cutoff_hz']:.1f} Hz, {100 * r['standstill_excluded']:.1f} % left out at "
        "standstill)",
        f"  method {r['method']}: {r['method_why']}",
        *([output_error_line(r["output_error"])] if "output_error" in r else []),
        f"  cut-off: {r['cutoff_note']}; command hold: {r['hold']}",
        *([f"  gaps: {r['gaps']}"] if r.get("gaps") else []),
        table(left(rows, (4,)), PARAM_HEADER + (["in the URDF"] if urdf else [])),
    ]
    regrouped = {k: v for k, v in r.get("base_parameters", {}).items() if k != v}
    if regrouped:  # a serial chain: the base parameters that are combinations of standard ones
        lines.append("  base parameters (identifiable combinations of the standard ones; the others are themselves):")
        lines += [f"    {k} = {v}" for k, v in regrouped.items()]
    c = r.get("consistent")
    if c is not None and "error" in c:
        lines.append(f"  physically consistent: none found ({c['error']})")
    elif c is not None:
        far = {k: v for k, v in c["moved_std"].items() if abs(v) >= 1}
        lines.append(
            "  physically consistent (each link's pseudo-inertia positive semidefinite, armatures and friction "
            "within their bounds): "
            + (
                "the estimate is consistent already"
                if c["already"]
                else f"the estimate breaks physics (rel_error {100 * c['ls_rel_error']:.2f} %): the parameters "
                f"above are the closest consistent set, rel_error {100 * c['rel_error']:.2f} %"
                + (
                    ", moving " + ", ".join(f"{k} by {v:+.1f} std" for k, v in far.items())
                    if far
                    else ", every parameter within one standard deviation"
                )
            )
        )
        lines.append(
            "    link masses " + ", ".join(f"{x['mass']:.4g}" for x in c["links"]) + " kg (held near the URDF's)"
        )
    for k, v in r.get("nonlinear", {}).items():
        shown = ", ".join(f"{x:.6g}" for x in v) if isinstance(v, (list, tuple)) else f"{v:.6g}"
        lines.append(f"  {k} = {shown} (searched or fixed)")
    for v in r.get("violations", []):
        lines.append(f"  {'the estimate ' if (c or {}).get('moved') else ''}breaks physics: {v}")
    if r.get("redundant"):
        lines.append(f"  redundant (explained by the others, set to 0): {', '.join(r['redundant'])}")
    fits = r["fit_percent"]
    lines.append("  torque fit (NRMSE) per joint: " + ", ".join(f"{x:.1f} %" for x in fits["torque"]))
    if "free_run" in r:
        fr = r["free_run"]
        lines.append(f"  free run: {fr['how']}")
        if "position" in fits:
            lines.append("    position fit per joint: " + ", ".join(f"{x:.2f} %" for x in fits["position"]))
        if "tracking_error_fit_percent" in fr:
            lines.append(
                "    tracking-error fit per joint: " + ", ".join(f"{x:.1f} %" for x in fr["tracking_error_fit_percent"])
            )
    for k, v in r.get("figures", {}).items():
        lines.append(f"  figure ({k}): {v}")
    return "\n".join(lines)


def output_error_line(oe: dict) -> str:
    """The output-error fit's positions, beside those of the estimate LS and IV gave."""
    rms = ", ".join(f"{x:.3g}" for x in oe["position_rms"])
    before = oe["compared"]
    was = (
        f"; {before['method'].upper()}'s parameters {100 * before['position_rel_error']:.2f} %"
        if before["position_rel_error"] is not None
        else ""
    )
    return (
        f"  output error: simulated positions off by {100 * oe['position_rel_error']:.2f} % of the windows' motion "
        f"(RMS {rms} per joint, encoder step {oe['encoder_step']:.3g}){was}; {oe['windows']} windows of "
        f"{oe['window_s']:.3g} s from the measured state, started from {oe['start']}"
    )


def json_text(result: dict) -> str:
    """`result` as strict JSON: numpy values as numbers and lists, and a number that is not finite
    (NaN, ±inf: no JSON number) as null."""

    def finite(x):
        if isinstance(x, float):
            return x if math.isfinite(x) else None
        if isinstance(x, dict):
            return {k: finite(v) for k, v in x.items()}
        if isinstance(x, list):
            return [finite(v) for v in x]
        return x

    return json.dumps(finite(json.loads(json.dumps(result, default=_jsonable))), allow_nan=False)


def _jsonable(x):
    import numpy as np

    if isinstance(x, np.generic):
        return x.item()
    if isinstance(x, np.ndarray):
        return x.tolist()
    raise TypeError(f"not JSON serializable: {type(x).__name__}")


def estimators_text(r: dict) -> str:
    """An estimators comparison's JSON (`manus estimators`) as text: the table, the best, the model."""

    def f(x, spec=".3g"):
        return "-" if x is None else format(x, spec)

    def knob(e):
        k = e.get("knob")
        return "" if k is None else f"{k['name']}={k['value']:.3g}" + (" (range end)" if k.get("at_limit") else "")

    rows = [
        [
            e["name"],
            knob(e),
            f(e["rms_error"]),
            f((e["moving"] or {}).get("rms_error")),
            f((e["still"] or {}).get("rms_error")),
            f(e["max_error"]),
            f(e["lag_ms"], ".2f"),
            f(e["noise_50hz"]),
        ]
        for e in r["estimators"]
    ]
    against = "the true velocity" if r["truth"] else f"the {r['reference']} reference"
    lines = [
        f"{r['recording']}: {r['samples']} samples, {r['joints']} joint(s); errors against {against}",
        table(
            rows,
            [
                "estimator",
                "knob" + (" (tuned)" if r["tuned"] else ""),
                "RMS",
                "RMS moving",
                "RMS still",
                "max",
                "lag [ms]",
                "noise >50 Hz",
            ],
        ),
        f"best: {r['best']}",
    ]
    m = r.get("model")
    if m is not None and "error" not in m:
        lines.append(model_line(m))
    reasons: dict[str, list[str]] = {}
    for x in r.get("left_out", []):
        reasons.setdefault(x["reason"], []).append(x["name"])
    for reason, names in reasons.items():
        lines.append(f"left out of the ranking: {', '.join(names)}: no model ({reason})")
    if r.get("gaps"):
        lines.append(f"gaps: {r['gaps']}")
    for name, path in (r.get("figures") or {}).items():
        lines.append(f"figure ({name}): {', '.join(path) if isinstance(path, list) else path}")
    return "\n".join(lines)


def model_line(m: dict) -> str:
    """The model-based estimators' model: its spec, where it came from, the fit's torque error."""
    from manus.estimators.compare import FITTED

    how = m["from"] if m["from"] in (FITTED, "--param") else f"from {m['from']}"
    fit = [f"rel_error {100 * m['rel_error']:.2f} %"] if m.get("rel_error") is not None else []
    fit += [f"method {m['method']}"] if m.get("method") else []
    fit += [f"set by hand: {', '.join(m['set_by_hand'])}"] if m.get("set_by_hand") else []
    fit += [f"{k} fitted {v:.3g}, within 2 std of its bound: set at it" for k, v in (m.get("at_bound") or {}).items()]
    return f"model of the model-based estimators: {m['spec']}, {how}" + (f" ({'; '.join(fit)})" if fit else "")
