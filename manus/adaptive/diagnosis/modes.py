"""Detecting a structural mode (the `compliance` effect) from a recording.

A shaft mode at ~200 Hz lies far above the band where inverse dynamics identifies a model (a
few tens of Hz: encoder quantization puts noise into q̈ that grows with the band), so it leaves
nothing in the identification residual. Its evidence is in the frequency response from the
torque to the measured (motor) acceleration between `band(fs)` (40 Hz, or a tenth of the sample
rate, to 0.4 fs). A rigid joint has a
flat apparent inertia Z(ω) = τ/θ̈ = J; a motor driving its link through a spring and damper has

    Z(ω) = α + β G(ω),   G(s) = (2ζω_z s + ω_z²) / (s² + 2ζω_z s + ω_z²)

(G: how the link follows the motor; ω_z: the anti-resonance), linear in (α, β) for fixed
(ω_z, ζ), which are found on a grid. The motor's share of the inertia is r = α/(α + β) and the
resonance f = ω_z/√r/2π (since ω_p² = k(1/J_m + 1/J_L) = ω_z²/r), the `compliance` effect's f.
Only physical modes count: damped at most as friction on a light motor damps them (ζ ≤ 0.2,
`ZETAS`), a motor share r inside `SHARE` (a fit on its bound is reported, not proposed:
`Mode.edge`), and a resonance the measured response really shows — a
peak of |θ̈/τ| at f at least `PEAK` times its level on the falling flank (1.3–1.6 f, inside
the band, at least one bin of it; so at 1 kHz modes up to ~300 Hz are resolved, at 200 Hz up
to ~60 Hz), and only where the sample rate can show it (`Mode.unresolved`: at most 0.6 of the
Nyquist frequency, above the identification band's cut-off, at least 8 bins of the frequency
response below it). Closed-loop data can otherwise dress the controller's response to encoder noise
(|θ̈/τ| rising steadily with frequency) up as a "mode" near the top of the band. The misfit is
the coherence-weighted relative error of Z over the band, and the error reduction the fraction
of the rigid model's misfit the mode removes. Both models carry a white floor S_nn ≥ 0 on the
recorded torque (a torque read from a measured current): H1 divides by S_xx = S_uu + S_nn, so
where the floor dominates the measured inertia is Z = 1/H + S_nn/S_xy, a column linear in S_nn
(`floor_column`); without it that bias, growing with frequency as the torque's spectrum falls,
hides the mode or dresses itself up as one. Frequency responses are estimated with the H1
estimator (cross-spectrum over input spectrum, unbiased by noise on the measured position) per
joint, corrected for what sampling does to a rigid joint's response (`sampling`: the held
command and the differentiated position), which otherwise looks like a mode near Nyquist at low
sample rates.

Only a recording that excites the mode says anything: the thesis's open-loop square-wave test
(Figs. 4-12 to 4-14), or closed-loop runs with enough damping gain to ring it (the Type 2
threshold). Under gentle closed-loop control the high-frequency torque is the controller's
answer to encoder noise, the spring model explains nothing the rigid one does not, and the
candidate is (rightly) not significant.
"""

from __future__ import annotations

import itertools
from dataclasses import dataclass

import numpy as np
from scipy import signal

from manus.plants.effects import Compliance

LOW = 40.0  # Hz: below, the rigid body and friction own the response
TOP = 0.4  # of the sample rate: above, the sampling correction is ill-conditioned (near Nyquist)


def band(fs: float) -> tuple[float, float]:
    """Where the frequency response is fitted at sample rate `fs`: from `LOW` (or a tenth of the
    rate, when that is lower) to `TOP` fs (the band scales with the rate: a fixed top would hide
    the modes a faster recording resolves)."""
    return min(LOW, 0.1 * fs), TOP * fs


