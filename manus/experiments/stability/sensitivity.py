"""How the thresholds move with the delay, the quantization step and the sampling rate (§4.5).

The thesis's brief summary, checked here: "decreasing time delay raises both Type 1 and Type 2
thresholds", "decreasing the quantization step raises the Type 2 threshold", and "increasing
the sampling frequency lowers the Type 2 threshold" (which it puts down to the discrete velocity
estimate).

For each setting the step test's limits are found by `edge`: the largest stable k at a few b_c
(0 and 5 N·s/m lie on the Type 1 side of the map, 20–30 on the Type 2 side) and the largest
stable b_c at k = 300 N/m (where the Type 2 edge meets low stiffness). A claim is checked on the
probes where the threshold of its type can be compared between neighbouring values of the
parameter: *reproduced* when each moves the claimed way by more than the search's resolution,
*partly* when some do, *contradicted* when each moves the other way, *unchanged* when none
moves, *not reproduced* otherwise.
"""

from __future__ import annotations

from itertools import pairwise

from manus.experiments.stability.analysis import finite
from manus.experiments.stability.search import edge
from manus.experiments.stability.steptest import KINDS, TYPE1, TYPE2, StepTest

PROBE_B_C = (0.0, 5.0, 20.0, 25.0, 30.0)  # N·s/m: k limits found here
THESIS_TEST = StepTest()  # the thesis's step test
PROBE_K = 300.0  # N/m: the b_c limit found here
VARIATIONS = {
    "delay": (0.0, 0.0005, 0.001, 0.002),
    "quantum": (1.2e-5, 2.4e-5, 4.8e-5),
    "rate_hz": (500.0, 1000.0, 2000.0),
}
# (parameter, claim, instability type, how the parameter changes, how the threshold should move)
CLAIMS = (
    ("delay", "less delay raises the Type 1 threshold", TYPE1, "down", "up"),
    ("delay", "less delay raises the Type 2 threshold", TYPE2, "down", "up"),
    ("quantum", "a finer quantizer raises the Type 2 threshold", TYPE2, "down", "up"),
    ("rate_hz", "faster sampling lowers the Type 2 threshold", TYPE2, "up", "down"),
)


def limits(test: StepTest, cluster=None, native: bool = False) -> list[dict]:
    """The probes' limits for one setting: [{"probe", "b_c" or "k", "limit", "step", "kind"}]."""
    k_edge = edge(test, PROBE_B_C, 30.0, 3e4, cluster=cluster, native=native)
    b_edge = edge(test, [PROBE_K], 0.0, 60.0, along="b_c", cluster=cluster, native=native)
    rows = [
        {"probe": f"k at b_c={b:g}", "limit": finite(x), "step": float(s), "kind": KINDS[int(c)]}
        for b, x, s, c in zip(PROBE_B_C, *k_edge, strict=True)
    ]
    rows.append(
        {
            "probe": f"b_c at k={PROBE_K:g}",
            "limit": finite(b_edge.limit[0]),
            "step": float(b_edge.step[0]),
            "kind": KINDS[int(b_edge.kind[0])],
        }
    )
    return rows


def sensitivity(base: StepTest = THESIS_TEST, variations=None, cluster=None) -> dict:
    """Limits for every value of every parameter (the others at `base`), and the claims.

    Two readings of the thesis are checked beside the default (the PSD of the measured
    position, normalized to read the same at every rate): the quantizer with the PSD of the
    true motor position (Simulink may have logged the plant's output before its quantizer),
    and the sampling rate with the PSD taken literally as |X|²/N (N grows with the rate)."""
    variations = VARIATIONS if variations is None else variations
    tables = [(name, name, base, False) for name in variations]
    if "quantum" in variations:
        tables.append(("quantum (PSD of the true position)", "quantum", base.with_(signal="true"), False))
    if "rate_hz" in variations:
        tables.append(("rate_hz (PSD as |X|²/N at each rate)", "rate_hz", base, True))
    out = {"base": {k: getattr(base, k) for k in variations}, "tables": [], "claims": []}
    for label, name, test, native in tables:
        rows = [{"value": v, "probes": limits(test.with_(**{name: v}), cluster, native)} for v in variations[name]]
        out["tables"].append({"label": label, "parameter": name, "rows": rows})
        out["claims"] += [
            check(rows, text, kind, change, move) | {"parameter": name, "reading": label}
            for p, text, kind, change, move in CLAIMS
            if p == name and (label == name or kind == TYPE2)
        ]
    return out


def check(rows: list[dict], claim: str, kind: int, change: str, move: str) -> dict:
    """Does each probe's threshold of type `kind` move `move` ("up"/"down") as the parameter
    goes `change`? A probe that met the other instability first (or none) bounds this type's
    threshold from below; consecutive values are compared where the bounds decide."""
    rows = sorted(rows, key=lambda r: r["value"], reverse=change == "down")
    want = 1 if move == "up" else -1
    outcome = {}
    for j, probe in enumerate(rows[0]["probes"]):
        seq = [r["probes"][j] for r in rows]
        signs = [s for a, b in pairwise(seq) if (s := _direction(a, b, KINDS[kind])) is not None]
        if signs:
            outcome[probe["probe"]] = (
                "as claimed"
                if all(s == want for s in signs)
                else "opposite"
                if all(s == -want for s in signs)
                else "unchanged"
                if all(s == 0 for s in signs)
                else "mixed"
            )
    votes = set(outcome.values())
    verdict = (
        "not comparable"
        if not votes
        else "reproduced"
        if votes == {"as claimed"}
        else "partly"
        if "as claimed" in votes
        else "contradicted"
        if votes == {"opposite"}
        else "unchanged"
        if votes == {"unchanged"}
        else "not reproduced"
    )
    return {"claim": claim, "verdict": verdict, "probes": outcome, "values": [r["value"] for r in rows]}


def _direction(a: dict, b: dict, kind: str) -> int | None:
    """+1 / −1 / 0 when the threshold of `kind` rises / falls / stays from probe a to probe b
    (beyond the searches' resolution); None when the bounds do not decide."""
    if a["limit"] is None or b["limit"] is None:  # unstable from the start: no edge
        return None
    res = max(abs(a["step"]), abs(b["step"]))
    d = b["limit"] - a["limit"]
    exact_a, exact_b = a["kind"] == kind, b["kind"] == kind
    if exact_a and exact_b:
        return 1 if d > res else -1 if d < -res else 0
    if exact_a and d > res:  # b's threshold lies above its limit, itself above a's
        return 1
    if exact_b and d < -res:  # a's lies above its limit, above b's
        return -1
    return None
