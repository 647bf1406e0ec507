"""A recording made ready for inverse-dynamics identification (`prepare` -> `Data`): the band,
the kinematics, the rows.

- the command u_k arrives `d` seconds late (the `delay` effect), so the torque acting at t_k is
  u read at fractional index k − d/T (linear interpolation). A digital controller holds each
  command over its period (zero-order hold: u_k acts on [t_k, t_k + T)), which looks like half a
  period of delay: that is sampling, not a physical effect. So the hold is the default
  (`command_hold: zoh`, also when the file does not say; `command_hold: none` reads u_k as acting
  at t_k), and every report says which was used (`hold`);
- the identification band (`auto_cutoff`) comes from the motion and the encoder, never from the
  torque: the band where the velocity's power lies (after the encoder's quantization noise is
  taken out of its spectrum), widened to let the friction steps through, and capped where the
  quantization noise in q̈ would exceed a small share of the motion's acceleration (noise in the
  regressor biases least squares toward zero: errors in variables). A cap is said in the report;
- parallel filtering (Gautier's procedure, as in the EMPS reference): the regressor columns are
  evaluated on kinematics from the zero-phase differentiator at a wider band (`KINEMATIC_BAND`
  times the cut-off), then each column and the torque are low-passed alike at the cut-off
  (`Data.smoothed`, `manus.adaptive.identify.columns`). For a linear term this is the usual
  filtering; for a non-linear one such as sgn(q̇) the step at a velocity reversal is smeared
  exactly as the friction step in the filtered torque is, instead of being compared sharp
  against a smooth torque;
- the columns and the torque are computed on a working grid, every `stride`-th sample, where the
  rate is far above the band: at least `WORK_RATE` samples per cut-off period remain (ten per
  period of the kinematic band, whose filter has taken the torque over 100 dB down at the
  grid's Nyquist frequency). Smooth columns are read at the grid's samples as the torque is; friction
  columns are averaged over each grid period (`manus.adaptive.identify.columns`), so their steps
  do not alias into the band. A 5 kHz log with a 10 Hz band is worked on at 417 Hz, a 1 kHz
  MANUS-2 recording with a 15 Hz band at its own rate;
- the filter's start-up transient is cut at both ends and the rows are decimated to about four
  samples per cut-off period (neighbouring rows of a low-passed signal carry no new information,
  and the standard deviations are computed from the decimated rows), on the working grid.
"""

from __future__ import annotations

import threading
from collections.abc import Callable
from dataclasses import dataclass, field
from typing import TypeVar

import numpy as np

from manus.estimators.offline import differentiate, edge, lowpass
from manus.plants.effects import Span
from manus.plants.errors import ModelError
from manus.plants.gaps import gaps, on_grid, spoiled, torque_outliers
from manus.plants.recording import Recording, smallest_step

MIN_CUTOFF_HZ = 2.0
MOTION_POWER = 0.99  # the motion band holds this share of the velocity's power
BAND_FACTOR = 4.0  # the cut-off is this multiple of the motion band (friction steps are broadband)
NOISE_BUDGET = 0.05  # quantization noise in q̈ at most this share of the motion's q̈ (RMS)
STANDSTILL_S = 0.005  # longer under two counts per band period than a zero crossing takes: at rest
CREEP = 0.005  # a joint creeps (held against its friction, see `prepare`) under this share of its high speed ...
CREEP_S = 0.05  # ... for longer than this [s] (a reversal passes such speeds in a few milliseconds)
KINEMATIC_BAND = 4.0  # kinematics for the columns are filtered at this multiple of the cut-off
# periods of the kinematic band either side of a rest left out (that filter spreads the rest's
# torque before the rows are known: 5 % of its kernel lies beyond one period)
REST_GUARD = 1.0
MIN_WEIGHT = 0.5  # a row whose cut-off window holds less moving weight than this (deep in a rest) is left out
MIN_SAMPLES = 8  # below this the recording cannot even be differentiated
MIN_ROWS = 20  # fewer usable rows than this identify nothing reliably
WORK_RATE = 40.0  # the working grid keeps at least this many samples per cut-off period
PREFETCH_BYTES = 64e6  # a search's arrays held at once (shifted torques, columns: working grid) stay under this
# serial chains: a joint's equations are left out within JOINT_GUARD cut-off periods of each of its
# reversals (its speed under the standstill threshold for any time: under Coulomb friction even a
# reversal holds the joint for an instant, an unknown torque the filter spreads over about a period)
JOINT_STANDSTILL_S = 0.0
JOINT_GUARD = 1.0


