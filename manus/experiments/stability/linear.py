"""The Type 1 threshold: the thesis's linear 1-DOF model with a delay (eqs. 4.1–4.2, §4.3.1).

The endpoint near the workspace centre is a mass m with damping b, optionally against an
environment spring k_env (eq. 4.2) and with the shaft mode of Fig. 4-16 (then m is split into
motor and link, and the position is measured on the motor). The impedance controller

    u = k (x_d − x) − b_c v̂,    v̂(s) = λ s / (s + λ) x(s)    (eq. 3.19, λ = 188.5 rad/s)

acts through the amplifier's pure delay τ (1 ms). Without the delay and the shaft mode the closed
loop is eq. 4.1 (eq. 4.2 with k_env):

    x/x_d = k (s + λ) / (m s³ + (mλ + b) s² + (bλ + b_c λ + k + k_env) s + (k + k_env) λ)

The thesis's method: break the loop at k (set k = 1), and the gain margin of what remains,

    L(s) = e^{−sτ} P(s) / (1 + b_c F(s) e^{−sτ} P(s)),   P = 1/(m s² + b s + k_env),

is the largest stable stiffness for that b_c. The margin is read from L's frequency response
with the delay exact (e^{−jωτ}); python-control builds the systems, and its `stability_margins`
of the same loop with an order-8 Padé delay agrees to 10⁻⁴ (tests); the closed-loop poles (with
that Padé delay) confirm each limit. With `rate_hz` the loop is the exact sampled one instead:
the plant discretized with a zero-order hold and the delay (a fractional delay handled exactly,
Åström & Wittenmark §3.2), the velocity filter in the Tustin form the controller runs
(`manus.estimators.base.FilteredFirstDifference`), position read at each tick and the command held
over the period — the simulator's own sampling order, so this threshold is what the simulator
reaches without quantization (tests check it).

Units: SI (m, N, s): the 1-DOF endpoint model of chapter 4.
"""

from __future__ import annotations

import functools
from dataclasses import dataclass, replace

import control
import numpy as np
import scipy.linalg
import scipy.optimize

from manus.plants.effects import Compliance

PADE_ORDER = 8
SPRINGS = (1050.0, 1883.0, 3826.0, 9842.0, 34660.0, 130900.0)  # table 4.2 [N/m]


