"""Inverse-dynamics identification of a model from a recording (`manus fit`).

The recorded commands and positions are prepared once (`prepare`):

- the command u_k arrives `d` seconds late (the `delay` effect), so the torque acting at t_k is
  u read at fractional index k − d/T (linear interpolation). When the recording says its command
  was held over each period (metadata `command_hold: zoh`, as manus's simulator and hardware loop
  write), u_k acts on [t_k, t_k + T): half a period more. A file that does not say is read as
  the EMPS reference reads its data, u_k acting at t_k;
- parallel filtering (Gautier's procedure, as in the EMPS reference): the regressor columns are
  evaluated on kinematics from the zero-phase differentiator at a wider band (`KINEMATIC_BAND`
  times the cut-off), then each column and the torque are low-passed alike at the cut-off. For a
  linear term this is the usual filtering; for a non-linear one such as sgn(q̇) the step at a
  velocity reversal is smeared exactly as the friction step in the filtered torque is, instead
  of being compared sharp against a smooth torque;
- the filter's start-up transient is cut at both ends and the rows are decimated to about four
  samples per cut-off period (neighbouring rows of a low-passed signal carry no new information,
  and the standard deviations are computed from the decimated rows).

The model's regressor is the stack of its effects' columns (`manus.plants.effects`, ∂torque/∂θ), so
candidate models share the columns computed once (`Columns`). The least-squares solution names
redundant parameters (a column that the earlier ones already explain) instead of failing, and
reports each parameter's standard deviation from a heteroscedasticity- and
autocorrelation-consistent (Newey–West) covariance. Non-linear parameters (the cogging order, the
Stribeck velocity, the delay) are found by search when the model does not fix them.
"""

from __future__ import annotations

from dataclasses import dataclass, field

import equinox as eqx
import jax
import jax.numpy as jnp
import numpy as np

from manus.adaptive.search import search as search_parameter
from manus.estimators.offline import differentiate, edge, lowpass
from manus.plants.effects import Effect, Model
from manus.plants.errors import ModelError
from manus.plants.recording import Recording

MIN_CUTOFF_HZ = 10.0
STANDSTILL_S = 0.005  # longer under two counts per band period than a zero crossing takes: at rest
KINEMATIC_BAND = 4.0  # kinematics for the columns are filtered at this multiple of the cut-off
MIN_SAMPLES = 8  # below this the recording cannot even be differentiated
MIN_ROWS = 20  # fewer usable rows than this identify nothing reliably


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
    window: np.ndarray | None = None  # the samples inside the filter's start-up edges (before standstill and decimation)
    _tau: dict = field(default_factory=dict)

    @property
    def dt(self) -> float:
        return self.rec.dt

    @property
    def n_joints(self) -> int:
        return self.rec.n_joints

    @property
    def kinematic_hz(self) -> float:
        return min(KINEMATIC_BAND * self.cutoff_hz, 0.45 / self.dt)

    def filtered(self, x: np.ndarray) -> np.ndarray:
        """What identification compares: x through the kinematic band and the cut-off (the
        positions went through the same two filters before differentiation)."""
        return lowpass(lowpass(x, self.dt, self.kinematic_hz), self.dt, self.cutoff_hz)

    def tau(self, delay: float = 0.0, full: bool = False) -> np.ndarray:
        """The torque acting on the joints, aligned with the positions, filtered like the columns.
        (Filtering and the fractional shift are both linear and time-invariant: they commute, so
        the torque is filtered once and shifted per delay.)"""
        if "filtered" not in self._tau:
            self._tau["filtered"] = self.filtered(self.rec.tau)
        hold = 0.5 if self.rec.meta.get("command_hold") == "zoh" else 0.0
        out = align(self._tau["filtered"], delay / self.dt + hold)
        return out if full else out[self.rows]

    def moving(self) -> np.ndarray:
        """Per joint: the fraction of used samples where the joint moves (more than a few
        encoder counts per filter time constant)."""
        v_min = 5 * self.step * self.cutoff_hz
        return np.mean(np.abs(self.qd[self.rows]) > v_min, axis=0)


