"""`manus diagnose REC --model EFFECTS`: where does the model fail, and which effect is missing?
(`manus.adaptive.diagnose`: every effect not in the model is a candidate, judged on held-out blocks.)
Writes the residual figure (`resid`) and one evidence figure per candidate."""

from __future__ import annotations

from pathlib import Path

from manus.runs.cmd_fit import add_model_options, load
from manus.runs.common import add_common, note, table

NAME = "diagnose"
HELP = "where the model fails and which physical effect is missing: candidates best first, a verdict, figures"


def add_arguments(p) -> None:
    add_model_options(p)
    p.add_argument("--no-figures", action="store_true", help="skip the figures")
    add_common(p)


def figures(d, out: Path, stem: str) -> dict:
    from manus.runs.diagnose_figures import evidence_figures, resid_figure, unexplained_figure

    return {"resid": resid_figure(d, out, f"{stem}_resid.png"),
            "evidence": evidence_figures(d, out, prefix=f"{stem}_"),
            "unexplained": unexplained_figure(d, out, f"{stem}_unexplained.png")}


def run(args) -> dict:
    from manus.adaptive.diagnose import diagnose

    rec = load(args, proposing=True)
    note(f"diagnosing {args.model}: fitting it with each missing effect in turn ...")
    d = diagnose(rec, args.model, cutoff_hz=args.cutoff, method=args.method)
    out = d.report()
    if not args.no_figures:
        stem = f"diagnose_{Path(rec.path).stem}"
        out["figures"] = figures(d, args.out, stem)
    return out


def candidate_rows(candidates: list[dict], verdict: str | None) -> list[list]:
    rows = []
    for c in candidates:
        skip = ("per_joint_error_reduction", "p_values", "score_test")
        detail = {k: v for k, v in c["detail"].items() if k not in skip}
        text = ", ".join(f"{k}={v:.4g}" if isinstance(v, float) else f"{k}={v}" for k, v in detail.items())
        flag = ("<- verdict" if c["effect"] == verdict else f"overlaps {c['overlaps']}" if c.get("overlaps")
                else "not proposed" if c.get("not_proposed") else "")
        tests = c["detail"].get("p_values", {})
        each = lambda k: f"{tests[k]:.2g}" if k in tests else "-"
        rows.append([c["effect"], f"{100 * c['error_reduction']:.1f}", f"{100 * c['cv_error_reduction']:.1f}",
                     f"{c['p_value']:.2g}", each("score"), each("held_out"), "yes" if c["significant"] else "no",
                     c["joint"], text, flag])
    return rows


def render(r: dict) -> str:
    from manus.runs.report import left

    lines = [f"model {r['spec']}: rel_error {100 * r['rel_error']:.2f} % (torque low-passed at {r['cutoff_hz']:.1f} Hz; "
             f"{r['method']}; command hold {r['hold']})",
             table(left([row[:8] + row[9:] + row[8:9] for row in candidate_rows(r["candidates"], r["verdict"])], (8, 9)),
                   ["candidate", "removes %", "held out %", "p", "p score", "p held out", "significant", "joint", "",
                    "detail"])]
    notes = [f"  {c['effect']}: {c['note']}" for c in r["candidates"] if c.get("note")] + [f"  {x}" for x in r["notes"]]
    notes += [f"  {c['effect']}: not proposed: {'; '.join(c['not_proposed'])}" for c in r["candidates"]
              if c.get("not_proposed") and c["significant"]]
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
            lines.append(f"evidence figures ({len(ev)}): {Path(next(iter(ev.values()))).parent}/"
                         f"{Path(next(iter(ev.values()))).name.rsplit('evidence_', 1)[0]}evidence_<effect>.png")
    return "\n".join(line.rstrip() for text in lines for line in text.splitlines())


def limits_line(limits: dict) -> str:
    """One line on how large a missing effect must be for this recording to show it."""
    groups: dict[str, list[str]] = {}
    for name, v in sorted(limits.items(), key=lambda kv: kv[1]):
        groups.setdefault(f"{100 * v:.2g} %", []).append(name)
    items = "; ".join(f"{v} {', '.join(names)}" for v, names in groups.items())
    return (f"detection limits (the share of the torque's RMS a missing effect must explain, beyond the model's "
            f"own terms, to be found 4 times in 5): {items}")


def unexplained_line(u: dict) -> str:
    """One line on the structure left in the residual that no effect of the vocabulary explains."""
    if not u:
        return "left in the residual: not tested"
    from manus.adaptive.leftover import what_removes

    what = what_removes(u)
    if u.get("significant"):
        return (f"left in the residual: something no effect of the vocabulary explains: {what} removes "
                f"{100 * u['fraction']:.0f} % of joint {u['joint']}'s remaining error held out (p = {u['p_value']:.2g})")
    if u.get("below_relevance"):
        return (f"left in the residual: a small structure: {what} removes {100 * u['fraction']:.1f} % of joint "
                f"{u['joint']}'s remaining error held out (p = {u['p_value']:.2g}), under the "
                f"{100 * u['below_relevance']:.0f} % of the error or the {100 * u.get('min_share', 0):.1f} % of the "
                f"torque ({100 * u.get('share', 0):.2f} % here) that count")
    return (f"left in the residual: no structure beyond noise (best: {u.get('against')} on joint {u.get('joint')}, "
            f"{100 * u.get('fraction', 0):.0f} %, p = {u.get('p_value', 1):.2g})")
