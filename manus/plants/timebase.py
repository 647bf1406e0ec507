"""What a recording's time stamps and positions say about its true sample grid (`examine`; the
recording put back on that grid is `manus.plants.recording.repair`'s, applied by `read`).

A rig samples on a uniform grid; a logger on a PC can blur it in three ways, each of which makes
the positions look broadband (a staircase) and so would set the identification band from the
artefact:

- **repeated rows**: a row whose every position and torque equals the previous row's while the
  joints move (the logger read the same packet twice; the sample of that instant is lost). A
  joint moving more than `MOVING_STEPS` encoder steps per sample either side of a row, at the
  pace it keeps through it, does not stand still for that row (`runs` says when it may: a stop,
  a reversal, a motion that turns as sharply elsewhere while its torques repeat): such a copy
  is an artefact. Repair: the copy is dropped and its slot left as a lost sample
  (`manus.plants.gaps` fills it for the filters and leaves it out);
- **jittered or alternating stamps**: the stamps scatter around their grid t₀ + i T (a PC's
  clock read when the packet arrives; a cobot logged at ~100 Hz with steps of 10 and 12 ms).
  The scatter is the RMS deviation of the stamps from the best uniform grid (`grid`), as a
  share of the period. A uniform clock written with a resolution q (a decimal digit, float32's
  or float64's spacing at the recording's last stamp) scatters by q/√12 at most:
  `QUANTIZATION_MARGIN` times that is the clock's own. Below `JITTER` of the period the scatter
  is left alone whatever its cause: a sample read 1 % of a period late is off the motion by 1 %
  of its step per period, under an encoder step's quantization noise (Δ/√12) up to ~30 steps
  per period. Whatever the scatter, stamps whose median step misreads the grid's period by more
  than `JITTER` (steps alternating between two values: 10 and 12 ms, or a uniform clock's
  period rounded to a coarser resolution) are put on the grid too, where the rate is read from
  them. Repair: each stamp goes to its grid point t₀ + i T, the indices i the strictly
  increasing integers nearest to (t − t₀)/T (`_settle`: late rows bunched onto one slot spread
  to the free slots beside it); no row is dropped for its stamp; a skipped index is a lost
  sample, left as a gap;
- **held positions**: a log resampled to k times its rate by holding each sample (positions
  update every k-th row, the torque may change in between). In moving stretches every joint's
  position then stays equal over runs of k rows: held when most of the rows of the moving
  stretches (`HELD_SHARE`) lie in runs of one length k ≥ 2 (a clean log has runs of one row
  there; 5 % repeated rows put 10 % of them in runs of two). Repair where the runs keep one
  phase (`PHASE_SHARE` of them start at the same row modulo k): one row per run, the first
  (where the new sample arrived); the true rate is the log's over k.

A clean recording (none of the three) is returned exactly as it is.
"""

from __future__ import annotations

import math
from dataclasses import dataclass
from typing import Protocol

import numpy as np
from scipy.optimize import isotonic_regression


class Logged(Protocol):
    """What the time base reads of a recording (`manus.plants.recording.Recording`)."""

    t: np.ndarray
    q: np.ndarray
    tau: np.ndarray
    meta: dict

    def __len__(self) -> int: ...

    @property
    def position_step(self) -> float | None: ...

    @property
    def sample_rate_hz(self) -> float: ...


MOVING_STEPS = 2.5  # a joint moves when its position changes by more than this many encoder steps per sample
JITTER = 0.01  # stamps scattering less than this share of the period (RMS) are read as clean
QUANTIZATION_MARGIN = 3.0  # ... and less than this many times their own resolution's q/√12
PACE = 3.0  # a joint moving through a run of held positions keeps within this factor of its pace either side
TORQUE_REPEATS = 0.01  # torques that repeat in at most this share of the moving rows: a copied torque is a copy
MAX_COPIES = 4  # copies where the motion starts or stops: a packet read up to five times
HELD_SHARE = 0.5  # positions are held when this share of the moving stretches' rows lie in runs of one length k
PHASE_SHARE = 0.9  # ... and repaired when this share of those runs start at one phase modulo k
BLOCK = 64  # rows per block of the stamps' phase (`grid`)
PREFIX = 2048  # the period is first searched on this many stamps ...
SEARCH = 0.05  # ... within this share of the steps' own reading


