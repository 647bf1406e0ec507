"""Physically consistent parameters of a serial chain's fit: the fit a user gets where the
estimate breaks physics (`physical`, the last stage of `manus.adaptive.identify.fit`).

Inverse-dynamics identification estimates the base parameters β = K φ (`SerialBase`), and noise,
unmodelled effects or poor excitation can leave an estimate that no rigid bodies produce. A set of
standard parameters φ is physically consistent when each link's pseudo-inertia

    J = [[½ tr(I) 𝟙 − I, h], [hᵀ, m]]   (I about the link frame's origin, h = m c)

is positive semidefinite (Wensing, Kim and Slotine 2017: a mass density on the link exists with
these moments; m ≥ 0 and the triangle inequalities follow), each armature is non-negative, and the
other effects keep their own physical bounds (b ≥ 0, Fc ≥ 0, ...: each effect's `lower_bounds`).

`consistent(fit)` first asks whether the estimate itself is consistent: whether standard parameters
with every pseudo-inertia PSD and armatures ≥ 0 give its base parameters exactly, its other
parameters within their bounds. If not, it finds the consistent parameters closest to the fit in
the data's own metric, (x − x̂)ᵀ YᵀY (x − x̂) over every parameter x of the model (the rise of the
squared torque error, for least squares exactly), with the pseudo-inertias as linear matrix
inequalities (Sousa and Cortesão 2014): each link's J, linear in its ten standard parameters, in
the PSD cone; a convex quadratic problem over a few dozen variables, solved by the conic
interior-point solver Clarabel (the `consistency` extra) in milliseconds. The standard parameters
that no base parameter holds are held near the URDF's own: such a combination 100 % away from its
URDF value costs `TIE` (1e-2) squared standard deviations of the fit, the combinations the base
parameters hold `WEAK` (1e-4) times that; so the data decide the base parameters and the URDF
the rest (without it, a link's mass, which no base parameter holds, drifts to millions of kilograms to make room).

`physical(fit)` is the fit a user gets: the estimate itself where it is consistent (unchanged, bit
for bit), else the consistent parameters with their torque error, the estimate kept beside them
(`Fit.unconstrained`: its error, and the rules it breaks, are reported too). A structure other than
a serial chain, a model without `rigid`, or a machine without the extra (said in one line) keep
the estimate.
"""

from __future__ import annotations

from dataclasses import dataclass, field, replace

import numpy as np

from manus.adaptive.identify.columns import Columns
from manus.adaptive.identify.result import Fit
from manus.plants.errors import ManusError, ModelError, require
from manus.plants.serial import SerialBase

TIE = 1e-2  # cost of a standard parameter 100 % away from the URDF's, in squared standard deviations of the fit
WEAK = 1e-4  # the tie's weight, relative, on the standard parameters' combinations that base parameters hold
LINK = 10  # standard parameters per link: m, mx, my, mz, Ixx, Ixy, Ixz, Iyy, Iyz, Izz
OK = ("optimal", "optimal_inaccurate")


def pseudo_inertia(p) -> np.ndarray:
    """The 4x4 pseudo-inertia of one link's 10 standard parameters."""
    m, mx, my, mz, ixx, ixy, ixz, iyy, iyz, izz = (float(p[k]) for k in range(LINK))
    half = 0.5 * (ixx + iyy + izz)
    rows = [[half - ixx, -ixy, -ixz, mx], [-ixy, half - iyy, -iyz, my], [-ixz, -iyz, half - izz, mz], [mx, my, mz, m]]
    return np.array(rows, float)


def _triangle() -> np.ndarray:
    """T (10, 10): a link's pseudo-inertia as Clarabel's PSD-triangle vector (the upper triangle
    column by column, off-diagonal entries times √2) of its ten standard parameters."""
    T = np.zeros((LINK, LINK))
    for k in range(LINK):
        J = pseudo_inertia(np.eye(LINK)[k])
        T[:, k] = [J[i, j] * (1.0 if i == j else np.sqrt(2)) for j in range(4) for i in range(j + 1)]
    return T


def _solve(clarabel, P: np.ndarray, q: np.ndarray, blocks: list) -> tuple[str, np.ndarray | None]:
    """min ½ zᵀPz + qᵀz subject to A z + s = b, s in each block's cone (`blocks`: (A, b, cone)), by
    Clarabel, the variables scaled so that P's diagonal is 1: (status, z or None)."""
    from scipy import sparse

    d = np.diag(P)
    d = np.where(d > 0, 1 / np.sqrt(np.where(d > 0, d, 1.0)), 1.0)
    A = np.concatenate([a for a, _, _ in blocks]) * d
    b = np.concatenate([b for _, b, _ in blocks])
    settings = clarabel.DefaultSettings()
    settings.verbose = False
    solver = clarabel.DefaultSolver(
        sparse.csc_matrix(np.triu(P * np.outer(d, d))),
        q * d,
        sparse.csc_matrix(A),
        b,
        [c for *_, c in blocks],
        settings,
    )
    sol = solver.solve()
    status = {"Solved": "optimal", "AlmostSolved": "optimal_inaccurate"}.get(str(sol.status), str(sol.status))
    return status, (d * np.asarray(sol.x)) if status in OK else None