# Bins below this coherence carry no usable frequency response. The variance of H1 in a bin is
# (1 − γ²)/(2 n γ²) over n averaged segments: at γ² = 0.1 and the ~90 segments of 12 s at 1 kHz
# it is ~5 %, enough to weigh, and a bin of no coherence at all reaches 0.1 with probability
# 0.9^(n−1) ~ 1e-4. (Calibrated: under open-loop steps with white noise on the recorded torque,
# where the mode's bins reach only γ² ≈ 0.1-0.16, the arm's mode is found in 4 of 8 calibration
# recordings at 0.1 against 1 at 0.3; with the torque exact, 0.3 finds it in 18 of 20.)
MIN_COHERENCE = 0.1
# The shaft itself is lightly damped, but friction on the motor side damps the mode it makes
# (ζ_extra = b / (2 J_m ω): a light motor with viscous friction, e.g. a linear axis, rings at
# ζ ≈ 0.1–0.2 whatever its shaft): the grid reaches 0.2, where a peak still shows (`PEAK`).
ZETAS = (0.005, 0.01, 0.02, 0.05, 0.1, 0.2)
# A resonance: the measured |θ̈/τ| near f at least this many times its level on the falling
# flank (1.3–1.6 f). For a motor-side measurement the ratio is ≈ (1 − r) / (3.8 ζ): 1.2 at
# ζ = 0.2 with r = 0.1, ~10 for a lightly damped shaft; a response that keeps rising with
# frequency (closed loop answering encoder noise) has a ratio below 1.
PEAK = 1.2
SHARE = (0.02, 0.9)  # a plausible motor share of the inertia; outside it the "mode" is not one
# A fitted share within this fraction of a bound of SHARE sits on it: the response asks for a share
# outside what a motor and its link have (calibrated: recordings with nothing missing whose
# response rises gently at the top of its coherent band land at r = 0.895-0.899; the modes hidden in
# the calibration set fit at 0.04-0.18).
EDGE = 0.02
# Where the sample rate can show a mode (`Mode.unresolved`): well below Nyquist (the sampling
# correction divides by a response that falls to nothing there, and the calibration's modes lie at
# 15–30 % of the rate), above the identification band (inside it the rigid model and friction own
# the response), and with this many bins of the frequency response below it (its peak and flank
# tests need a few bins each: at 100 Hz a 30 s log's 1.6 Hz bins see a 22.9 Hz mode in 14).
NYQUIST_SHARE = 0.6  # of fs/2, at most
MIN_BINS = 8


@dataclass
class Mode:
    f_hz: float
    zeta: float
    motor_fraction: float
    joint: int  # the joint where the mode explains most (0-based)
    resonant: bool  # the measured response peaks at f (else the fit is no evidence of a mode)
    err_rigid: np.ndarray  # (blocks,) misfit of the rigid model per block
    err_mode: np.ndarray  # (blocks,) with the mode
    freq: np.ndarray  # the whole-recording frequency response, for the evidence figure
    measured: np.ndarray  # (F, n) |θ̈/τ|
    rigid: np.ndarray  # (F, n)
    fitted: np.ndarray  # (F, n)
    coherent_hz: float = np.inf  # the highest frequency of the band where the response is coherent

    @property
    def reduction(self) -> float:
        return 1 - float(np.sqrt(self.err_mode.sum() / self.err_rigid.sum()))

    def edge(self) -> str:
        """Why the fit is not a mode to propose when its motor share lies on a bound of `SHARE`
        (else '')."""
        lo, hi = SHARE
        if lo * (1 + EDGE) < self.motor_fraction < hi * (1 - EDGE):
            return ""
        return (
            f"its motor share {self.motor_fraction:.3g} lies on the edge of its search range ({lo:g} to "
            f"{hi:g}): the response asks for a share of the inertia no motor and link have"
        )

    def unresolved(self, fs: float, cutoff_hz: float) -> str:
        """Why the sample rate cannot show this mode (a sentence), else '': too near Nyquist,
        inside the identification band (cut-off `cutoff_hz`) or on too coarse a frequency grid."""
        f = self.f_hz
        df = float(self.freq[1] - self.freq[0]) if self.freq.size > 1 else np.inf
        if f > NYQUIST_SHARE * fs / 2:
            return (
                f"at {f:.3g} Hz it lies too near the Nyquist frequency ({fs / 2:.3g} Hz) for {fs:.3g} Hz samples "
                f"to show it (at most {NYQUIST_SHARE * fs / 2:.3g} Hz)"
            )
        if f <= cutoff_hz:
            return (
                f"at {f:.3g} Hz it lies inside the identification band (cut-off {cutoff_hz:.3g} Hz), where the "
                "rigid model and friction own the response"
            )
        if f < MIN_BINS * df:
            return (
                f"the frequency response's {df:.3g} Hz bins resolve it too coarsely (at least {MIN_BINS} bins "
                "below it are needed: record longer)"
            )
        return ""

    def effect(self) -> Compliance:
        return Compliance(f_hz=self.f_hz, zeta=self.zeta)


def link_response(freq: np.ndarray, wz: float, zeta: float) -> np.ndarray:
    s = 2j * np.pi * freq
    return (2 * zeta * wz * s + wz**2) / (s**2 + 2 * zeta * wz * s + wz**2)