@dataclass(frozen=True)
class TimeBase:
    """What `examine` found in a recording's time base, and what its repair does about it."""

    rate_hz: float  # the true sample rate (of the repaired recording where it was repaired)
    repeated_rows: int = 0  # rows that copy the row before while the joints move (dropped)
    jitter: float = 0.0  # RMS deviation of the stamps from their uniform grid, in periods
    jittered: bool = False  # the stamps scatter more than a uniform clock's, or misread its period (put on the grid)
    held_rows: int = 0  # rows that hold the positions of a resampled log (dropped: one kept per run)
    held_every: int = 1  # k: the positions update every k-th row
    lost: int = 0  # grid slots no row holds after the repair (lost samples, left as gaps)
    period_steps: tuple[float, float] = (0.0, 0.0)  # the stamps' step, 1st and 99th percentile [s]
    repaired: bool = False

    def __bool__(self) -> bool:
        return bool(self.repeated_rows or self.jittered or self.held_rows)

    @property
    def note(self) -> str:
        """One line: what was found and what was done."""
        said = []
        if self.held_rows:
            said.append(
                f"positions held over runs of {self.held_every} rows while the joints move (a log resampled "
                f"{self.held_every}x): {'one row kept per run' if self.repaired else 'not repaired (no steady phase)'}"
            )
        if self.repeated_rows:
            said.append(
                f"{self.repeated_rows} repeated row{'s' if self.repeated_rows != 1 else ''} (a copy of the row before "
                "while the joints move) dropped"
            )
        if self.jittered:
            lo, hi = self.period_steps
            said.append(
                f"stamps scatter by {100 * self.jitter:.3g} % of the period (RMS; steps {1e3 * lo:.4g} to "
                f"{1e3 * hi:.4g} ms) around a uniform {1e3 / self.rate_hz:.6g} ms grid: put on it"
            )
        if self.lost:
            said.append(f"{self.lost} lost sample{'s' if self.lost != 1 else ''} left as gaps")
        return f"time base: {'; '.join(said)}; read at {self.rate_hz:.6g} Hz"

    def report(self) -> dict:
        """The commands' JSON `time_base` object."""
        return {
            "rate_hz": self.rate_hz,
            "repeated_rows": self.repeated_rows,
            "jitter": self.jitter,
            "held_rows": self.held_rows,
            "repaired": self.repaired,
            "note": self.note,
        }


# -- the encoder's step and the runs of held positions ------------------------------------------


def encoder_steps(rec: Logged) -> np.ndarray:
    """(n,) each joint's position grid: the smallest non-zero change of its position, at least the
    metadata's step (0 for a joint that never moves)."""
    d = np.abs(np.diff(rec.q, axis=0))
    own = np.where(d > 0, d, np.inf).min(axis=0, initial=np.inf)
    own[~np.isfinite(own)] = 0.0
    declared = rec.position_step or 0.0
    return np.maximum(own, declared)


@dataclass(frozen=True)
class Runs:
    """The recording cut into runs of rows whose every position is equal."""

    start: np.ndarray  # first row of each run
    length: np.ndarray  # rows in each run
    moving: np.ndarray  # (bool) the joints move through the run (`runs`)
    edge: np.ndarray  # (bool) the joints move into or out of the run at its pace (`runs`)