@dataclass(frozen=True)
class LinearAxis:
    """The linear 1-DOF model: mass [kg], damping [N·s/m], velocity-filter corner λ [rad/s],
    delay [s], environment spring [N/m]; `shaft` adds the compliance effect's two-mass mode
    (`manus.plants.effects.Compliance`: motor fraction, frequency and damping ratio)."""

    mass: float = 1.0
    damping: float = 1.5
    corner: float = 188.5
    delay: float = 1e-3
    spring: float = 0.0
    shaft: Compliance | None = None

    def with_(self, **changes) -> LinearAxis:
        return replace(self, **changes)

    def state_space(self) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
        """(A, B, C) from the actuator force to the measured position, no delay."""
        m, b, ke = self.mass, self.damping, self.spring
        if self.shaft is None:
            return np.array([[0, 1], [-ke / m, -b / m]]), np.array([[0], [1 / m]]), np.array([[1.0, 0]])
        k2, b2 = (float(x) for x in self.shaft.shaft(m))
        mm = self.shaft.motor_fraction * m  # motor: friction b, measured; link: the rest, the spring
        ml = m - mm
        A = np.array(
            [
                [0, 1, 0, 0],
                [-k2 / mm, -(b + b2) / mm, k2 / mm, b2 / mm],
                [0, 0, 0, 1],
                [k2 / ml, b2 / ml, -(k2 + ke) / ml, -b2 / ml],
            ]
        )
        return A, np.array([[0], [1 / mm], [0], [0]]), np.array([[1.0, 0, 0, 0]])

    # -- the loop broken at k ---------------------------------------------------------------------
    def plant(self) -> control.StateSpace:
        return control.ss(*self.state_space(), 0)  # pyright: ignore[reportReturnType] (python-control is untyped)

    def filter(self, rate_hz: float | None = None) -> control.TransferFunction:
        """The velocity estimator λ s/(s + λ), or its Tustin form at `rate_hz`."""
        lam = self.corner
        if rate_hz is None:
            return control.tf([lam, 0], [1, lam])  # pyright: ignore[reportReturnType] (python-control is untyped)
        T = 1.0 / rate_hz
        a, g = (2 - lam * T) / (2 + lam * T), 2 * lam / (2 + lam * T)
        return control.tf([g, -g], [1, -a], T)  # pyright: ignore[reportReturnType] (python-control is untyped)

    def closed_loop(self, k: float, b_c: float) -> control.TransferFunction:
        """x/x_d without the delay: eq. 4.1 (eq. 4.2 with a spring)."""
        return k * control.feedback(control.ss2tf(self.plant()), k + b_c * self.filter())

    def loop(self, b_c: float, rate_hz: float | None = None) -> control.StateSpace:
        """L such that the closed loop with stiffness k is 1 + k L = 0: the loop broken at k,
        with the delay (Padé, or exactly sampled), in state-space form (well conditioned)."""
        if rate_hz is None:
            delay = _pade(self.delay) if self.delay > 0 else 1
            forward = delay * self.plant()
        else:
            forward = self.sampled(rate_hz)
        return control.feedback(forward, b_c * self.filter(rate_hz))  # pyright: ignore[reportReturnType, reportArgumentType] (python-control is untyped)

    def sampled(self, rate_hz: float) -> control.StateSpace:
        """The plant with zero-order hold and delay, exact at the sampling instants.

        Over one period the command computed at tick k−n acts for the last T − d', the one
        before it for the first d' (d = nT + d'): x_{k+1} = Φ x_k + Γ0 u_{k−n} + Γ1 u_{k−n−1}.
        Past commands are kept in a shift register."""
        phi, gamma0, gamma1, n = self._hold(1.0 / rate_hz)
        A, _, C = self.state_space()
        nx = A.shape[0]
        regs = n + bool(np.any(gamma1))  # registers hold u_{k−1} ... u_{k−regs}
        Ad = np.zeros((nx + regs, nx + regs))
        Bd = np.zeros((nx + regs, 1))
        Ad[:nx, :nx] = phi
        if n == 0:
            Bd[:nx] += gamma0
        else:
            Ad[:nx, nx + n - 1 : nx + n] += gamma0
        if regs > n:
            Ad[:nx, nx + n : nx + n + 1] += gamma1
        if regs:
            Bd[nx, 0] = 1.0
            Ad[nx + 1 :, nx:-1] = np.eye(regs - 1)
        return control.ss(Ad, Bd, np.hstack([C, np.zeros((1, regs))]), 0, 1.0 / rate_hz)  # pyright: ignore[reportReturnType] (python-control is untyped)

    def _hold(self, T: float):
        """(Φ, Γ0, Γ1, n) of `sampled` (cached: searches ask for the same plant many times)."""
        A, B, _ = self.state_space()
        return _hold(tuple(map(tuple, A)), tuple(map(tuple, B)), self.delay, T)

    def response(self, b_c: float, rate_hz: float | None = None):
        """ω ↦ L(jω) (or L(e^{jωT})), ω [rad/s] an array, with the delay exact (e^{−jωτ})."""
        A, B, C = self.state_space()
        sampled = None
        if rate_hz is not None:
            T = 1.0 / rate_hz
            sampled = (T, *self._hold(T))
        f = self.filter(rate_hz)
        num, den = f.num[0][0], f.den[0][0]
        eye = np.eye(A.shape[0])

        def at(w):
            w = np.atleast_1d(np.asarray(w, float))
            if sampled is None:
                s = 1j * w
                a, b, forward = A, B, np.exp(-s * self.delay)
            else:
                T, phi, gamma0, gamma1, n = sampled
                s = np.exp(1j * w * T)
                a, b, forward = phi, gamma0 + gamma1 / s[:, None, None], s ** (-n)
            b = np.broadcast_to(b, (w.size, *b.shape[-2:]))
            forward = forward * (C @ np.linalg.solve(s[:, None, None] * eye - a, b))[:, 0, 0]
            return forward / (1 + b_c * np.polyval(num, s) / np.polyval(den, s) * forward)

        return at

    # -- thresholds ---------------------------------------------------------------------------------
    def closed_poles(self, k: float, b_c: float, rate_hz: float | None = None) -> np.ndarray:
        """Poles of the closed loop with the delay (Padé, or sampled: z-plane)."""
        return control.poles(control.feedback(self.loop(b_c, rate_hz), k))  # pyright: ignore[reportArgumentType] (python-control is untyped)

    def stable(self, k: float, b_c: float, rate_hz: float | None = None) -> bool:
        return _inside(self.closed_poles(k, b_c, rate_hz), rate_hz, strict=True)

    def k_max(self, b_c: float, rate_hz: float | None = None) -> float:
        """The largest stable stiffness for damping b_c: the gain margin of `loop`.

        The loop's frequency response (delay exact) is scanned for crossings of the negative
        real axis, each refined by root finding; the smallest gain margin is the limit (as k
        grows, −1/k reaches the leftmost crossing first). NaN when the loop is unstable already
        for k → 0 (b_c below −b: no stiffness helps); inf when nothing crosses."""
        if not _inside(control.poles(self.loop(b_c, rate_hz)), rate_hz, strict=False):
            return float("nan")
        top = np.pi * rate_hz if rate_hz else 1e5
        w = np.geomspace(1e-2, top, 20000)
        at = self.response(b_c, rate_hz)
        L = at(w)
        gains = [-1 / L[-1].real] if rate_hz and L[-1].real < 0 else []  # the Nyquist frequency
        cross = np.flatnonzero((np.sign(L.imag[:-1]) * np.sign(L.imag[1:]) < 0) & (L.real[:-1] < 0))
        rough = -1 / L.real[cross]
        for i in cross[rough <= 1.5 * rough.min()] if cross.size else ():  # refine the likely minima
            wc = scipy.optimize.brentq(lambda x: at(x)[0].imag, w[i], w[i + 1], xtol=float(1e-12 * w[i]))
            re = at(wc)[0].real
            if re < 0:
                gains.append(-1 / re)
        return float(min(gains)) if gains else float("inf")

    def b_c_min(self, k: float, rate_hz: float | None = None, lo: float = -10.0, tol: float = 1e-4) -> float:
        """The most negative controller damping that stays stable at stiffness k (bisection on
        the closed-loop poles; the region is an interval in b_c down to this edge)."""
        hi = 0.0
        if not self.stable(k, hi, rate_hz):
            return float("nan")
        while hi - lo > tol:
            mid = 0.5 * (lo + hi)
            lo, hi = (lo, mid) if self.stable(k, mid, rate_hz) else (mid, hi)
        return hi