def align(u: np.ndarray, lag: float) -> np.ndarray:
    """u read `lag` samples late (fractional, linear interpolation; held at the start)."""
    k = np.arange(u.shape[0]) - lag
    k0 = np.clip(np.floor(k).astype(int), 0, u.shape[0] - 1)
    k1 = np.clip(k0 + 1, 0, u.shape[0] - 1)
    w = np.clip(k - np.floor(k), 0, 1)[:, None]
    return (1 - w) * u[k0] + w * u[k1]


def encoder_step(rec: Recording) -> float:
    """The position grid: from the metadata, else the smallest non-zero position change."""
    if rec.position_step:
        return rec.position_step
    d = np.abs(np.diff(rec.q, axis=0))
    d = d[d > 0]
    return float(d.min()) if d.size else 0.0


def _long_runs(mask: np.ndarray, longer_than: int) -> np.ndarray:
    """The samples of `mask` that lie in runs of more than `longer_than` samples."""
    edges = np.diff(np.r_[0, mask.astype(np.int8), 0])
    starts, stops = np.flatnonzero(edges == 1), np.flatnonzero(edges == -1)
    out = np.zeros_like(mask)
    for a, b in zip(starts, stops):
        if b - a > longer_than:
            out[a:b] = True
    return out


def auto_cutoff(rec: Recording) -> float:
    """The identification bandwidth the data call for: three times the frequency below which
    99.5 % of the torque's power lies, at least `MIN_CUTOFF_HZ`, below Nyquist. Encoder
    quantization puts noise into q̈ that grows as the 2.5th power of the cut-off, so the cut-off
    should not reach far past where the excitation lives (the arm under a 3 Hz multi-sine: ~13 Hz;
    the EMPS axis: ~80 Hz)."""
    from scipy import signal

    tau = rec.tau - rec.tau.mean(axis=0)
    f, p = signal.welch(tau, fs=rec.sample_rate_hz, nperseg=min(2048, len(rec)), axis=0)
    power = np.cumsum(p.sum(axis=1))
    f995 = f[min(np.searchsorted(power, 0.995 * power[-1]), len(f) - 1)]
    return float(np.clip(3 * f995, MIN_CUTOFF_HZ, 0.45 * rec.sample_rate_hz))


def prepare(rec: Recording, cutoff_hz: float | None = None, decimate: int | None = None,
            exclude_standstill: bool = True) -> Data:
    """Filter, differentiate and choose the rows. With `exclude_standstill`, the rows within
    half a cut-off period of a sample where a joint is at rest are left out: a joint at rest
    holds whatever friction the other torques ask of it (stiction), which no function of the
    velocity predicts, and the low-pass spreads that sample's torque over its neighbours. A joint
    is at rest when its speed stays under two encoder counts per kinematic-band period for more
    than `STANDSTILL_S` (a mere zero crossing is shorter: the EMPS axis never rests, the arm under
    impedance control sticks for tens of milliseconds at each reversal).

    A recording too short or too still to leave `MIN_ROWS` usable rows is still prepared: `fit`
    refuses it, naming the parameters the remaining samples cannot identify (the model is not
    known here)."""
    if len(rec) < MIN_SAMPLES:
        raise ModelError(f"{rec.path}: recording too short: {len(rec)} samples (at least {MIN_SAMPLES} are needed "
                         "to differentiate the positions; no parameter is identifiable)")
    dt = rec.dt
    cutoff_hz = auto_cutoff(rec) if cutoff_hz is None else cutoff_hz
    if cutoff_hz <= 0:
        raise ModelError(f"cut-off frequency must be positive (got {cutoff_hz})")
    cutoff_hz = min(cutoff_hz, 0.45 / dt)
    band = min(KINEMATIC_BAND * cutoff_hz, 0.45 / dt)
    q, qd, qdd = differentiate(rec.q, dt, band)
    step = encoder_step(rec)
    cut = edge(dt, cutoff_hz)
    keep = np.zeros(len(rec), bool)
    keep[cut:len(rec) - cut] = True
    usable = keep.sum()
    if exclude_standstill and step > 0:
        slow = np.abs(qd) < 2 * step * band
        still = np.any([_long_runs(slow[:, j], int(round(STANDSTILL_S / dt))) for j in range(rec.n_joints)], axis=0)
        w = int(np.ceil(0.5 / (cutoff_hz * dt)))
        near = np.convolve(still.astype(float), np.ones(2 * w + 1), mode="same") > 0
        keep &= ~near
    if decimate is None:
        decimate = max(1, int(0.25 / (cutoff_hz * dt)))
    rows = np.flatnonzero(keep)[::decimate]
    window = np.arange(cut, max(cut, len(rec) - cut))[::decimate]
    return Data(rec, cutoff_hz, q, qd, qdd, rows, step, float(1 - keep.sum() / max(usable, 1)), window)