def runs(rec: Logged, steps: np.ndarray | None = None) -> Runs:
    """`rec`'s runs of equal positions, and which lie where the joints move through them.

    Each run r holds its positions for L_r rows, then jumps by J_r. A joint moves through run r
    when all of these hold:
    - the runs either side jump by more than `MOVING_STEPS` encoder steps and the three jumps go
      one way (a reversal changes direction; a slow joint's quantized staircase jumps by a step);
    - its pace through the run, |J_r| / L_r per row, is within a factor `PACE` of the mean of
      theirs, |J_{r±1}| / L_{r±1}: the motion went on while the positions stood (a joint that
      stops for L rows and starts again jumps out by its breakaway's first step, under 2/L of its
      pace either side: on the calibration recordings at 200 Hz, stops of 5 to 50 rows pace at
      0.1 % to 10 % of it);
    - where the recorded torques often repeat from one moving row to the next (more than
      `TORQUE_REPEATS` of them: an open-loop schedule of steps), a copied torque tells nothing,
      and the positions alone must show the copy: standing still for a row and going on needs a
      second difference of the positions of about a row's motion, min(|J_{r−1}|, |J_r|), more
      than the joint shows anywhere in its uninterrupted motion (`_smooth_limit`); a joint whose
      motion does turn that sharply (a shaft mode ringing through stick-slip) may have stood
      still, and is left be. Where the torques change at nearly every row (a closed loop, a
      measured torque), a row whose positions and torques all equal the row before is a copy.
    `edge`: the same on one side only (a copy just before the motion comes to rest, or just after
    it starts), which a stop's own first or last rows can show as well: `_repeated` takes it for
    short runs whose torques are copied too."""
    steps = encoder_steps(rec) if steps is None else steps
    change = np.flatnonzero(np.any(np.diff(rec.q, axis=0) != 0, axis=1)) + 1  # rows unlike the row before
    start = np.r_[0, change]
    length = np.diff(np.r_[start, len(rec)])
    moving, edge = np.zeros(start.size, bool), np.zeros(start.size, bool)
    if start.size < 4:
        return Runs(start, length, moving, edge)
    jump = np.diff(rec.q[start], axis=0)  # (runs - 1, n): J_r, the jump out of run r
    fast = (np.abs(jump) > MOVING_STEPS * steps) & (steps > 0)
    # runs 1 .. R-3 (each has a jump before and after it); a one-row run moves where the joints go on
    inner = fast[:-2] & fast[2:] & (jump[:-2] * jump[1:-1] > 0) & (jump[1:-1] * jump[2:] > 0)
    moving[1:-2] = np.any(inner, axis=1) & (length[1:-2] == 1)
    held = np.flatnonzero(length[1:-2] > 1) + 1  # the runs that hold: their pace decides
    if held.size:
        pace = np.abs(jump) / length[:-1, None]  # |J_r| / L_r
        before, here, after = pace[held - 1], pace[held], pace[held + 1]
        sharp = np.minimum(np.abs(jump[held - 1]), np.abs(jump[held])) > _smooth_limit(rec.q)
        if _torque_repeats(rec, change) <= TORQUE_REPEATS:
            sharp[:] = True
        with np.errstate(divide="ignore", invalid="ignore"):
            steady = _within(here / ((before + after) / 2))
            sides = [
                fast[held + d] & (jump[held + d] * jump[held] > 0) & _within(here / there)
                for d, there in ((-1, before), (1, after))
            ]
        moving[held] = np.any(inner[held - 1] & steady & sharp, axis=1)
        edge[held] = np.any((sides[0] | sides[1]) & sharp, axis=1)
    return Runs(start, length, moving, edge)


def _torque_repeats(rec: Logged, change: np.ndarray) -> float:
    """The share of the rows whose positions moved (`change`) whose torques all equal the row
    before's."""
    if not change.size:
        return 1.0
    return float(np.mean(np.all(rec.tau[change] == rec.tau[change - 1], axis=1)))


def _smooth_limit(q: np.ndarray) -> np.ndarray:
    """(n,) per joint, the largest |Δ²q| (second difference of the positions) over the rows of
    its uninterrupted motion: its steps either side non-zero, and no row within two where every
    position stands (a candidate copy) — 0 where there are none (a log whose every step is
    followed by a hold)."""
    d = np.diff(q, axis=0)  # step i: row i to i + 1
    stand = np.all(d == 0, axis=1).astype(float)
    near = np.convolve(np.r_[0.0, 0.0, stand, 0.0, 0.0], np.ones(6), mode="valid")  # steps i-2 .. i+3
    ok = (d[:-1] != 0) & (d[1:] != 0) & (near == 0)[:, None]  # Δ²q at row i + 1: steps i and i + 1
    return np.where(ok, np.abs(np.diff(d, axis=0)), 0.0).max(axis=0, initial=0.0)


def _within(ratio: np.ndarray) -> np.ndarray:
    """A pace ratio within a factor `PACE` of one."""
    return (ratio > 1 / PACE) & (ratio < PACE)


def _held(r: Runs) -> tuple[int, int] | None:
    """(k, phase) of a log resampled by holding its positions: most moving rows in runs of one
    length k ≥ 2 (`HELD_SHARE`); phase −1 where the runs keep no steady phase."""
    lengths = r.length[r.moving]
    if not lengths.size:
        return None
    counts = np.bincount(lengths)
    counts[:2] = 0
    k = int(np.argmax(counts * np.arange(counts.size)))  # the length holding the most rows
    if k < 2 or k * counts[k] < HELD_SHARE * lengths.sum():
        return None
    phases = r.start[r.moving & (r.length == k)] % k
    phase = int(np.argmax(np.bincount(phases, minlength=k)))
    return k, phase if np.mean(phases == phase) >= PHASE_SHARE else -1