@functools.lru_cache(maxsize=64)
def _hold(a_rows: tuple, b_rows: tuple, delay: float, T: float):
    """(Φ, Γ0, Γ1, n) for the system (A, B) sampled every T with an input delay, each from one
    matrix exponential of [[A, B], [0, 0]]; A and B as tuples of rows (hashable: cached)."""
    A, B = np.array(a_rows), np.array(b_rows)
    nx = A.shape[0]

    def hold(t):  # (e^{At}, ∫0^t e^{Aσ} dσ B)
        M = np.zeros((nx + 1, nx + 1))
        M[:nx, :nx], M[:nx, nx:] = A, B
        E = scipy.linalg.expm(M * t)
        return E[:nx, :nx], E[:nx, nx:]

    n = int(np.floor(delay / T + 1e-9))
    frac = delay - n * T
    ahead, gamma0 = hold(T - frac)
    gamma1 = ahead @ hold(frac)[1] if frac > 1e-12 * T else np.zeros_like(gamma0)
    return hold(T)[0], gamma0, gamma1, n


@functools.lru_cache(maxsize=16)
def _pade(delay: float) -> control.StateSpace:
    return control.ss(control.tf(*control.pade(delay, PADE_ORDER)))  # pyright: ignore[reportReturnType] (python-control is untyped)


def _inside(poles: np.ndarray, rate_hz: float | None, strict: bool) -> bool:
    """All poles in the stable region (open when `strict`, else marginal poles allowed)."""
    margin = -1e-12 if strict else 1e-9
    return bool(np.all(np.abs(poles) - 1 < margin) if rate_hz else np.all(np.real(poles) < margin))


def curve(model: LinearAxis, b_cs, rate_hz: float | None = None) -> np.ndarray:
    """k_max for each controller damping in `b_cs`."""
    return np.array([model.k_max(float(b), rate_hz) for b in b_cs])