R = TypeVar("R")

_TAU_LOCK = threading.RLock()  # guards `Data._tau`, the torque's filtered shifts kept, and `Data._kept`


@dataclass
class Data:
    """A recording made ready for inverse-dynamics identification."""

    rec: Recording
    cutoff_hz: float
    q: np.ndarray  # (T, n) positions, velocities, accelerations at the kinematic band, full rate
    qd: np.ndarray
    qdd: np.ndarray
    rows: np.ndarray  # indices of the samples used (edges cut, standstill left out, decimated)
    step: float  # the encoder grid (estimated when the file does not say)
    standstill: float  # fraction of the samples left out around standstill
    window: np.ndarray | None = None  # the samples inside the filter's start-up edges (standstill in, decimated)
    cutoff_note: str = ""  # how the cut-off was chosen (and what limited it)
    # serial chains: which joints' equations each used row keeps (rows, n) (the others stick there); None: all
    mask: np.ndarray | None = None
    lost: str = ""  # samples lost in gaps of the time column, filled and left out ("" when none)
    rest: np.ndarray | None = None  # (T,) samples where a joint is at rest: kept out of the cut-off's low-pass
    stride: int = 1  # the working grid: every `stride`-th sample (the rows are on it)
    _tau: dict = field(default_factory=dict)
    _kept: dict = field(default_factory=dict)  # `once`'s answers

    @property
    def hold(self) -> str:
        return self.rec.hold

    def span(self) -> Span:
        """What the effects' search spaces are derived from (see `manus.plants.effects.Span`);
        where the structure has a transmission θ = N q, with the same in actuator coordinates
        (`Span.actuators`: N q, N q̇, an encoder step of Σ_j |N_ij| steps on actuator i)."""
        q = self.q[self.rows] if self.rows.size else self.q
        qd = self.qd[self.rows] if self.rows.size else self.qd
        N = self.rec.structure.transmission

        def of(q: np.ndarray, qd: np.ndarray, step: float) -> Span:
            return Span(
                self.dt,
                len(self.rec) * self.dt,
                np.ptp(q, axis=0),
                step,
                np.percentile(np.abs(qd), 95, axis=0),
                self.rec.prismatic,
                step * self.cutoff_hz,
                self.cutoff_hz,
                np.median(np.abs(qd), axis=0),
            )

        if N is None:
            return of(q, qd, self.step)
        M = N.matrix
        return of(q, qd, self.step)._replace(
            actuators=of(q @ M.T, qd @ M.T, self.step * float(np.max(np.abs(M).sum(axis=1))))
        )

    @property
    def dt(self) -> float:
        return self.rec.dt

    @property
    def n_joints(self) -> int:
        return self.rec.n_joints

    @property
    def kinematic_hz(self) -> float:
        return min(KINEMATIC_BAND * self.cutoff_hz, 0.45 / self.dt)

    @property
    def work_dt(self) -> float:
        """The working grid's period [s]."""
        return self.dt * self.stride

    def work(self, x: np.ndarray) -> np.ndarray:
        """x (T, ...) at full rate read on the working grid (every `stride`-th sample)."""
        return x if self.stride == 1 else x[:: self.stride]

    def smoothed(self, x: np.ndarray, rows: np.ndarray | None = None) -> np.ndarray:
        """x (W, ...) on the working grid (`work`) through the cut-off, the samples at rest left
        out of it: the low-pass of x·m over the low-pass of m (m = 0 at rest; a normalized
        convolution). Each row is a weighted mean of moving samples only, the same weights for
        the torque and for every column, so the equations stay exact while the unknown stiction
        torque of a rest is kept out of its neighbours (`prepare`). `rows` (sample indices, on the
        working grid): only those samples of the result."""
        at = None if rows is None else rows // self.stride
        pick = (lambda y: y) if at is None else (lambda y: y[at])
        if self.rest is None or not self.rest.any():
            return pick(lowpass(x, self.work_dt, self.cutoff_hz))
        m = (~self.work(self.rest)).astype(float).reshape((-1,) + (1,) * (np.ndim(x) - 1))
        weight = pick(self.weight()).reshape((-1,) + m.shape[1:])
        return pick(lowpass(np.asarray(x) * m, self.work_dt, self.cutoff_hz)) / np.maximum(weight, 1e-12)

    def once(self, key: tuple, compute: Callable[[], R]) -> R:
        """What `compute()` gives, computed once for this data and kept under `key`: what depends
        on the recording alone and each step of a loop asks again (a structural mode's frequency
        response at the model's delay)."""
        with _TAU_LOCK:
            if key in self._kept:
                return self._kept[key]
        out = compute()
        with _TAU_LOCK:
            return self._kept.setdefault(key, out)

    def weight(self) -> np.ndarray:
        """(W,) `moving_weight` of the rests on the working grid (computed by `prepare`, kept here)."""
        if "weight" not in self._tau:
            assert self.rest is not None, "only a recording with rests is weighted"
            self._tau["weight"] = moving_weight(self.work(self.rest), self.work_dt, self.cutoff_hz)
        return self._tau["weight"]

    def tau(self, delay: float | np.ndarray = 0.0, full: bool = False) -> np.ndarray:
        """The torque acting on the joints, aligned with the positions, filtered like the columns,
        on the used rows (`full`: at every sample of the working grid).
        (The kinematic band's low-pass and the fractional shift are linear and time-invariant:
        they commute, so the torque goes through that filter once. The cut-off's low-pass leaves
        the rests of the motion out, so it follows the shift: the torque that acted at a moving
        sample is the one recorded `delay` earlier.)"""
        hold = 0.5 if self.hold == "zoh" else 0.0
        with _TAU_LOCK:  # (candidates are judged on threads: the shifts kept are shared)
            if "band" not in self._tau:
                self._tau["band"] = lowpass(self.rec.tau, self.dt, self.kinematic_hz)
            out = self._late(np.asarray(delay, float) / self.dt + hold)
        if full:
            return out
        at = self.rows // self.stride
        return out[at] if self.mask is None else out[at] * self.mask

    def _late(self, lag: np.ndarray) -> np.ndarray:
        """`smoothed(align(band, lag))`, built from the smoothed whole-sample shifts either side
        of each joint's lag: `align` interpolates linearly between them and `smoothed` is linear,
        so a search over delays filters each whole shift once, however many fractions it asks
        (the shifts are kept; the weighted sum of two of them is cheap and made per call)."""
        held = [k for k in self._tau if isinstance(k, tuple)]
        if sum(self._tau[k].nbytes for k in held) > PREFETCH_BYTES:  # (a delay search asks for many shifts)
            for k in held:
                del self._tau[k]
        band = self._tau["band"]
        lags = np.broadcast_to(lag, band.shape[1:])
        out = np.zeros_like(self.work(band))
        for j, x in enumerate(lags):
            i = np.floor(x)
            for shift, weight in ((i, 1 - (x - i)), (i + 1, x - i)):
                if weight > 0:
                    key = ("shift", int(shift))
                    if key not in self._tau:  # (`align` at a whole shift, read on the working grid only)
                        at = np.clip(np.arange(0, len(band), self.stride) - int(shift), 0, len(band) - 1)
                        self._tau[key] = self.smoothed(band[at])
                    out[:, j] += weight * self._tau[key][:, j]
        return out

    def moving(self) -> np.ndarray:
        """Per joint: the fraction of used samples where the joint moves (more than a few
        encoder counts per filter time constant)."""
        v_min = 5 * self.step * self.cutoff_hz
        return np.mean(np.abs(self.qd[self.rows]) > v_min, axis=0)