def _repeated(rec: Logged, r: Runs) -> np.ndarray:
    """(bool, per row) the rows that copy the row before, positions and torques, while the joints
    move through their run, or move into or out of a run of at most `MAX_COPIES` copies."""
    out = np.zeros(len(rec), bool)
    same_tau = np.r_[False, np.all(np.diff(rec.tau, axis=0) == 0, axis=1)]
    pick = (r.length > 1) & (r.moving | (r.edge & (r.length <= 1 + MAX_COPIES)))
    for a, n in zip(r.start[pick], r.length[pick], strict=True):
        out[a + 1 : a + n] = same_tau[a + 1 : a + n]
    return out


# -- the stamps' grid -----------------------------------------------------------------------------


def stamp_resolution(t: np.ndarray) -> float:
    """The resolution the stamps were written with: the coarsest decimal digit all of them lie on,
    float32's spacing at the last stamp where they are float32 numbers, float64's at least."""
    span = float(np.max(np.abs(t)))
    out = float(np.spacing(span))
    if np.all(t.astype(np.float32).astype(np.float64) == t):
        out = max(out, float(np.spacing(np.float32(span))))
    for digits in range(0, 10):
        q = 10.0**-digits
        tol = 1e-6 + 4 * np.spacing(span) / q
        if tol < 0.1 and np.all(np.abs(t / q - np.rint(t / q)) <= tol):
            return max(out, q)
    return out


def typical_period(t: np.ndarray) -> float:
    """A first reading of the stamps' period, robust to alternating steps (10/12 ms) and to lost
    samples: the mean of the steps within half a median step of it (a lost sample's step of two
    periods is left out; the steps of an alternation, or of jittered stamps, average to the period)."""
    d = np.diff(t)
    m = float(np.median(d))
    near = d[np.abs(d - m) <= 0.5 * m]
    return float(near.mean()) if near.size else m