# -- regressor columns, computed once per effect ------------------------------------------

@eqx.filter_jit
def _effect_columns(effect: Effect, structure, q, qd, qdd):
    model = Model(structure, (effect,))
    return jax.vmap(model.regressor)(q, qd, qdd)


class Columns:
    """Regressor columns of effects on prepared data, cached by effect spec."""

    def __init__(self, data: Data, rows: np.ndarray | None = None):
        self.data = data
        self.rows = data.rows if rows is None else rows
        self._cache: dict[str, np.ndarray] = {}
        self._args = tuple(jnp.asarray(x) for x in (data.q, data.qd, data.qdd))

    def effect(self, e: Effect) -> np.ndarray:
        """(rows, n, p) columns of one linear effect, low-passed like the torque."""
        if e.spec not in self._cache:
            d = self.data
            full = np.asarray(_effect_columns(e, d.rec.structure, *self._args))
            self._cache[e.spec] = lowpass(full, d.dt, d.cutoff_hz)[self.rows]
        return self._cache[e.spec]

    def model(self, model: Model) -> np.ndarray:
        """(rows, n, P): the model's regressor, its effects' columns side by side."""
        blocks = [self.effect(e) for e in model.effects if e.linear]
        n = self.data.n_joints
        return np.concatenate(blocks, axis=2) if blocks else np.zeros((self.rows.size, n, 0))


# -- least squares --------------------------------------------------------------------------

@dataclass
class Solution:
    theta: np.ndarray  # (P,)
    std: np.ndarray  # (P,)
    redundant: list[int]  # columns the others already explain (their θ is 0)
    residual: np.ndarray  # (rows, n)
    rel_error: float


def solve(Y: np.ndarray, tau: np.ndarray, rtol: float = 1e-7, hac_lags: int = 5) -> Solution:
    """Least squares τ ≈ Y θ over all rows and joints. Y (rows, n, P), tau (rows, n)."""
    rows, n, P = Y.shape
    X = Y.reshape(rows * n, P)
    y = tau.reshape(rows * n)
    scale = np.sqrt(np.mean(X**2, axis=0))
    # Gram–Schmidt order: a column is redundant when the earlier ones explain it
    redundant = unidentifiable(Y, rtol)
    keep = [j for j in range(P) if j not in redundant]
    theta = np.zeros(P)
    std = np.full(P, np.nan)
    if keep:
        Xk = X[:, keep] / scale[keep]
        coef, *_ = np.linalg.lstsq(Xk, y, rcond=None)
        theta[keep] = coef / scale[keep]
        e = y - Xk @ coef
        cov = _newey_west(Xk, e, n, hac_lags)
        std[keep] = np.sqrt(np.maximum(np.diag(cov), 0)) / scale[keep]
    resid = (y - X @ theta).reshape(rows, n)
    denom = np.linalg.norm(y)
    return Solution(theta, std, sorted(redundant), resid, float(np.linalg.norm(resid) / denom) if denom else np.inf)


def _newey_west(X: np.ndarray, e: np.ndarray, n: int, lags: int) -> np.ndarray:
    """Covariance of the LS estimate robust to unequal noise per joint and to residual
    autocorrelation over `lags` rows (Bartlett weights). Rows are interleaved by joint."""
    XtX_inv = np.linalg.pinv(X.T @ X)
    g = X * e[:, None]  # score per row
    meat = g.T @ g
    for lag in range(1, lags + 1):
        w = 1 - lag / (lags + 1)
        a, b = g[lag * n:], g[:-lag * n]  # the same joint, `lag` rows apart
        meat += w * (a.T @ b + b.T @ a)
    return XtX_inv @ meat @ XtX_inv