def sampling(f: np.ndarray, fs: float) -> np.ndarray:
    """What sampling does to θ̈/τ of a rigid joint: the command held over each period (zero-order
    hold: Q/U = T²(z+1)/(2J(z−1)²)) and θ̈ taken by central differences twice (D² = −sin²(ωT)/T²)
    give θ̈/τ = K(ω)/J with K = −sin²(ωT)(z+1)/(2(z−1)²), z = e^{jωT}: 1 at low frequency, a
    phase lag and a fall toward Nyquist that a continuous-time model would read as a mode."""
    w = 2 * np.pi * np.asarray(f) / fs
    z = np.exp(1j * w)
    with np.errstate(divide="ignore", invalid="ignore"):
        k = -(np.sin(w) ** 2) * (z + 1) / (2 * (z - 1) ** 2)
    return np.where(w > 0, k, 1.0 + 0j)


def _spectra(tau, acc, fs, nperseg):
    """Cross and auto spectra per joint, θ̈ corrected for sampling (`sampling`): f (F,), sxy,
    sxx, syy (F, n)."""
    f, sxy = signal.csd(tau, acc, fs=fs, nperseg=nperseg, axis=0)
    _, sxx = signal.welch(tau, fs=fs, nperseg=nperseg, axis=0)
    _, syy = signal.welch(acc, fs=fs, nperseg=nperseg, axis=0)
    k = sampling(f, fs)[:, None]
    ok = np.abs(k) > 1e-3
    k = np.where(ok, k, 1.0)
    return f, np.where(ok, sxy / k, 0), sxx, np.where(ok, syy / np.abs(k) ** 2, 0)


def _frf(sxy, sxx, syy):
    """H1 estimate of θ̈/τ, the apparent inertia Z = 1/H, and the coherence."""
    with np.errstate(divide="ignore", invalid="ignore"):
        h = np.nan_to_num(sxy / sxx)
        z = np.where(np.abs(h) > 0, 1 / np.where(h == 0, 1, h), 0)
        coh = np.nan_to_num(np.abs(sxy) ** 2 / (sxx * syy))
    return h, z, coh


def _weights(f, coh, fs):
    lo, hi = band(fs)
    inband = (f >= lo) & (f <= hi)
    c = np.clip(coh, 0, 0.999)
    return np.where(inband[:, None] & (c >= MIN_COHERENCE), c / (1 - c), 0.0)  # ∝ 1/variance of H


def fit_response(z, w, g, floor):
    """Weighted LS of the apparent inertia z (F,) on real coefficients of the columns g (k, F)
    and of `floor` (F,), the column of a white floor S_nn on the recorded torque (`floor_column`),
    held at S_nn ≥ 0; returns (coef (k + 1,), misfit)."""
    rel = np.sqrt(w / np.maximum(np.abs(z) ** 2, 1e-300))

    def solve(cols):
        A = np.concatenate([(cols * rel).real, (cols * rel).imag], axis=1).T
        b = np.concatenate([(z * rel).real, (z * rel).imag])
        return np.linalg.lstsq(A, b, rcond=None)[0]

    coef = solve(np.concatenate([g, floor[None]]))
    if coef[-1] < 0:
        coef = np.append(solve(g), 0.0)
    return coef, float(np.sum(rel**2 * np.abs(z - _model(coef, g, floor)) ** 2))


def _model(coef, g, floor):
    return coef[:-1] @ g + coef[-1] * floor


def floor_column(sxy, sxx):
    """The column of a white floor on the recorded torque in the apparent inertia: with x = u + n
    (n white, S_nn) and y = H u, S_xx = S_uu + S_nn and S_xy = H S_uu, so the H1 inertia
    Z = S_xx/S_xy = 1/H + S_nn/S_xy."""
    return np.where(np.abs(sxy) > 0, 1 / np.where(sxy == 0, 1, sxy), 0)


def search_grid(f: np.ndarray, fs: float) -> tuple[np.ndarray, np.ndarray]:
    """The searched (anti-resonance f_z, ζ) pairs (Q, 2) and their link responses G (Q, F)."""
    lo, hi = band(fs)
    pts = np.array([(fz, zeta) for fz in np.geomspace(lo / 4, hi, 60) for zeta in ZETAS])
    return pts, np.stack([link_response(f, 2 * np.pi * fz, zeta) for fz, zeta in pts])