def _phase_period(s: np.ndarray, T: float) -> float:
    """The period near `T` at which the stamps `s` line up best (the Rayleigh statistic
    |Σ exp(2πi s / T')| at its largest), searched within `SEARCH` of `T` in steps of a quarter
    of the peak's width (one period over the span), on the first `PREFIX` stamps."""
    x = s[:PREFIX]
    width = T / max(x[-1] - x[0], T)  # the peak's relative width
    trial = np.arange(-SEARCH, SEARCH, width / 4)
    best, value = 0.0, -1.0
    for chunk in np.array_split(trial, max(1, trial.size * x.size // 2**19)):
        r = np.abs(np.exp(2j * np.pi * np.outer((1 + chunk) / T, x)).sum(axis=1))
        if r.max() > value:
            best, value = float(chunk[np.argmax(r)]), float(r.max())
    return T / (1 + best)


def grid(t: np.ndarray) -> tuple[np.ndarray, float, float]:
    """(i, t₀, T): each stamp's index on the uniform grid t₀ + i T that fits them best.

    The period is found from the stamps' phase against a trial period T' (2π t / T' modulo 2π:
    jitter spreads it, lost or doubled samples leave it as it is): first the T' at which the
    first stamps line up best (`_phase_period`), then refined over the whole recording: the
    phase, averaged over blocks of `BLOCK` rows as a unit vector, drifts at 2π (1/T' − 1/T) per
    second, read by a straight line through the blocks' unwrapped phases (twice, the second time
    over blocks four times longer). Then i = round((t − t₀)/T), and (t₀, T) by least squares on
    those indices."""
    t = np.asarray(t, float)
    origin = t[0]
    s = t - origin
    T = typical_period(t)
    if s.size >= 2 * BLOCK:
        T = _phase_period(s, T)
    for block in (BLOCK, 4 * BLOCK):
        nb = s.size // block
        if nb < 3:
            break
        mean = _phasors(s[: nb * block], T, block)
        w = np.abs(mean)
        if not w.sum() > 0:
            break
        centre = s[: nb * block].reshape(nb, block).mean(axis=1)
        beta = np.polyfit(centre, np.unwrap(np.angle(mean)), 1, w=np.sqrt(w))[0]
        T = 1.0 / (1.0 / T - beta / (2 * np.pi))
    offset = float(np.angle(_phasors(s, T, s.size)[0])) / (2 * np.pi) * T
    i = np.rint((s - offset) / T)
    # (a, T): least squares of s on [1, i], in the sums of its normal equations about their means
    im, sm = i.mean(), s.mean()
    i -= im
    T = float(i @ (s - sm) / (i @ i)) if i.size > 1 else T
    a = sm - T * im
    i = np.rint((s - a) / T).astype(np.int64)
    return i - i[0], float(origin + a + i[0] * T), float(T)


PHASOR_ROWS = 1 << 16  # rows whose phasors are held at once (`_phasors`)


def _phasors(s: np.ndarray, T: float, block: int) -> np.ndarray:
    """The mean of exp(2πi s/T) over each `block` of rows of s (its length a multiple of `block`),
    worked out `PHASOR_ROWS` at a time: a long recording's phasors are never all held."""
    z = lambda x: np.exp(2j * np.pi * x / T)
    if block <= PHASOR_ROWS:
        step = PHASOR_ROWS // block * block
        return np.concatenate([z(s[k : k + step]).reshape(-1, block).mean(axis=1) for k in range(0, s.size, step)])
    return np.array(
        [
            sum(z(s[k : min(k + PHASOR_ROWS, b + block)]).sum() for k in range(b, b + block, PHASOR_ROWS)) / block
            for b in range(0, s.size, block)
        ]
    )


def _settle(x: np.ndarray) -> np.ndarray:
    """Grid slots for stamps read as x (in periods from the grid's origin): the strictly
    increasing integers nearest to them in least squares (an isotonic regression of x_k − k,
    rounded, plus k). Late rows bunched onto one slot spread over the slots beside them, in
    their order; no row is dropped for its stamp (a copy of the row before while the joints
    move is `_repeated`'s to find)."""
    k = np.arange(x.size)
    return (np.rint(isotonic_regression(x - k).x) + k).astype(np.int64)


# -- examine and repair ---------------------------------------------------------------------------


def examine(rec: Logged) -> tuple[TimeBase, np.ndarray, np.ndarray | None]:
    """What the recording's stamps and positions say: the finding, the rows kept, and the kept
    rows' stamps on the grid (None where the stamps are left as they are)."""
    keep = np.ones(len(rec), bool)
    found: dict = {}
    if len(rec) < 4:
        return TimeBase(rec.sample_rate_hz), keep, None
    steps = encoder_steps(rec)
    r = runs(rec, steps)
    held = _held(r)
    if held is not None:
        k, phase = held
        found.update(held_every=k, held_rows=int(np.sum(r.length[r.moving & (r.length == k)] - 1)))
        if phase >= 0:
            keep &= np.arange(len(rec)) % k == phase
            found["held_rows"] = int(len(rec) - keep.sum())
    else:
        rep = _repeated(rec, r)
        found["repeated_rows"] = int(rep.sum())
        keep &= ~rep
    t = rec.t[keep]
    i, t0, T = grid(t)
    resid = t - (t0 + i * T)
    jitter = float(np.sqrt(np.mean(resid**2)) / T)
    clock = QUANTIZATION_MARGIN * stamp_resolution(rec.t) / math.sqrt(12) / T
    d = np.diff(t)
    misread = d.size > 0 and abs(float(np.median(d)) / T - 1) > JITTER
    jittered = jitter > max(JITTER, clock) or misread
    out = None
    lost = 0
    if jittered:
        i = _settle((t - t0) / T)
        lost = int(i[-1] - i[0] + 1 - i.size)
        out = t0 + i * T
    elif found.get("repeated_rows"):
        lost = int(found["repeated_rows"])
    repaired = bool(found.get("repeated_rows") or jittered or (held is not None and held[1] >= 0))
    rate = 1.0 / T if jittered or held is not None else rec.sample_rate_hz
    if held is not None and held[1] >= 0 and "sample_rate_hz" in rec.meta:
        rate = float(rec.meta["sample_rate_hz"]) / held[0]
    tb = TimeBase(
        rate,
        jitter=jitter,
        jittered=jittered,
        lost=lost,
        period_steps=(float(np.percentile(d, 1)), float(np.percentile(d, 99))) if d.size else (0.0, 0.0),
        repaired=repaired,
        **found,
    )
    return tb, keep, out
