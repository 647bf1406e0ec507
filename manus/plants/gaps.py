"""Samples lost from a recording's time column: where (`gaps`), the recording put back on its
uniform grid with them filled (`on_grid`), and which samples the analysis must leave out
(`spoiled`).

Filters and differences assume one sample per period. A real-time loop that misses packets
(`run-hardware` writes t = seq·T, so a lost sample is a step of 2T) breaks that; a logger whose
time stamps jitter does not, and must not be read as if it did.
"""

from __future__ import annotations

from dataclasses import dataclass, replace

import numpy as np
from scipy.interpolate import CubicSpline

from manus.plants.errors import RecordingError
from manus.plants.recording import Recording

GAP = 1.5  # a step of t longer than this many sample periods: samples were lost there
MAX_FILL = 1.0  # at most this many missing samples per recorded one are filled (else: separate runs)


@dataclass(frozen=True)
class Gaps:
    """Where a recording's time column jumps: samples lost (a real-time loop that missed packets:
    `run-hardware` writes t = seq·T, so a lost sample is a step of 2T)."""

    at: np.ndarray  # indices (in the recording) of the first sample after each gap
    missing: np.ndarray  # samples missing in each

    def __bool__(self) -> bool:
        return bool(self.at.size)

    def describe(self, rec: Recording) -> str:
        first = int(self.at[0])
        return (
            f"{int(self.missing.sum())} sample{'s' if self.missing.sum() != 1 else ''} lost in {self.at.size} "
            f"gap{'s' if self.at.size != 1 else ''} of the time column (the first: t jumps from "
            f"{rec.t[first - 1]:.6g} to {rec.t[first]:.6g} s)"
        )


JITTER_WINDOW = 10  # samples either side of a long step whose time stamps say whether samples were lost
CLEAN = 0.1  # stamps are clean when 99 % of the steps lie this close (in periods) to a whole number of periods


def gaps(rec: Recording) -> Gaps:
    """The recording's gaps: where samples are missing, not where a time stamp is late.

    Clean time stamps (a sample counter, t = seq·T as `run-hardware` writes them: every step
    within `CLEAN` of a whole number of periods) count each long step as the periods it spans,
    less one. Stamps that jitter (a logger reading a busy computer's clock) are late and then
    early again, while a lost sample moves every later stamp on by a period: at each step longer
    than `GAP` periods the lag of the stamps behind their count, (t − t₀)/T − index, is compared
    either side (its median over `JITTER_WINDOW` samples, which jitter and a slow drift of the
    clock do not move by a whole period), and the gap counts as the whole periods it moved."""
    dt, t = rec.dt, rec.t
    steps = np.diff(t) / dt
    long = np.flatnonzero(steps > GAP)
    if not long.size or np.percentile(np.abs(steps - np.rint(steps)), 99) < CLEAN:
        return Gaps(long + 1, np.rint(steps[long]).astype(np.int64) - 1)
    lag = (t - t[0]) / dt - np.arange(len(t))
    w = JITTER_WINDOW
    moved = np.array(
        [np.rint(np.median(lag[i + 1 : i + 1 + w]) - np.median(lag[max(i + 1 - w, 0) : i + 1])) for i in long]
    ).astype(np.int64)
    return Gaps(long[moved >= 1] + 1, moved[moved >= 1])


