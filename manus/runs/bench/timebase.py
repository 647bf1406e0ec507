"""`manus bench timebase`: how a logger's time-base corruptions (`manus.experiments.logs`) are
found and repaired on recordings whose truth is known (`manus.plants.timebase`).

Recordings: the calibration's null recordings (`manus.experiments.calibration.case`: the axis and
the arm, open and closed loop, torques exact or noisy), `--seeds` of them at each of `--rates`.

- **finding**: on each clean recording, whether anything is found (a false finding); on each
  corrupted one, whether its corruption is found, and (a device's log under load, whose every
  row is a sample) whether any row is lost.
- **fit**: over the first `--fit-seeds` seeds, `manus fit` of rigid,viscous,coulomb on the clean
  recording, on the corrupted one as it is (the baseline: the analysis without the repair) and
  on the repaired one: the torque error and the largest parameter difference from the clean fit
  (relative to the parameter, or to three standard deviations where that is larger).
"""

from __future__ import annotations

import math

import numpy as np

HELP = "the time base: logger corruptions found and repaired on known recordings, fits beside the unrepaired"
MODEL = "rigid,viscous,coulomb"
CORRUPTIONS = ("repeated rows", "jitter", "alternating", "held", "pc logger", "device log")


def add_arguments(p) -> None:
    p.add_argument("--seeds", type=int, default=12, help="null recordings per rate (default 12)")
    p.add_argument("--rates", default="1000,200,100", help="sample rates [Hz], comma-separated (default 1000,200,100)")
    p.add_argument("--fit-seeds", type=int, default=2, help="seeds per rate that are also fitted (default 2; 0: none)")


def corrupt(rec, seed: int) -> dict:
    from manus.experiments import logs

    rng = np.random.default_rng([seed, 7])
    return {
        "repeated rows": logs.repeat_rows(rec, 0.05, rng)[0],
        "jitter": logs.jitter_stamps(rec, 0.2, rng),
        "alternating": logs.alternate_stamps(rec),
        "held": logs.hold_positions(rec, 10),
        "pc logger": logs.pc_logger(rec, 0.15, rng),
        "device log": logs.device_log(rec, 0.03, rng),
    }


def found(name: str, tb, keep) -> bool:
    """Whether the finding `tb` names the corruption `name`, and keeps every row where every row is
    a sample."""
    if name == "repeated rows":
        return tb.repeated_rows > 0
    if name in ("jitter", "alternating"):
        return tb.jittered and bool(keep.all())
    if name == "held":
        return tb.held_every == 10 and tb.repaired
    if name == "device log":
        return tb.jittered and bool(keep.all())
    return bool(tb.repaired)


def _far(a, b) -> float:
    scale = {k: max(abs(v), 3 * (b.stds[k] if math.isfinite(b.stds[k]) else 0.0)) for k, v in b.params.items()}
    return max(abs(a.params[k] - b.params[k]) / scale[k] for k in b.params)


def _fit(rec):
    from manus.adaptive import fit
    from manus.plants.errors import ManusError

    try:
        return fit(rec, MODEL)
    except ManusError:
        return None


def run(args) -> dict:
    from manus.experiments.calibration import case, check_rates
    from manus.plants.errors import ManusError
    from manus.plants.recording import repair
    from manus.plants.timebase import examine
    from manus.runs.progress import note

    try:
        rates = check_rates(tuple(float(r) for r in str(args.rates).split(",") if r.strip()))
    except ValueError as e:
        raise ManusError(f"--rates {args.rates!r}: {e}") from None
    if args.seeds < 1 or not 0 <= args.fit_seeds <= args.seeds:
        raise ManusError("--seeds must be at least 1 and --fit-seeds between 0 and --seeds")
    clean_found = 0
    hits = {name: 0 for name in CORRUPTIONS}
    fits: dict = {name: {"blurred": [], "repaired": [], "far_blurred": [], "far_repaired": []} for name in CORRUPTIONS}
    clean_errors: list[float] = []
    n = 0
    for rate in rates:
        for seed in range(args.seeds):
            note(f"{rate} Hz, seed {seed} ...")
            rec = case(seed, None, rates=(rate,)).rec
            n += 1
            clean_found += bool(examine(rec)[0])
            blurred = corrupt(rec, seed)
            for name, bad in blurred.items():
                tb, keep, _ = examine(bad)
                hits[name] += found(name, tb, keep)
            if seed >= args.fit_seeds:
                continue
            clean = _fit(rec)
            if clean is None:
                continue
            clean_errors.append(clean.rel_error)
            for name, bad in blurred.items():
                for kind, r in (("blurred", _fit(bad)), ("repaired", _fit(repair(bad)))):
                    fits[name][kind].append(r.rel_error if r is not None else math.inf)
                    fits[name][f"far_{kind}"].append(_far(r, clean) if r is not None else math.inf)
    med = lambda x: float(np.median(x)) if x else None
    figures = {"recordings": n, "clean_found": clean_found, "clean_rel_error_median": med(clean_errors)}
    for name in CORRUPTIONS:
        key = name.replace(" ", "_")
        figures[f"{key}_found"] = hits[name]
        for kind in ("blurred", "repaired"):
            figures[f"{key}_{kind}_rel_error_median"] = med(fits[name][kind])
            figures[f"{key}_{kind}_far_median"] = med(fits[name][f"far_{kind}"])
    return {"figures": figures, "rates": list(rates), "seeds": args.seeds, "fit_seeds": args.fit_seeds}


def render(r: dict) -> str:
    from manus.runs.text import table

    f = r["figures"]
    pct = lambda v: "-" if v is None else ("refused" if not math.isfinite(v) else f"{100 * v:.2f} %")
    rows = [
        [
            "clean (nothing to find)",
            f"{f['clean_found']}/{f['recordings']} found",
            "",
            pct(f["clean_rel_error_median"]),
            "",
        ]
    ]
    for name in CORRUPTIONS:
        key = name.replace(" ", "_")
        rows.append(
            [
                name,
                f"{f[f'{key}_found']}/{f['recordings']}",
                f"{pct(f[f'{key}_blurred_rel_error_median'])} (params {pct(f[f'{key}_blurred_far_median'])})",
                f"{pct(f[f'{key}_repaired_rel_error_median'])}",
                f"{pct(f[f'{key}_repaired_far_median'])}",
            ]
        )
    head = (
        f"time base: {f['recordings']} null recordings ({r['seeds']} seeds at {', '.join(map(str, r['rates']))} Hz); "
        f"fits over {r['fit_seeds']} seeds per rate, medians\n"
    )
    return head + table(
        rows, ["recording", "found", "fit as it is (baseline)", "fit repaired", "repaired params vs clean"]
    )
