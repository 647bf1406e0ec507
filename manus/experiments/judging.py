"""The calibration set judged: a case (`manus.experiments.calibration`, or the independent
simulator's) diagnosed and its verdict set against what was hidden — `quiet` or a `false alarm`
with nothing hidden; `named`, a `reading` (a verdict that names the hidden effect among the
effects the recording hardly tells apart), `missed` or `wrong` with something hidden; an `error`
(a one-line refusal) or a `crash` — and the rates over a set, with Wilson intervals, overall,
per effect and per condition (`summarize`). With `baseline`, each recording is diagnosed a
second time with relevance over all the torque only (`diagnose(..., per_joint=False)`), and its
outcome kept beside (`before`): the two rules compared on the same recordings."""

from __future__ import annotations

import math
import time
from typing import Any

import numpy as np

CONDITION_KEYS = ("structure", "rate", "excitation", "torque", "hold", "friction", "transmission", "log", "engine")
Z95 = 1.959963984540054


def wilson(k: int, n: int, z: float = Z95) -> tuple[float, float]:
    """The Wilson score interval of a proportion k/n (95 % by default); (0, 1) when n = 0."""
    if n == 0:
        return 0.0, 1.0
    p = k / n
    centre = (p + z * z / (2 * n)) / (1 + z * z / n)
    half = z * math.sqrt(p * (1 - p) / n + z * z / (4 * n * n)) / (1 + z * z / n)
    return max(0.0, centre - half), min(1.0, centre + half)


def rate(k: int, n: int) -> dict:
    lo, hi = wilson(k, n)
    return {"k": k, "n": n, "rate": k / n if n else None, "lo": lo, "hi": hi}


def case_seed(seed: int, effect_index: int, i: int) -> int:
    """The seed of recording i of the set for one hidden effect (index 0: nothing hidden)."""
    return int(np.random.SeedSequence([seed, effect_index, i]).generate_state(1)[0] % 2**31)


def judge(
    seed: int,
    hidden: str | None,
    alpha: float | None = None,
    blocks: int | None = None,
    rates: tuple | None = None,
    amplitude: float | None = None,
    lost: float = 0.0,
    simulator: str = "manus",
    baseline: bool = False,
    robots: tuple | None = None,
) -> dict:
    """Simulate one calibration recording and diagnose it; never raises (a ManusError is an
    `error`, anything else a `crash`, both reported). `robots`: the chains a `chain` recording's
    robot is drawn from (default `manus.experiments.chains.DRAWN`). `lost`: the fraction of its samples lost
    at random (seeded by the case), as a loop that misses packets loses them."""
    import traceback

    from manus.adaptive import diagnose
    from manus.experiments import calibration
    from manus.plants.errors import ManusError

    out = {"seed": seed, "hidden": hidden}
    try:
        if simulator == "independent":
            from manus.experiments import independent

            c = independent.case(seed, hidden, rates or independent.RATES, amplitude or calibration.AMPLITUDE)
        elif simulator == "chain":
            from manus.experiments import chains

            c = chains.case(seed, hidden, rates or chains.RATES, amplitude or chains.AMPLITUDE, robots or chains.DRAWN)
        else:
            c = calibration.case(seed, hidden, rates or calibration.RATES, amplitude or calibration.AMPLITUDE)
    except Exception as e:  # the simulator: a bug of the bench, reported as a crash
        out.update(outcome="crash", error=f"case: {type(e).__name__}: {e}", trace=traceback.format_exc(limit=6))
        return out
    out.update(condition=c.condition, joint=c.joint, start=c.start, simulate_s=c.seconds)
    rec = c.rec
    if lost:
        keep = np.random.default_rng([seed, 1]).random(len(rec)) >= lost
        keep[[0, -1]] = True
        rec = rec.rows(keep)
        out["condition"] = {**c.condition, "lost_samples": int((~keep).sum())}
    t0 = time.perf_counter()
    try:
        options: dict[str, Any] = {k: v for k, v in (("alpha", alpha), ("blocks", blocks)) if v is not None}
        d = diagnose(rec, c.start, **options)
    except ManusError as e:
        out.update(outcome="error", error=str(e), diagnose_s=time.perf_counter() - t0)
        return out
    except Exception as e:
        out.update(
            outcome="crash",
            error=f"{type(e).__name__}: {e}",
            trace=traceback.format_exc(limit=8),
            diagnose_s=time.perf_counter() - t0,
        )
        return out
    out["diagnose_s"] = time.perf_counter() - t0
    v = d.verdict
    out["verdict"] = None if v is None else v.effect
    out["verdict_spec"] = None if v is None else v.spec
    out["verdict_joint"] = None if v is None else int(v.joint)
    out["unexplained"] = bool(d.unexplained.get("significant"))
    out["candidates"] = [
        {k: c[k] for k in ("spec", "joint", "p_value", "cv_error_reduction", "significant")}
        | ({"not_proposed": c["not_proposed"]} if "not_proposed" in c else {})
        | {k: c["detail"][k] for k in ("p_values", "explains") if k in c["detail"]}
        for c in d.report()["candidates"]
    ]
    out["verdict_reads_as"] = [] if v is None else list(v.readings)
    # the detection limit diagnose states for the hidden effect's candidate (share of the torque)
    own = next((x for x in d.candidates if x.effect == hidden), None) if hidden else None
    if own is not None and own.detail.get("detectable") is not None:
        out["detectable"] = own.detail["detectable"]
    spec = c.condition.get("hidden_spec")
    out.update(_outcome(v, hidden, c.joint, spec))
    if baseline:
        try:
            b = diagnose(rec, c.start, per_joint=False, **options).verdict
            out["before"] = {"verdict_spec": None if b is None else b.spec, **_outcome(b, hidden, c.joint, spec)}
        except ManusError as e:
            out["before"] = {"outcome": "error", "error": str(e)}
    return out