def on_grid(rec: Recording) -> tuple[Recording, np.ndarray]:
    """The recording on its uniform sample grid, and which of its samples were filled in.

    Filters and differences assume one sample per period. Where samples were lost, the grid
    goes on across the gap and the lost samples are filled, so that no filter sees a jump: the
    positions by a cubic spline (a straight line errs toward the chord, by −q̈ (m + 1)² T² / 8: a
    bias in the acceleration that follows the motion; on the calibration set with 1 % of the
    samples lost, seed 0, a straight line and the guard it needs named 176 of 220 hidden effects,
    Stribeck 10 of 20, the cubic 186 and 15, the whole recordings 188 and 17), the torques and any
    other column by straight lines; the mask says which are filled, for the analysis to leave out
    (`spoiled`). A recording without gaps comes back as it is. A gap longer than the recording
    itself (two runs in one file) is refused: there is nothing to fill it from."""
    g = gaps(rec)
    if not g:
        return rec, np.zeros(len(rec), bool)
    if g.missing.sum() > MAX_FILL * len(rec):
        raise RecordingError(
            f"{rec.path}: {g.describe(rec)}: more samples are missing than recorded; "
            "the file holds separate runs: split it at the gap"
        )
    steps = np.ones(len(rec) - 1, np.int64)
    steps[g.at - 1] = g.missing + 1
    k = np.r_[0, np.cumsum(steps)]  # each recorded sample's place on the grid
    grid = np.arange(k[-1] + 1)
    filled = np.ones(grid.size, bool)
    filled[k] = False

    def fill(x) -> np.ndarray:
        x = np.asarray(x, float)
        flat = x.reshape(len(rec), -1)
        out = np.stack([np.interp(grid, k, flat[:, j]) for j in range(flat.shape[1])], 1)
        return out.reshape((grid.size,) + x.shape[1:])

    q = fill(rec.q)
    q[filled] = CubicSpline(k, rec.q, axis=0)(grid[filled])
    return Recording(
        rec.t[0] + grid * rec.dt,
        q,
        fill(rec.tau),
        None if rec.qd is None else fill(rec.qd),
        dict(rec.meta),
        {name: fill(v) for name, v in rec.extra.items()},
        rec.path,
        rec.serial,
        rec.time_base,
    ), filled


def spoiled(filled: np.ndarray, qdd: np.ndarray, dt: float, step: float, guard: int) -> np.ndarray:
    """The samples a filled gap spoils: the filled ones, and where the cubic across the gap may be
    off the motion by more than an encoder step (5/384 |q⁗| (m + 1)⁴ T⁴ for m samples lost, q⁗
    the largest over the gap and as long either side, from `qdd`: a quantizer's error, which the
    filters are made for, is up to half a step at every sample), the `guard` samples either side
    too (a filter's settling: it spreads the error)."""
    out = filled.copy()
    edges = np.diff(np.r_[0, filled.astype(np.int8), 0])
    q4 = np.abs(np.gradient(np.gradient(qdd, dt, axis=0), dt, axis=0))
    for a, b in zip(np.flatnonzero(edges == 1), np.flatnonzero(edges == -1), strict=True):
        m = b - a
        off = np.max(q4[max(a - m - 1, 0) : b + m + 1]) * 5 / 384 * ((m + 1) * dt) ** 4
        if not off < step:  # (no encoder step known: always)
            out[max(a - guard, 0) : b + guard] = True
    return out


OUTLIER = 10.0  # a torque sample over this many times its joint's 99.5th percentile of |τ| is not a measurement


def torque_outliers(rec: Recording) -> tuple[Recording, np.ndarray, str]:
    """Torque samples nothing else in the recording comes near (a logger's glitch, a value in
    another unit): over `OUTLIER` times their joint's 99.5th percentile of |τ| (a 22 N·m arm
    logging one 1e6). Returns the recording with each replaced by a straight line between its
    neighbours (the filters see no spike), which samples they are (to be left out as filled
    samples are, `spoiled`), and a sentence saying so ('' when there are none)."""
    tau = np.asarray(rec.tau, float)
    scale = np.percentile(np.abs(tau), 99.5, axis=0)
    scale = np.maximum(scale, 1e-3 * float(scale.max(initial=0.0)) + 1e-12)  # (a joint that is never driven)
    wild = np.abs(tau) > OUTLIER * scale
    rows = np.asarray(wild.any(axis=1))
    if not rows.any() or rows.all():
        return rec, np.zeros(len(rec), bool), ""
    i = int(np.argmax(rows))
    j = int(np.argmax(wild[i]))
    idx = np.arange(len(rec))
    clean = tau.copy()
    for k in range(tau.shape[1]):
        clean[rows, k] = np.interp(idx[rows], idx[~rows], tau[~rows, k])
    note = (
        f"{int(rows.sum())} torque sample{'s' if rows.sum() != 1 else ''} far outside the rest (the first at "
        f"t = {rec.t[i]:.4g} s: tau{j + 1} = {tau[i, j]:.4g}, {abs(tau[i, j]) / scale[j]:.3g}× that joint's 99.5th "
        "percentile): replaced by their neighbours for the filters"
    )
    return replace(rec, tau=clean), rows, note