def fit_grid(z, w, G, floor):
    """`fit_response` of z (F,) on the columns 1, G_q and the floor, for every grid point q at once:
    coefficients (Q, 3) (α, β, S_nn ≥ 0) and misfits (Q,). (The normal equations of three
    columns scaled to unit norm; S_nn held at 0 where it comes out negative. Only the bins of
    non-zero weight take part, and the columns shared by every point are summed once.)"""
    rel2 = w / np.maximum(np.abs(z) ** 2, 1e-300)
    on = rel2 > 0
    z, rel2, G, floor = z[on], rel2[on], G[:, on], floor[on]
    Q = G.shape[0]
    Gc = G.conj()
    M = np.empty((Q, 3, 3))
    M[:, 0, 0] = rel2.sum()
    M[:, 0, 1] = M[:, 1, 0] = (G @ rel2).real
    M[:, 0, 2] = M[:, 2, 0] = rel2 @ floor.real
    M[:, 1, 1] = (G * Gc).real @ rel2
    M[:, 1, 2] = M[:, 2, 1] = (Gc @ (rel2 * floor)).real
    M[:, 2, 2] = rel2 @ np.abs(floor) ** 2
    zw = rel2 * z
    v = np.stack([np.full(Q, zw.sum().real), (Gc @ zw).real, np.full(Q, (floor.conj() @ zw).real)], 1)
    d = np.sqrt(np.maximum(np.einsum("qaa->qa", M), 1e-300))
    Ms, vs = M / (d[:, :, None] * d[:, None, :]), v / d

    def solve(k):
        return (np.linalg.pinv(Ms[:, :k, :k]) @ vs[:, :k, None])[..., 0] / d[:, :k]

    x = solve(3)
    x = np.where(x[:, 2:] < 0, np.concatenate([solve(2), np.zeros((Q, 1))], 1), x)
    misfit = np.abs(z - x[:, :1] - x[:, 1:2] * G - x[:, 2:] * floor) ** 2 @ rel2
    return x, misfit


def _search(z, w, floor, pts, G, fs):
    """The grid point whose mode fits best over the joints (summed misfits), among those of a
    plausible motor share: (index, the joint where it gains most, its share r, the
    coefficients per joint (n, 3)); None where no point is plausible."""
    n = z.shape[1]
    one = np.ones((1, z.shape[0]), complex)
    rigid = np.array([fit_response(z[:, i], w[:, i], one, floor[:, i])[1] for i in range(n)])
    fits = [fit_grid(z[:, i], w[:, i], G, floor[:, i]) for i in range(n)]
    coef = np.stack([c for c, _ in fits], 1)  # (Q, n, 3)
    misfit = np.stack([m for _, m in fits], 1)  # (Q, n)
    joint = np.argmax(rigid[None] - misfit, axis=1)
    alpha, beta = coef[np.arange(len(pts)), joint, 0], coef[np.arange(len(pts)), joint, 1]
    with np.errstate(divide="ignore", invalid="ignore"):
        r = np.where(alpha + beta > 0, alpha / (alpha + beta), -1.0)
        ok = (r >= SHARE[0]) & (r <= SHARE[1]) & (pts[:, 0] / np.sqrt(np.abs(r)) <= 0.5 * fs)
    if not ok.any():
        return None
    q = int(np.flatnonzero(ok)[np.argmin(misfit.sum(1)[ok])])
    return q, int(joint[q]), float(r[q]), coef[q]


