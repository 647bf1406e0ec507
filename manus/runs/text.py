"""Text for the person at the terminal: notes on stderr, plain tables, the lines several
commands' reports share (a model's parameters, the detection limits, what is left unexplained),
and a diagnosis and a discovery as text."""

from __future__ import annotations

import sys
from pathlib import Path


def note(*parts) -> None:
    """A progress note or remark for the person at the terminal: stderr, never stdout."""
    print(*parts, file=sys.stderr, flush=True)


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


def discovery_text(r: dict) -> str:
    """A discovery's JSON (`manus discover`) as text: the table of steps, why it stopped, what is left."""
    rows = [[0, f"(start) {r['start']['model']}", "", f"{100 * r['start']['rel_error']:.2f}"]]
    rows += [[s["step"], s["spec"], format_params(s["params"]), f"{100 * s['rel_error']:.2f}"] for s in r["steps"]]
    lines = [
        table(left(rows, (1, 2)), ["step", "effect added", "parameters (value±std)", "rel_error %"]),
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