# -- fitting a model -------------------------------------------------------------------------

@dataclass
class Fit:
    model: Model  # with its non-linear parameters as found
    names: list[str]
    theta: np.ndarray
    std: np.ndarray
    redundant: list[str]
    rel_error: float
    residual: np.ndarray  # (rows, n)
    data: Data
    delay: float
    search: dict = field(default_factory=dict)  # the search curves: name -> (grid, rel_errors)

    @property
    def params(self) -> dict[str, float]:
        return dict(zip(self.names, self.theta.tolist()))

    def predicted(self) -> np.ndarray:
        return self.data.tau(self.delay) - self.residual

    def report(self) -> dict:
        """The JSON contract of `manus fit` (docs/cli.md)."""
        params = {k: {"value": float(v), "std": None if not np.isfinite(s) else float(s)}
                  for k, v, s in zip(self.names, self.theta, self.std)}
        nonlinear = {k: v for e in self.model.effects for k, v in e.describe().items()}
        out = {"model": self.model.effect_names, "spec": self.model.spec, "params": params,
               "rel_error": self.rel_error, "samples": int(self.data.rows.size),
               "cutoff_hz": self.data.cutoff_hz, "standstill_excluded": self.data.standstill}
        if nonlinear:
            out["nonlinear"] = nonlinear
        if self.redundant:
            out["redundant"] = self.redundant
        return out

    def evaluate(self, rec: Recording | Data) -> "Fit":
        """These parameters, unchanged, applied to another recording (validation: the EMPS
        reference's 5.98 % on the PULSES file). The recording is prepared at this fit's cut-off
        (the band the parameters were identified in); the result is a `Fit` whose `residual`,
        `rel_error` and `data` are the other recording's, with `theta`/`std` as identified here."""
        data = rec if isinstance(rec, Data) else prepare(rec, self.data.cutoff_hz)
        if data.n_joints != self.model.n_joints:
            raise ModelError(f"{data.rec.path}: the fitted model has {self.model.n_joints} joints, the recording "
                             f"{data.n_joints}")
        if data.rec.structure_name != self.data.rec.structure_name:
            raise ModelError(f"{data.rec.path}: structure {data.rec.structure_name!r}, but the model was fitted on "
                             f"a {self.data.rec.structure_name!r} recording")
        _check_rows(data, self.model)
        tau = data.tau(self.delay)
        resid = tau - Columns(data).model(self.model) @ self.theta
        denom = np.linalg.norm(tau)
        rel = float(np.linalg.norm(resid) / denom) if denom else np.inf
        return Fit(self.model, list(self.names), self.theta, self.std, list(self.redundant), rel, resid, data,
                   self.delay, {})

    def rel_error_on(self, rec: Recording | Data) -> float:
        """`rel_error` of these parameters on another recording (see `evaluate`)."""
        return self.evaluate(rec).rel_error


SEARCHABLE = ("cogging", "stribeck", "delay")


def _model_from(model: Model | str, structure) -> tuple[Model, set[str]]:
    """A Model from text; effects given with an argument (cogging:39) are fixed, not searched."""
    if isinstance(model, Model):
        return model, set()
    fixed = {t.split(":")[0].strip() for t in model.split(",") if ":" in t}
    return Model(structure, model), fixed