def moving_weight(rest: np.ndarray, dt: float, cutoff_hz: float) -> np.ndarray:
    """(T,) the cut-off's low-pass of the moving samples' indicator: 1 far from a rest, 0 inside
    one (the denominator of `Data.smoothed`)."""
    return lowpass((~rest).astype(float), dt, cutoff_hz)


def align(u: np.ndarray, lag) -> np.ndarray:
    """u (T, n) read `lag` samples late (fractional, linear interpolation; held at the start);
    `lag` one number, or one per column (a delay per joint)."""
    lag = np.asarray(lag, float)
    if lag.ndim == 0:
        k = np.arange(u.shape[0]) - lag
        k0 = np.clip(np.floor(k).astype(int), 0, u.shape[0] - 1)
        k1 = np.clip(k0 + 1, 0, u.shape[0] - 1)
        w = np.clip(k - np.floor(k), 0, 1)[:, None]
        return (1 - w) * u[k0] + w * u[k1]
    return np.stack([align(u[:, [j]], lag[j])[:, 0] for j in range(u.shape[1])], axis=1)


def encoder_step(rec: Recording) -> float:
    """The position grid: from the metadata, else the smallest non-zero position change."""
    return rec.position_step or smallest_step(rec.q)


def _long_runs(mask: np.ndarray, longer_than: int) -> np.ndarray:
    """The samples of `mask` that lie in runs of more than `longer_than` samples."""
    edges = np.diff(np.r_[0, mask.astype(np.int8), 0])
    starts, stops = np.flatnonzero(edges == 1), np.flatnonzero(edges == -1)
    out = np.zeros_like(mask)
    for a, b in zip(starts, stops, strict=True):
        if b - a > longer_than:
            out[a:b] = True
    return out