def _outcome(v, hidden: str | None, joint: int | None, spec: str | None = None) -> dict:
    """How a verdict `v` (a Candidate or None) stands against what was hidden (`spec`: a hidden
    coupling's, named or a reading only with its joints and sign)."""
    if hidden is None:
        return {"outcome": "quiet" if v is None else "false alarm"}
    from manus.experiments.chains import same_coupling

    named = v is not None and v.effect == hidden and (spec is None or same_coupling(v.spec, spec))
    # the verdict says the recording hardly tells it from the hidden effect (a tilted plane,
    # a spring with its preload and an offset on a small swing) and names that reading too
    reading = bool(
        not named
        and v is not None
        and any(hidden in _effects(x) and (spec is None or same_coupling(x, spec)) for x in v.readings)
    )
    right = bool(v is not None and (named or reading) and (joint is None or v.joint == joint))
    outcome = "named" if named else ("reading" if reading else "missed" if v is None else "wrong")
    return {"named": bool(named), "reading": reading, "right_joint": right, "outcome": outcome}


def _effects(spec: str) -> set[str]:
    """The effect names of a model spec ("offset,spring" -> {offset, spring}; "cogging:39" -> {cogging})."""
    return {part.split(":")[0].strip() for part in spec.split(",") if part.strip()}


