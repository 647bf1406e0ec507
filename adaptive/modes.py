"""Detecting a structural mode (the `compliance` effect) from a recording.

A shaft mode at ~200 Hz lies far above the band where inverse dynamics identifies a model (a
few tens of Hz: encoder quantization puts noise into q̈ that grows with the band), so it leaves
nothing in the identification residual. Its evidence is in the frequency response from the
torque to the measured (motor) acceleration between `BAND` Hz and Nyquist. A rigid joint has a
flat apparent inertia Z(ω) = τ/θ̈ = J; a motor driving its link through a spring and damper has

    Z(ω) = α + β G(ω),   G(s) = (2ζω_z s + ω_z²) / (s² + 2ζω_z s + ω_z²)

(G: how the link follows the motor; ω_z: the anti-resonance), linear in (α, β) for fixed
(ω_z, ζ), which are found on a grid. The motor's share of the inertia is r = α/(α + β) and the
resonance f = ω_z/√r/2π (since ω_p² = k(1/J_m + 1/J_L) = ω_z²/r), the `compliance` effect's f.
Only physical modes count: lightly damped (ζ ≤ 0.05), a motor share r in `SHARE`, and a
resonance the measured response really shows — a peak of |θ̈/τ| at f at least twice its level
on the falling flank (1.3–1.6 f, inside the band; so at 1 kHz modes up to ~280 Hz are
resolved). Closed-loop data can otherwise dress the controller's response to encoder noise
(|θ̈/τ| rising steadily with frequency) up as a "mode" near the top of the band. The misfit is the coherence-weighted
relative error of Z over the band, and the error reduction the fraction of the rigid model's
misfit the mode removes. Frequency responses are estimated with the H1 estimator (cross-spectrum
over input spectrum, unbiased by noise on the measured position) per joint.

Only a recording that excites the mode says anything: the thesis's open-loop square-wave test
(Figs. 4-12 to 4-14), or closed-loop runs with enough damping gain to ring it (the Type 2
threshold). Under gentle closed-loop control the high-frequency torque is the controller's
answer to encoder noise, the spring model explains nothing the rigid one does not, and the
candidate is (rightly) not significant.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np
from scipy import signal

from manus.plants.effects import Compliance

BAND = (40.0, 450.0)  # Hz
MIN_COHERENCE = 0.5  # bins below this carry no usable frequency response
ZETAS = (0.005, 0.01, 0.02, 0.05)  # a structural mode is lightly damped
SHARE = (0.02, 0.9)  # a plausible motor share of the inertia; outside it the "mode" is not one


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

    @property
    def reduction(self) -> float:
        return 1 - float(np.sqrt(self.err_mode.sum() / self.err_rigid.sum()))

    def effect(self) -> Compliance:
        return Compliance(f_hz=self.f_hz, zeta=self.zeta)


def link_response(freq: np.ndarray, wz: float, zeta: float) -> np.ndarray:
    s = 2j * np.pi * freq
    return (2 * zeta * wz * s + wz**2) / (s**2 + 2 * zeta * wz * s + wz**2)


def _spectra(tau, acc, fs, nperseg):
    """Cross and auto spectra per joint: f (F,), sxy, sxx, syy (F, n)."""
    f, sxy = signal.csd(tau, acc, fs=fs, nperseg=nperseg, axis=0)
    _, sxx = signal.welch(tau, fs=fs, nperseg=nperseg, axis=0)
    _, syy = signal.welch(acc, fs=fs, nperseg=nperseg, axis=0)
    return f, sxy, sxx, syy


def _frf(sxy, sxx, syy):
    """H1 estimate of θ̈/τ, the apparent inertia Z = 1/H, and the coherence."""
    with np.errstate(divide="ignore", invalid="ignore"):
        h = np.nan_to_num(sxy / sxx)
        z = np.where(np.abs(h) > 0, 1 / np.where(h == 0, 1, h), 0)
        coh = np.nan_to_num(np.abs(sxy) ** 2 / (sxx * syy))
    return h, z, coh


def _weights(f, coh):
    inband = (f >= BAND[0]) & (f <= BAND[1])
    c = np.clip(coh, 0, 0.999)
    return np.where(inband[:, None] & (c >= MIN_COHERENCE), c / (1 - c), 0.0)  # ∝ 1/variance of H


def _fit(z, w, g):
    """Weighted LS of the apparent inertia z (F,) on real coefficients of the columns g (k, F);
    returns (coef, misfit)."""
    rel = np.sqrt(w / np.maximum(np.abs(z) ** 2, 1e-300))
    A = np.concatenate([(g * rel).real, (g * rel).imag], axis=1).T
    b = np.concatenate([(z * rel).real, (z * rel).imag])
    coef = np.linalg.lstsq(A, b, rcond=None)[0]
    return coef, float(np.sum(rel**2 * np.abs(z - coef @ g) ** 2))


def _columns(f, fz, zeta):
    one = np.ones((1, f.size), complex)
    return one, np.concatenate([one, link_response(f, 2 * np.pi * fz, zeta)[None]])


def detect(q: np.ndarray, tau: np.ndarray, dt: float, blocks: int = 8) -> Mode | None:
    """Look for a shaft mode; q (T, n) measured positions, tau (T, n) the torque acting on the
    joints (aligned). None when the recording cannot show one (sampled too slowly, too short).

    The anti-resonance and damping are searched on the whole recording; the significance comes
    from held-out blocks: each block's misfit with coefficients fitted on the other blocks."""
    fs = 1 / dt
    T, n = q.shape
    nper = int(2 ** np.floor(np.log2(max(T / blocks / 4, 64))))
    if 0.5 * fs <= BAND[0] * 2 or T < blocks * nper:
        return None
    acc = np.gradient(np.gradient(q, dt, axis=0), dt, axis=0)
    edges = np.linspace(0, T, blocks + 1).astype(int)
    parts = [_spectra(tau[a:b], acc[a:b], fs, nper) for a, b in zip(edges[:-1], edges[1:])]
    f = parts[0][0]
    total = [sum(p[j] for p in parts) for j in (1, 2, 3)]
    h, z, coh = _frf(*total)
    w = _weights(f, coh)
    if not np.any(w > 0):
        return None
    best = None
    one = _columns(f, 1.0, 0.1)[0]
    for fz in np.geomspace(BAND[0] / 4, BAND[1], 60):
        for zeta in ZETAS:
            g = _columns(f, fz, zeta)[1]
            fits = [_fit(z[:, i], w[:, i], g) for i in range(n)]
            gains = [_fit(z[:, i], w[:, i], one)[1] - m for i, (_, m) in enumerate(fits)]
            joint = int(np.argmax(gains))
            (alpha, beta), _ = fits[joint]
            r = alpha / (alpha + beta) if alpha + beta > 0 else -1.0
            if not SHARE[0] <= r <= SHARE[1] or fz / np.sqrt(r) > 0.5 * fs:
                continue
            misfit = sum(m for _, m in fits)
            if best is None or misfit < best[0]:
                best = (misfit, fz, zeta, joint, float(r))
    if best is None:
        return None
    _, fz, zeta, joint, r = best
    one, g = _columns(f, fz, zeta)
    err_rigid, err_mode = np.zeros(blocks), np.zeros(blocks)
    for k, part in enumerate(parts):
        _, zk, ck = _frf(*part[1:])
        wk = _weights(f, ck)
        _, zo, co = _frf(*[total[j] - part[j + 1] for j in range(3)])
        wo = _weights(f, co)
        for i in range(n):
            for cols, err in ((one, err_rigid), (g, err_mode)):
                coef, _ = _fit(zo[:, i], wo[:, i], cols)
                rel = wk[:, i] / np.maximum(np.abs(zk[:, i]) ** 2, 1e-300)
                err[k] += float(np.sum(rel * np.abs(zk[:, i] - coef @ cols) ** 2))
    mag = lambda i, cols: 1 / np.abs(_fit(z[:, i], w[:, i], cols)[0] @ cols)
    rigid = np.stack([mag(i, one) for i in range(n)], 1)
    fitted = np.stack([mag(i, g) for i in range(n)], 1)
    f_mode = float(fz / np.sqrt(r))
    return Mode(f_mode, float(zeta), r, joint, _peaks(f, np.abs(h[:, joint]), f_mode), err_rigid, err_mode,
                f, np.abs(h), rigid, fitted)


def _peaks(f, mag, f_mode) -> bool:
    near = (f >= 0.9 * f_mode) & (f <= 1.1 * f_mode)
    flank = (f >= 1.3 * f_mode) & (f <= 1.6 * f_mode) & (f <= BAND[1])
    if not near.any() or flank.sum() < 2:
        return False
    return bool(mag[near].max() > 2 * np.median(mag[flank]))