def fit(rec: Recording | Data, model: Model | str, cutoff_hz: float | None = None,
        fixed: set[str] | None = None, columns: Columns | None = None) -> Fit:
    """Identify `model`'s parameters from `rec`. Non-linear parameters of effects not in
    `fixed` are searched (a model given as text fixes those written with an argument)."""
    data = rec if isinstance(rec, Data) else prepare(rec, cutoff_hz)
    model, fixed_text = _model_from(model, data.rec.structure)
    fixed = fixed_text | (fixed or set())
    if model.n_joints != data.n_joints:
        raise ModelError(f"the model has {model.n_joints} joints, the recording {data.n_joints}")
    if model.has("compliance"):
        raise ModelError("compliance is a structural mode above the identification bandwidth: "
                         "`manus diagnose` detects it from the spectrum; it has no inverse-dynamics columns")
    cols = columns or Columns(data)
    _check_rows(data, model)
    _check_motion(data, model)
    search: dict = {}
    for name in SEARCHABLE:
        e = model.get(name)
        if e is not None and name not in fixed:
            model, curve = search_parameter(data, cols, model, e)
            search[name] = curve
    delay = model.get("delay").seconds if model.has("delay") else 0.0
    sol = solve(cols.model(model), data.tau(delay))
    names = list(model.names)
    return Fit(model, names, sol.theta, sol.std, [names[j] for j in sol.redundant], sol.rel_error,
               sol.residual, data, delay, search)


def _check_rows(data: Data, model: Model) -> None:
    """Refuse a recording that leaves fewer than `MIN_ROWS` usable rows, naming the parameters
    that are not identifiable: those outside the rank of the model's regressor over every sample
    inside the filter's start-up edges (standstill included: at rest q̇ = q̈ = 0, so inertia and
    friction columns vanish there; a recording shorter than its two edges has no row at all)."""
    if data.rows.size >= MIN_ROWS:
        return
    window = data.window if data.window is not None else np.zeros(0, int)
    lin = Model(model.structure, tuple(e for e in model.effects if e.linear))
    names = list(lin.names)
    if window.size:
        Y = Columns(data, rows=window).model(lin)
        lost = [names[j] for j in unidentifiable(Y)]
    else:
        lost = names
    rec = data.rec
    why = (f"{len(rec)} samples ({len(rec) * data.dt:.3g} s) leave {data.rows.size} usable rows "
           f"(at least {MIN_ROWS} needed) once the filter's start-up ({edge(data.dt, data.cutoff_hz)} samples at "
           f"each end, {data.cutoff_hz:.3g} Hz cut-off) and standstill are left out")
    what = (f"parameters {', '.join(lost)} are not identifiable (the regressor has rank {len(names) - len(lost)} "
            f"of {len(names)})" if lost else "too few rows to identify the parameters reliably")
    raise ModelError(f"{rec.path}: recording too short or without motion: {why}; {what}; record longer, "
                     "with the joints moving (e.g. a multi-sine reference)")


def unidentifiable(Y: np.ndarray, rtol: float = 1e-7) -> list[int]:
    """Columns of Y (rows, n, P) that are zero or that the earlier ones explain (the regressor's
    rank deficiency, in column order); every column when there are fewer equations than the rank
    would need."""
    rows, n, P = Y.shape
    if rows * n == 0:
        return list(range(P))
    X = Y.reshape(rows * n, P)
    scale = np.sqrt(np.mean(X**2, axis=0))
    out = [j for j in range(P) if not scale[j] > 0]
    keep = [j for j in range(P) if scale[j] > 0]
    if keep:
        r = np.abs(np.diag(np.linalg.qr(X[:, keep] / scale[keep], mode="r")))
        r = np.r_[r, np.zeros(len(keep) - r.size)]  # fewer equations than columns: the rest are lost
        out += [keep[j] for j in np.flatnonzero(r < rtol * max(r.max(initial=0), 1e-300) * np.sqrt(rows * n))]
    return sorted(out)


def _check_motion(data: Data, model: Model) -> None:
    """A joint that does not move identifies none of its velocity- or inertia-driven terms."""
    still = [i for i, f in enumerate(data.moving()) if f < 0.02]
    if not still:
        return
    lost = [k for e in model.effects if e.name not in ("offset", "gravity", "cogging")
            for k in e.names(model.structure)
            if any(k.endswith(str(i + 1)) for i in still) or (e.name == "rigid" and model.n_joints == 2)]
    joints = ", ".join(f"joint {i + 1}" for i in still)
    raise ModelError(f"{data.rec.path}: no motion on {joints}: parameters {', '.join(lost)} are not "
                     "identifiable (record the joints moving, e.g. with a multi-sine reference)")