def detect(q: np.ndarray, tau: np.ndarray, dt: float, blocks: int = 8) -> Mode | str:
    """Look for a shaft mode; q (T, n) measured positions, tau (T, n) the torque acting on the
    joints (aligned). Where the recording cannot show one, why (a sentence).

    The mode reported is the one found on the whole recording. Its significance comes from
    held-out blocks: for each block, the anti-resonance and damping are searched again and the
    coefficients fitted on the other blocks alone, and the block's misfit is measured with them
    (a search on the whole recording would pick, among its 360 points, the one that also fits the
    held-out block's noise best)."""
    fs = 1 / dt
    T, n = q.shape
    nper = int(2 ** np.floor(np.log2(max(T / blocks / 4, 64))))
    lo, hi = band(fs)
    if blocks * nper > T:
        return f"too short: {blocks} blocks of {nper} samples are needed for its frequency response"
    acc = np.gradient(np.gradient(q, dt, axis=0), dt, axis=0)
    edges = np.linspace(0, T, blocks + 1).astype(int)
    parts = [_spectra(tau[a:b], acc[a:b], fs, nper) for a, b in itertools.pairwise(edges)]
    f = parts[0][0]
    total = [sum(p[j] for p in parts) for j in (1, 2, 3)]
    h, z, coh = _frf(*total)
    w = _weights(f, coh, fs)
    if not np.any(w > 0):
        return (
            f"no frequency in its band ({lo:.3g}-{hi:.3g} Hz) where the torque explains the measured "
            f"acceleration (coherence below {MIN_COHERENCE:g} throughout: the encoder's resolution or noise "
            "on the torque swamps the motion there)"
        )
    coherent = float(f[np.any(w > 0, axis=1)].max())
    floor = floor_column(total[0], total[1])
    pts, G = search_grid(f, fs)
    found = _search(z, w, floor, pts, G, fs)
    if found is None:
        short = coherent_only(coherent, fs)
        return "no mode of a plausible motor share of the inertia fits its frequency response" + (
            f": the response is {short}" if short else ""
        )
    best, joint, r, fitted_coef = found
    fz, zeta = pts[best]
    one = np.ones((1, f.size), complex)
    g = np.stack([one[0], G[best]])
    err_rigid, err_mode = np.zeros(blocks), np.zeros(blocks)
    # Each block is weighed by the other blocks' coherence: a bin's H1 variance follows the true
    # coherence, which one block's ~10 averaged segments estimate noisily and biased upward
    # (per-block weights let noise-only bins in and drown a mode that rings at γ² ≈ 0.4).
    for k, part in enumerate(parts):
        _, zk, _ = _frf(*part[1:])
        rest = [total[j] - part[j + 1] for j in range(3)]
        _, zo, co = _frf(*rest)
        wo = _weights(f, co, fs)
        fk, fo = floor_column(*part[1:3]), floor_column(*rest[:2])
        there = _search(zo, wo, fo, pts, G, fs)
        for i in range(n):
            rel = wo[:, i] / np.maximum(np.abs(zk[:, i]) ** 2, 1e-300)
            rigid_coef, _ = fit_response(zo[:, i], wo[:, i], one, fo[:, i])
            e_rigid = float(np.sum(rel * np.abs(zk[:, i] - _model(rigid_coef, one, fk[:, i])) ** 2))
            err_rigid[k] += e_rigid
            if there is None:  # no plausible mode on the other blocks: the rigid model stands
                err_mode[k] += e_rigid
                continue
            gk = np.stack([one[0], G[there[0]]])
            err_mode[k] += float(np.sum(rel * np.abs(zk[:, i] - _model(there[3][i], gk, fk[:, i])) ** 2))
    # the models as the measured response sees them (with the torque's floor)
    mag = lambda i, cols, coef: 1 / np.maximum(np.abs(_model(coef, cols, floor[:, i])), 1e-300)
    rigid = np.stack([mag(i, one, fit_response(z[:, i], w[:, i], one, floor[:, i])[0]) for i in range(n)], 1)
    fitted = np.stack([mag(i, g, fitted_coef[i]) for i in range(n)], 1)
    f_mode = float(fz / np.sqrt(r))
    return Mode(
        f_mode,
        float(zeta),
        r,
        joint,
        peaks_at(f, np.abs(h[:, joint]), f_mode, hi),
        err_rigid,
        err_mode,
        f,
        np.abs(h),
        rigid,
        fitted,
        coherent,
    )


def coherent_only(coherent_hz: float, fs: float) -> str:
    """Where the measured response is coherent over less than three quarters of the band, how far
    (a phrase); else ''."""
    hi = band(fs)[1]
    if coherent_hz >= 0.75 * hi:
        return ""
    return (
        f"coherent only up to {coherent_hz:.3g} Hz of its band's {hi:.3g} Hz (above, the encoder's "
        "resolution or noise on the torque swamps the motion)"
    )


def peaks_at(f, mag, f_mode, top) -> bool:
    """A peak at f_mode: above the falling flank (1.3–1.6 f), and above the rise into it (0.6–0.8
    f, where the bins reach): the motor passes the anti-resonance below a resonance, so every
    physical mode (ζ ≤ 0.2, r ≤ 0.9) stands at least 1.23 times above that level, while a response
    that falls steadily with frequency (H1 biased by noise on a recorded torque whose spectrum
    falls) passes the flank test alone."""
    near = (f >= 0.9 * f_mode) & (f <= 1.1 * f_mode)
    flank = (f >= 1.3 * f_mode) & (f <= 1.6 * f_mode) & (f <= top)
    rise = (f >= 0.6 * f_mode) & (f <= 0.8 * f_mode)
    if not near.any() or not flank.any():
        return False
    peak = mag[near].max()
    return bool(peak > PEAK * np.median(mag[flank]) and (not rise.any() or peak > PEAK * np.median(mag[rise])))
