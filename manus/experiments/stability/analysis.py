"""The analyses of chapter 4 and Appendix D, each returning plain JSON-ready numbers.

- `eq41_poles`: the closed-loop poles of eq. 4.1 at the clinical gains (k = 100, b_c = 2).
- `type1_curves`: the Type 1 threshold k_max(b_c) of the linear model — the thesis's analysis
  (continuous, 1 ms delay, Padé) uncoupled and against the springs of table 4.2 (eq. 4.2), and
  the exactly sampled loop at 1 kHz (with and without the shaft mode).
- `negative_damping`: the most negative b_c that stays stable (thesis: −1.5 N·s/m, "as much
  negative damping as there is real physical damping"), simulated and linear.
- `appendix_d`: the stability maps at 100 Hz sampling, uncoupled and against 1050 and 3826 N/m.
- `psd_conventions`: a map's Type 2 boundary under each normalization of the PSD threshold.
- `type2_example`: a point just past the Type 2 threshold, whose step response shows it.
"""

from __future__ import annotations

import numpy as np

from manus.experiments.stability.linear import SPRINGS, LinearAxis, curve
from manus.experiments.stability.search import boundary, edge, read_map, slope, stability_map
from manus.experiments.stability.steptest import TYPE1, TYPE2, StepTest

THESIS_POLES = [-186.5, complex(-1.7, 9.9), complex(-1.7, -9.9)]  # §3.7, k = 100, b_c = 2
THESIS_NEGATIVE_DAMPING = -1.5  # N·s/m, §4.5
APPENDIX_D_SPRINGS = (0.0, 1050.0, 3826.0)  # N/m
APPENDIX_D_TEST = StepTest(rate_hz=100.0, step=0.002)  # test 3 of Appendix D: a 2 mm step at 100 Hz
THESIS_AXIS = LinearAxis()  # the linear model of chapter 4

# Equivalent thresholds, in our normalization (|X|²/N at 1 kHz, a line of amplitude A reads
# 250 A²), of 10⁻⁶ read in other conventions: a one-sided density in m²/Hz over 1 s (A²/2), and
# MATLAB's Welch `psd` with a 256-point Hann window (A² 256/6).
PSD_CONVENTIONS = {
    "fft |X|^2/N (ours)": 1e-6,
    "one-sided density m^2/Hz": 1e-6 * 250 / 0.5,
    "Welch Hann-256": 1e-6 * 250 / (256 / 6),
}


def finite(x):
    """Numbers for JSON: a float, or a list of them, with nan and inf as None."""
    if np.ndim(x) == 0:
        v = float(x)
        return v if np.isfinite(v) else None
    return [finite(v) for v in np.asarray(x, float)]


def eq41_poles(k: float = 100.0, b_c: float = 2.0) -> dict:
    import control

    p = np.sort_complex(control.poles(LinearAxis(delay=0.0).closed_loop(k, b_c)))
    wn = float(np.abs(p[np.argmax(np.abs(np.imag(p)))]))
    return {
        "k": k,
        "b_c": b_c,
        "poles": [[float(z.real), float(z.imag)] for z in p],
        "thesis": [[float(np.real(z)), float(np.imag(z))] for z in THESIS_POLES],
        "natural_hz": wn / (2 * np.pi),
        "damping_ratio": float(-p[np.argmax(np.abs(np.imag(p)))].real / wn),
    }


def type1_curves(b_cs, base: LinearAxis = THESIS_AXIS, springs=(0.0, *SPRINGS), rate_hz: float = 1000.0) -> dict:
    """k_max per b_c: continuous (the thesis's analysis) for each spring; sampled at `rate_hz`
    uncoupled, rigid and with the shaft mode (the linear face of Type 2)."""
    from manus.plants.effects import Compliance

    b_cs = np.asarray(b_cs, float)
    return {
        "b_c": b_cs.tolist(),
        "continuous": {f"{s:g}": finite(curve(base.with_(spring=s), b_cs)) for s in springs},
        "sampled": finite(curve(base, b_cs, rate_hz)),
        "sampled_shaft": finite(curve(base.with_(shaft=Compliance()), b_cs, rate_hz)),
        "rate_hz": rate_hz,
    }


