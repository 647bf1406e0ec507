"""What a PC logger does to a rig's uniform samples, done to a recording whose truth is known
(the time-base corruptions that `manus.plants.timebase` finds and repairs), each from the
logger's physics:

- `repeat_rows`: the logger reads the packet it read before while the joints move (the sample of
  that instant is lost);
- `jitter_stamps`: the stamps are read from a busy clock, ± a share of the period (uniform);
- `alternate_stamps`: a cobot logged at ~100 Hz, stamps 10 and 12 ms apart in turn;
- `hold_positions`: a log resampled to k times its rate by holding each sample (the torque
  interpolated: it changes within the runs);
- `pc_logger`: a PC loop at the rig's rate, waking late (exponential) and writing the newest
  sample with its own stamp: repeated rows, skipped samples and jittered stamps at once;
- `device_log`: a device under load stamping each packet when it processes it: packets queued
  behind a stall are processed at once, their stamps bunched onto one slot, every row distinct.
"""

from __future__ import annotations

import numpy as np

from manus.plants.recording import Recording


def _copy(rec: Recording) -> Recording:
    out = rec.rows(np.arange(len(rec)))
    out.t = np.asarray(out.t, float)
    return out


def _unstated(rec: Recording) -> Recording:
    rec.meta.pop("sample_rate_hz", None)
    return rec


def repeat_rows(rec: Recording, share: float, rng: np.random.Generator) -> tuple[Recording, np.ndarray]:
    """`share` of the rows (among those whose positions moved) replaced by the row before, in
    order (two neighbours picked make a run of three equal rows, as a logger reading one packet
    three times does); the rows copied over."""
    out = _copy(rec)
    moving = np.flatnonzero(np.any(np.diff(rec.q, axis=0) != 0, axis=1)) + 1
    moving = moving[(moving > 2) & (moving < len(rec) - 3)]
    pick = np.sort(rng.choice(moving, int(share * len(rec)), replace=False))
    for x in (out.q, out.tau) + ((out.qd,) if out.qd is not None else ()):
        for i in pick:
            x[i] = x[i - 1]
    return out, pick


def jitter_stamps(rec: Recording, amplitude: float, rng: np.random.Generator) -> Recording:
    """Stamps moved by up to ± `amplitude` periods (uniform)."""
    out = _copy(rec)
    out.t = out.t + rng.uniform(-amplitude, amplitude, len(rec)) / rec.sample_rate_hz
    return _unstated(out)


def alternate_stamps(rec: Recording) -> Recording:
    """Steps of 10/11 and 12/11 of the period in turn (10 and 12 ms at 90.9 Hz)."""
    out = _copy(rec)
    k = np.arange(len(rec))
    out.t = rec.t[0] + (k - (k % 2) / 11) / rec.sample_rate_hz
    return _unstated(out)


def hold_positions(rec: Recording, k: int) -> Recording:
    """The recording resampled to k times its rate: positions held, torques interpolated."""
    n = len(rec)
    j = np.arange(n * k) / k
    held = np.floor(j).astype(int)
    tau = np.stack([np.interp(j, np.arange(n), rec.tau[:, i]) for i in range(rec.n_joints)], 1)
    meta = dict(rec.meta, sample_rate_hz=f"{rec.sample_rate_hz * k:g}")
    extra = {name: v[held] for name, v in rec.extra.items()}
    qd = None if rec.qd is None else rec.qd[held]
    return Recording(rec.t[0] + j / rec.sample_rate_hz, rec.q[held], tau, qd, meta, extra, rec.path, rec.serial)


def pc_logger(rec: Recording, late: float, rng: np.random.Generator) -> Recording:
    """A PC loop at the rig's rate that wakes late (exponential, mean `late` periods) and writes the
    newest sample with the time it woke."""
    T, n = 1 / rec.sample_rate_hz, len(rec)
    woke = np.sort(rec.t[0] + (np.arange(n) + 0.3 + rng.exponential(late, n)) * T)
    newest = np.clip(np.floor((woke - rec.t[0]) / T).astype(int), 0, n - 1)
    out = rec.rows(newest)
    out.t = woke
    return _unstated(out)


def device_log(rec: Recording, stalls: float, rng: np.random.Generator) -> Recording:
    """A device under load stamping each packet when it processes it: a share `stalls` of the
    packets wait 0.5–3 periods, and the packets queued behind a stall are processed at once, 20 µs
    apart (their stamps bunch onto one slot). Every row is a distinct sample, in order."""
    T, n = 1 / rec.sample_rate_hz, len(rec)
    delay = np.where(rng.random(n) < stalls, rng.uniform(0.5, 3.0, n), 0.0) * T
    t = np.asarray(rec.t, float) + delay
    for k in range(1, n):
        t[k] = max(t[k], t[k - 1] + 2e-5)
    out = _copy(rec)
    out.t = t
    return _unstated(out)