def summarize(results: list[dict]) -> dict:
    """False-alarm and detection rates, overall, per effect and per condition value."""
    nulls = [r for r in results if r["hidden"] is None]
    hidden = [r for r in results if r["hidden"] is not None]

    def alarms(rs):
        return rate(sum(r["outcome"] == "false alarm" for r in rs), len(rs))

    def detections(rs):
        return {
            "named": rate(sum(bool(r.get("named")) for r in rs), len(rs)),
            "named_or_reading": rate(sum(bool(r.get("named") or r.get("reading")) for r in rs), len(rs)),
            "right_joint": rate(sum(bool(r.get("right_joint")) for r in rs), len(rs)),
        }

    per_effect = {}
    for name in dict.fromkeys(r["hidden"] for r in hidden):
        rs = [r for r in hidden if r["hidden"] == name]
        per_effect[name] = {**detections(rs), "verdicts": _counts(r.get("verdict") or r["outcome"] for r in rs)}
    per_condition = {}
    for key in CONDITION_KEYS:
        values = sorted({str(r["condition"][key]) for r in results if key in r.get("condition", {})})
        per_condition[key] = {
            v: {
                "false_alarm": alarms([r for r in nulls if str(r.get("condition", {}).get(key)) == v]),
                **detections([r for r in hidden if str(r.get("condition", {}).get(key)) == v]),
            }
            for v in values
        }
    distinct = [r for r in hidden if _distinct(r)]
    # the stated detection limit against the truth: the hidden effect's distinct share at or above
    # the limit diagnose states for its candidate on that recording, and below it
    limited = [r for r in hidden if r.get("detectable") is not None and "distinct_fraction" in r.get("condition", {})]
    above = [r for r in limited if r["condition"]["distinct_fraction"] >= r["detectable"]]
    below = [r for r in limited if r["condition"]["distinct_fraction"] < r["detectable"]]
    times = [r["diagnose_s"] for r in results if "diagnose_s" in r]
    sims = [r["simulate_s"] for r in results if "simulate_s" in r]
    missed = [r for r in hidden if r["outcome"] == "missed"]
    compared = [r for r in results if "before" in r]
    before = [{**r, **r["before"]} for r in compared]
    return {
        "before": {  # the same recordings judged with relevance over all the torque only
            "false_alarm": alarms([r for r in before if r["hidden"] is None]),
            "detection": detections([r for r in before if r["hidden"] is not None]),
            "per_effect": {
                name: detections([r for r in before if r["hidden"] == name])
                for name in dict.fromkeys(r["hidden"] for r in before if r["hidden"] is not None)
            },
        }
        if compared
        else None,
        "false_alarm": alarms(nulls),
        "false_alarm_verdicts": _counts(r.get("verdict") for r in nulls if r["outcome"] == "false alarm"),
        # "something is left that no effect explains": said on a recording with nothing missing
        # (a false alarm of its own), and said where the hidden effect was not named
        "unexplained_on_null": rate(
            sum(bool(r.get("unexplained")) for r in nulls if "unexplained" in r), sum("unexplained" in r for r in nulls)
        ),
        "unexplained_when_missed": rate(sum(bool(r.get("unexplained")) for r in missed), len(missed)),
        "detection": detections(hidden),
        # the recordings whose hidden effect has a part of its own no other reading explains
        "detection_where_distinct": {
            **detections(distinct),
            "threshold": DISTINCT,
            "per_effect": {
                name: detections([r for r in distinct if r["hidden"] == name])
                for name in dict.fromkeys(r["hidden"] for r in distinct)
            },
        },
        "detection_by_limit": {"at_or_above": detections(above), "below": detections(below)},
        "per_effect": per_effect,
        "per_condition": per_condition,
        "errors": sum(r["outcome"] == "error" for r in results),
        "null_errors": sum(r["outcome"] == "error" for r in nulls),
        "crashes": sum(r["outcome"] == "crash" for r in results),
        "diagnose_s_per_recording": {
            "mean": float(np.mean(times)) if times else None,
            "median": float(np.median(times)) if times else None,
            "max": float(np.max(times)) if times else None,
        },
        "simulate_s_per_recording": {"mean": float(np.mean(sims)) if sims else None},
    }


DISTINCT = 0.025  # a hidden effect is distinct when this share of the torque is its own (half its size)


def _distinct(r: dict) -> bool:
    """Whether a hidden effect left a part no other reading explains of at least `DISTINCT` of
    the torque (`manus.experiments.sizing.distinct`; a delay: what it changes in the torque; a
    mode: counted, its share is not measured). The independent simulator measures neither: its
    recordings do not count here."""
    c = r.get("condition", {})
    if "distinct_fraction" in c:
        return c["distinct_fraction"] >= DISTINCT
    if r["hidden"] == "delay":
        return max(c.get("hidden_fraction", [0.0])) >= DISTINCT
    return r["hidden"] == "compliance" and "condition" in r


def _counts(items) -> dict:
    out: dict = {}
    for x in items:
        out[str(x)] = out.get(str(x), 0) + 1
    return dict(sorted(out.items(), key=lambda kv: -kv[1]))