def _tie(K: np.ndarray, prior: np.ndarray) -> np.ndarray:
    """Q (P, P): (φ − φ₀)ᵀ Q (φ − φ₀) is the squared distance of standard parameters φ from the
    URDF's φ₀, each relative to its URDF value (1e-3 at least), on the combinations that no base
    parameter holds (the null space of K in those relative units); on the others `WEAK` times
    that (a base parameter the recording leaves undetermined stays near the URDF's, one it
    determines is the data's: an armature the URDF puts at 0 is not pulled there)."""
    D = np.maximum(np.abs(prior), 1e-3)
    _, sv, Vt = np.linalg.svd(K * D)
    rank = int(np.sum(sv > 1e-10 * sv.max()))
    null = Vt[rank:].T
    return (null @ null.T + WEAK * np.eye(len(D))) / np.outer(D, D)


@dataclass
class Consistency:
    """The physically consistent parameters closest to a fit (`consistent`)."""

    fit: Fit  # the estimate
    theta: np.ndarray  # every parameter of the model, consistent (the estimate's own where `already`)
    standard: np.ndarray  # the standard parameters (10 per link, then armatures) that give them
    already: bool  # the estimate itself is consistent: standard parameters give its rigid part, the rest in bounds
    rel_error: float  # the torque error of the consistent set on the fit's rows
    residual: np.ndarray  # (rows, n) its residual
    status: str
    breaks: list[str] = field(default_factory=list)  # the rules the estimate breaks, strictly (no std allowed)

    def report(self) -> dict:
        """The `consistent` block of `manus fit`'s JSON (serial chains): the estimate's error
        (`ls_rel_error`, also `rel_error_of_fit`) and the consistent set's (`rel_error`), whether
        the set `moved` from the estimate, each parameter's move in the estimate's standard
        deviations, each link's mass and its pseudo-inertia's smallest eigenvalue, the armatures."""
        f = self.fit
        names = f.names
        moved = {
            k: float((self.theta[j] - f.theta[j]) / f.std[j])
            for j, k in enumerate(names)
            if np.isfinite(f.std[j]) and f.std[j] > 0
        }
        s = f.model.structure
        assert isinstance(s, SerialBase)  # `consistent` is a serial chain's, in its base parameters
        serial = s.serial
        per_link = [self.standard[LINK * i : LINK * (i + 1)] for i in range(serial.n_joints)]
        links = [
            {"mass": float(p[0]), "min_eigenvalue": float(np.linalg.eigvalsh(pseudo_inertia(p))[0])} for p in per_link
        ]
        return {
            "already": self.already,
            "moved": not self.already,
            "status": self.status,
            "rel_error": self.rel_error,
            "ls_rel_error": f.rel_error,
            "rel_error_of_fit": f.rel_error,
            "params": dict(zip(names, self.theta.tolist(), strict=True)),
            "moved_std": {k: round(v, 3) for k, v in moved.items()},
            "links": links,
            "armature": self.standard[LINK * serial.n_joints :].tolist(),
            "breaks": self.breaks,
        }