def auto_cutoff(rec: Recording, step: float | None = None) -> tuple[float, str]:
    """The identification band the motion calls for, and how it was chosen.

    The motion band f_m is where `MOTION_POWER` of the velocity's power lies, once the encoder's
    quantization noise (white, Δ²/12, through the first difference) is taken out of the
    velocity's spectrum; the cut-off is `BAND_FACTOR` f_m (friction steps and reversals are
    broadband), at least `MIN_CUTOFF_HZ`, below Nyquist, and capped where the quantization noise
    in q̈ (σ² = Δ²/12 · 2T · (2π)⁴ f⁵ / 5 below f) reaches `NOISE_BUDGET` of the motion's own q̈
    RMS in that band. The torque's spectrum plays no part: a noisy torque sensor must not widen
    the band (the noise would follow it up to Nyquist)."""
    from scipy import signal

    dt, n = rec.dt, len(rec)
    step = encoder_step(rec) if step is None else step
    v = np.diff(rec.q, axis=0) / dt
    v = v - v.mean(axis=0)
    f, p = signal.welch(v, fs=1 / dt, nperseg=min(4096, max(16, n // 4)), axis=0)
    noise = (step**2 / 12) * 2 * dt * (2 * np.sin(np.pi * f * dt) / dt) ** 2  # one-sided PSD of the difference
    clean = np.clip(p.sum(axis=1) - rec.n_joints * noise, 0, None)
    total = np.cumsum(clean)
    if not total[-1] > 0:
        return float(min(10.0, 0.45 / dt)), "no motion above the encoder's noise: cut-off 10 Hz by default"
    f_m = float(f[min(np.searchsorted(total, MOTION_POWER * total[-1]), len(f) - 1)])
    want = max(BAND_FACTOR * f_m, MIN_CUTOFF_HZ)
    top = 0.45 / dt
    # the motion's q̈ power below each frequency, against the quantization noise's
    acc = np.cumsum(clean * (2 * np.pi * f) ** 2) * (f[1] - f[0])
    acc_noise = (step**2 / 12) * 2 * dt * (2 * np.pi) ** 4 * f**5 / 5 * rec.n_joints
    ok = acc_noise <= NOISE_BUDGET**2 * np.maximum(acc, 1e-300)
    cap = float(f[np.flatnonzero(ok)[-1]]) if ok.any() and step > 0 else top
    cut = min(want, top, max(cap, MIN_CUTOFF_HZ))
    note = f"motion band {f_m:.3g} Hz (99 % of the velocity's power)"
    if cut < min(want, top) - 1e-9:
        note += (
            f"; limited to {cut:.3g} Hz (not {min(want, top):.3g}) by the encoder's quantization noise in the "
            f"acceleration (step {step:.3g})"
        )
    return float(cut), note


def prepare(
    rec: Recording, cutoff_hz: float | None = None, decimate: int | None = None, exclude_standstill: bool = True
) -> Data:
    """Filter, differentiate and choose the rows. With `exclude_standstill`, the samples where a
    joint is at rest are left out: a joint at rest holds whatever friction the other torques ask
    of it (stiction), which no function of the velocity predicts. A joint is at rest when its
    speed stays under two encoder counts per kinematic-band period for more than `STANDSTILL_S`
    (a mere zero crossing is shorter: the EMPS axis never rests, the arm under impedance control
    sticks for tens of milliseconds at each reversal).

    The cut-off's low-pass would spread a rest's torque over half a cut-off period either side;
    it leaves the rests out instead (`Data.smoothed`: the low-pass of x·m over the low-pass of m,
    m = 0 at rest, the same weights for the torque and every column, so the equations stay exact).
    What is left out is the rest, `REST_GUARD` periods of the kinematic band either side (that
    filter is applied before the rows are known, as it is to the positions; 5 % of its kernel
    lies beyond one period), and the rows whose cut-off window is mostly rest (`MIN_WEIGHT`).
    Breakaway and the approach to a rest, where Stribeck friction lives, stay in.

    A joint held against its friction may creep instead of sticking: a simulator that regularizes
    friction (Drake's stiction tolerance, MuJoCo's soft friction loss; Fc tanh(q̇/ε)) lets it
    slide at speeds of order ε, above the encoder's threshold, with a friction anywhere between
    ±Fc. So a joint is at rest too while its speed stays under `CREEP` of its high speed (95th
    percentile) for more than `CREEP_S`, outside the rests the encoder shows (a reversal passes
    such speeds in a few milliseconds; the approach to a rest, contiguous with it, is kept).

    A serial chain (`structure: urdf`) leaves out equations, not rows: a joint's stiction is a
    torque on that joint alone, so only its own equation is unknown near its standstill, and the
    other joints' equations of those rows are kept (`Data.mask`; `standstill` is then the share of
    equations left out). With six or seven joints reversing in turn, leaving out whole rows would
    leave out most of the recording. Each joint's equations are left out around every reversal
    (`JOINT_STANDSTILL_S`: any time under the threshold), one cut-off period either side
    (`JOINT_GUARD`): on 20 s of a simulated Panda with Coulomb friction (0.2 N·m) the base
    parameters' median error is 0.2 %, against 1.6 % under the whole-row rule (rests over 5 ms
    and half a period) applied per joint. MANUS-2 and single axes keep whole rows and their
    rule (their calibrated results).

    A recording too short or too still to leave `MIN_ROWS` usable rows is still prepared: `fit`
    refuses it, naming the parameters the remaining samples cannot identify (the model is not
    known here)."""
    if len(rec) < MIN_SAMPLES:
        raise ModelError(
            f"{rec.path}: recording too short: {len(rec)} samples (at least {MIN_SAMPLES} are needed "
            "to differentiate the positions; no parameter is identifiable)"
        )
    recorded, (rec, filled) = rec, on_grid(rec)  # lost samples filled, to be left out (`spoiled`)
    gapped = bool(filled.any())
    rec, wild, wild_note = torque_outliers(rec)  # torque glitches: replaced for the filters, left out too
    filled = filled | wild
    dt = rec.dt
    step = encoder_step(rec)
    if cutoff_hz is None:
        cutoff_hz, note = auto_cutoff(rec, step)
    else:
        note = "cut-off given"
    if not cutoff_hz > 0:
        raise ModelError(f"cut-off frequency must be positive (got {cutoff_hz})")
    if cutoff_hz > 0.45 / dt * (1 + 1e-9) and note == "cut-off given":
        raise ModelError(
            f"cut-off {cutoff_hz:g} Hz: above what {1 / dt:g} Hz sampling shows (at most {0.45 / dt:g} Hz, "
            "0.45 of the rate)"
        )
    cutoff_hz = min(cutoff_hz, 0.45 / dt)
    band = min(KINEMATIC_BAND * cutoff_hz, 0.45 / dt)
    q, qd, qdd = differentiate(rec.q, dt, band)
    cut = edge(dt, cutoff_hz)
    keep = np.zeros(len(rec), bool)
    keep[cut : len(rec) - cut] = True
    lost = ""
    if filled.any():
        bad = spoiled(filled, qdd, dt, step, cut)
        keep &= ~bad
        said = (
            [f"{gaps(recorded).describe(recorded)}: filled for the filters (positions by a cubic spline)"]
            if gapped
            else []
        )
        lost = "; ".join(said + ([wild_note] if wild_note else [])) + (
            f"; {int(bad.sum())} sample{'s' if bad.sum() != 1 else ''} left out (the filled ones, and the filter's "
            f"settling, "
            f"{1e3 * cut * dt:.3g} ms, either side of a gap the fill may miss by more than an encoder step)"
        )
    keep_edges, usable = keep.copy(), keep.sum()
    per_joint = rec.structure_name == "urdf"
    equations = np.repeat(keep[:, None], rec.n_joints, 1)
    rest = None
    if exclude_standstill and step > 0:
        slow = np.abs(qd) < 2 * step * band
        if keep.any():  # creeping: slow for the motion, not for the encoder, for a long time
            creep = (np.abs(qd) < CREEP * np.percentile(np.abs(qd[keep]), 95, axis=0)) & ~slow
            slow |= np.stack([_long_runs(creep[:, j], int(round(CREEP_S / dt))) for j in range(rec.n_joints)], 1)
        if per_joint:
            w = int(np.ceil(JOINT_GUARD / (cutoff_hz * dt)))
            for j in range(rec.n_joints):
                still = _long_runs(slow[:, j], int(round(JOINT_STANDSTILL_S / dt)))
                equations[:, j] &= ~(np.convolve(still.astype(float), np.ones(2 * w + 1))[w : w + len(rec)] > 0)
            keep &= equations.any(1)
        else:
            still = np.any([_long_runs(slow[:, j], int(round(STANDSTILL_S / dt))) for j in range(rec.n_joints)], axis=0)
            rest = still
            w = int(np.ceil(REST_GUARD / (band * dt)))  # the kinematic band's filter still spreads a rest
            near = np.convolve(still.astype(float), np.ones(2 * w + 1))[w : w + len(rec)] > 0  # dilated by w
            weight = moving_weight(still, dt, cutoff_hz)
            keep &= ~near & (weight >= MIN_WEIGHT)
    stride = max(1, int(1 / (WORK_RATE * cutoff_hz * dt)))
    if decimate is None:
        decimate = max(1, int(0.25 / (cutoff_hz * dt)))
    decimate = max(1, round(decimate / stride))  # (on the working grid)
    rows = stride * np.flatnonzero(keep[::stride])[::decimate]
    window = stride * np.flatnonzero(keep_edges[::stride])[::decimate]
    left_out = (
        float(1 - equations[keep].sum() / max(usable * rec.n_joints, 1))
        if per_joint
        else float(1 - keep.sum() / max(usable, 1))
    )
    return Data(
        rec,
        cutoff_hz,
        q,
        qd,
        qdd,
        rows,
        step,
        left_out,
        window,
        note,
        equations[rows].astype(float) if per_joint else None,
        lost=lost,
        rest=rest,
        stride=stride,
        _tau={} if rest is None or stride > 1 else {"weight": weight},
    )