def negative_damping(test: StepTest, ks=(10.0, 30.0, 100.0, 300.0), cluster=None) -> dict:
    """The most negative stable b_c at each k: step tests (edge along b_c from 0 down to −3),
    the sampled linear model and the continuous one."""
    ks = np.asarray(ks, float)
    e = edge(test, ks, 0.0, -3.0, along="b_c", points=(16, 24), cluster=cluster)
    lin = test.linear()
    sampled = np.array([lin.b_c_min(k, test.rate_hz) for k in ks])
    best = int(np.nanargmin(e.limit)) if np.isfinite(e.limit).any() else 0
    return {
        "k": ks.tolist(),
        "simulated": finite(e.limit),
        "resolution": float(np.max(np.abs(e.step))),
        "linear_sampled": finite(sampled),
        "linear_continuous": finite([lin.b_c_min(k) for k in ks]),
        "limit": finite(e.limit[best]),
        "at_k": float(ks[best]),
        "physical_damping": test.damping,
        "thesis": THESIS_NEGATIVE_DAMPING,
    }


def map_summary(smap, lin: LinearAxis, rate_hz: float) -> dict:
    """The thresholds a map shows, with the linear curves at its b_c values."""
    t1, t2 = boundary(smap, TYPE1), boundary(smap, TYPE2)
    ok = np.isfinite(smap.limit)
    peak = int(np.nanargmax(np.where(ok, smap.limit, -np.inf))) if ok.any() else 0
    return {
        "b_c": smap.b_cs.tolist(),
        "k": smap.ks.tolist(),
        "points": int(smap.kinds.size),
        "limit": finite(smap.limit),
        "limit_kind": smap.limit_kind.tolist(),
        "type1_boundary": t1,
        "type2_boundary": t2,
        "type1_slope": finite(slope(t1)),
        "type2_slope": finite(slope(t2)),
        "peak": {"b_c": float(smap.b_cs[peak]), "k": float(smap.limit[peak])} if ok.any() else None,
        "stable_fraction": float(np.mean(smap.kinds == 0)),
        "linear_sampled": finite(curve(lin, smap.b_cs, rate_hz)),
    }


def appendix_d(
    b_cs,
    ks,
    springs=APPENDIX_D_SPRINGS,
    base: StepTest = APPENDIX_D_TEST,
    cluster=None,
    progress: bool = True,
) -> tuple[dict, dict]:
    """Maps at 100 Hz (Appendix D: test 3's 2 mm step) for each spring -> (summary, maps)."""
    maps, out = {}, {"rate_hz": base.rate_hz, "step": base.step, "springs": {}}
    for s in springs:
        test = base.with_(spring=float(s))
        maps[s] = stability_map(test, b_cs, ks, cluster, progress)
        out["springs"][f"{s:g}"] = map_summary(maps[s], test.linear(), base.rate_hz)
    return out, maps


def psd_conventions(test: StepTest, smap) -> dict:
    """The Type 2 boundary of a map read with the threshold of each PSD convention (`PSD_CONVENTIONS`)."""
    return {
        name: {
            "threshold": thr,
            "type2_boundary": boundary(read_map(test, smap.b_cs, smap.ks, smap.metrics, psd_threshold=thr), TYPE2),
        }
        for name, thr in PSD_CONVENTIONS.items()
    }


def type2_example(smap) -> tuple[float, float] | None:
    """A point just past the Type 2 threshold (Fig. 4-22): the first unstable k of the Type 2
    row nearest the middle of that edge."""
    rows = np.flatnonzero((smap.limit_kind == TYPE2) & np.isfinite(smap.limit))
    if rows.size == 0:
        return None
    r = rows[len(rows) // 2]
    j = int(np.searchsorted(smap.ks, smap.limit[r])) + 1
    return float(smap.ks[min(j, len(smap.ks) - 1)]), float(smap.b_cs[r])