def consistent(f: Fit, columns: Columns | None = None) -> Consistency:
    """The physically consistent parameters closest to the fit `f` of a serial chain (module
    docstring); `columns`: the columns of `f`'s data computed already. A `ModelError` for another
    structure, a model without `rigid`, or when the solver fails; a `ManusError` without the extra."""
    s = f.model.structure
    if not isinstance(s, SerialBase):  # the one structure whose rigid parameters are combinations
        raise ModelError(
            "physically consistent parameters are a serial chain's (structure urdf): "
            f"{type(s).__name__} has no standard inertial parameters"
        )
    if not f.model.has("rigid"):
        raise ModelError("physically consistent parameters are a rigid model's: the model has no 'rigid' effect")
    clarabel = require("clarabel", "consistency")
    serial, K = s.serial, np.asarray(s.K, float)
    n = serial.n_joints
    names = f.names
    rigid = [names.index(k) for k in s.base_names]
    others = [j for j in range(len(names)) if j not in set(rigid)]
    lower = np.full(len(names), -np.inf)
    rules = {k: "an armature (a rotor's inertia) is non-negative" for k in s.armatures}  # each bound's meaning
    for e in f.model.effects:
        if e.linear and not e.inertial:
            for k, lb in zip(e.names(s), e.lower_bounds(s), strict=True):
                lower[names.index(k)] = lb
                rules[k] = f"{e.name} {e.rule}"
    bounded = np.flatnonzero(np.isfinite(lower))
    prior = np.asarray(serial.defaults, float)
    tie = _tie(K, prior)
    # the variables z = [φ (10 per link, then the armatures), the model's other parameters];
    # the model's parameters are x = E z, each link's pseudo-inertia T φᵢ in the PSD cone
    nphi, T = len(prior), _triangle()
    E = np.zeros((len(names), nphi + len(others)))
    E[rigid, :nphi] = K
    E[others, nphi + np.arange(len(others))] = 1.0

    def physics(width: int) -> list:
        """The cones of consistency on the first `width` variables (φ first)."""
        out = []
        for i in range(n):
            a = np.zeros((LINK, width))
            a[:, LINK * i : LINK * (i + 1)] = -T
            out.append((a, np.zeros(LINK), clarabel.PSDTriangleConeT(4)))
        a = np.zeros((n, width))
        a[:, LINK * n : nphi] = -np.eye(n)
        return [*out, (a, np.zeros(n), clarabel.NonnegativeConeT(n))]

    # the estimate's own parameters: do consistent standard parameters give its rigid ones, and
    # are the others (and the armatures of their own) within their bounds?
    status, phi = _solve(
        clarabel, 2 * tie, -2 * tie @ prior, [(K, f.theta[rigid], clarabel.ZeroConeT(len(rigid))), *physics(nphi)]
    )
    bound = {k: 0.0 for k in s.armatures} | {names[j]: float(lower[j]) for j in bounded}
    below = [k for k, lo in bound.items() if f.theta[names.index(k)] < lo]
    if phi is not None and not below:
        return Consistency(f, f.theta, phi, True, f.rel_error, f.residual, status)
    breaks = [
        f"{k} = {f.theta[names.index(k)]:.4g} ± {np.nan_to_num(f.std[names.index(k)]):.2g} < {bound[k]:g}: {rules[k]}"
        for k in below
    ]
    if phi is None:
        breaks.append(
            "no rigid bodies give the base parameters (no standard parameters with every link's pseudo-inertia "
            "positive semidefinite and the armatures non-negative have them)"
        )
    # the consistent parameters closest to the estimate in the data's metric (in units of the
    # residual's variance per row: one standard deviation of a parameter costs about 1), the
    # standard parameters the data leave free held near the URDF's
    cols = columns if columns is not None and columns.data is f.data else Columns(f.data)
    Y = cols.model(f.model)
    tau = f.data.tau(f.delay)
    Yf = Y.reshape(-1, Y.shape[2])
    dof = max(tau.size - len(names), 1)
    var = float(np.sum(f.residual**2)) / dof or 1.0
    G = E.T @ (Yf.T @ Yf) @ E / var
    G[:nphi, :nphi] += TIE * tie
    g = E.T @ (Yf.T @ (Yf @ f.theta)) / var
    g[:nphi] += TIE * tie @ prior
    width = E.shape[1]
    blocks = physics(width)
    if bounded.size:
        blocks.append((-E[bounded], -lower[bounded], clarabel.NonnegativeConeT(bounded.size)))
    status, z = _solve(clarabel, 2 * G, -2 * g, blocks)
    if z is None:
        raise ModelError(f"physically consistent parameters: the solver ended {status}")
    theta = E @ z
    residual = tau - Y @ theta
    rel = float(np.linalg.norm(residual) / (np.linalg.norm(tau) or 1.0))
    return Consistency(f, theta, z[:nphi], False, rel, residual, status, breaks)


def physical(f: Fit, columns: Columns | None = None) -> Fit:
    """The fit a user gets (module docstring): `f` itself where it is consistent or where the
    stage does not apply, else the consistent parameters, with `f` as `unconstrained`; the stage's
    report (or why it has none) in `consistency`."""
    s = f.model.structure
    if not isinstance(s, SerialBase) or not f.model.has("rigid"):
        return f
    try:
        c = consistent(f, columns)
    except ManusError as e:  # the extra missing, or the solver failed: the estimate stands, and says why
        return replace(f, consistency={"error": f"no physically consistent stage ({e}); the estimate kept"})
    if c.already:
        return replace(f, consistency=c.report())
    return replace(
        f, theta=c.theta, residual=c.residual, rel_error=c.rel_error, unconstrained=f, consistency=c.report()
    )
