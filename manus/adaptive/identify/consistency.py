"""Physically consistent parameters of a serial chain's fit: a separate, reported stage.

Inverse-dynamics identification estimates the base parameters β = K φ (`SerialBase`), and noise,
unmodelled effects or poor excitation can leave an estimate that no rigid bodies produce. A set of
standard parameters φ is physically consistent when each link's pseudo-inertia

    J = [[½ tr(I) 𝟙 − I, h], [hᵀ, m]]   (I about the link frame's origin, h = m c)

is positive semidefinite (Wensing, Kim and Slotine 2017: a mass density on the link exists with
these moments; m ≥ 0 and the triangle inequalities follow), each armature is non-negative, and the
other effects keep their own physical bounds (b ≥ 0, Fc ≥ 0, ...: each effect's `lower_bounds`).

`consistent(fit)` finds the consistent parameters closest to the fit in the data's own metric,
(x − x̂)ᵀ YᵀY (x − x̂) over every parameter x of the model (the rise of the squared torque
error, for least squares exactly), with the pseudo-inertias as linear matrix inequalities (Sousa
and Cortesão 2014), a convex problem solved by Clarabel through cvxpy. The standard parameters that
the data do not determine are held near the URDF's own: a standard parameter 100 % away from its
URDF value costs `TIE` (1e-2) squared standard deviations of the fit, so the data decide the base
parameters (a pull of at most about a tenth of a standard deviation) and the URDF the rest (without
it, a link's mass, which no base parameter holds, drifts to millions of kilograms to make room). It reports
whether the estimate was consistent already, how far each parameter moved (in standard
deviations), and the torque error the consistent set leaves.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from manus.adaptive.identify.columns import Columns
from manus.adaptive.identify.result import Fit
from manus.plants.errors import ModelError, require
from manus.plants.serial import SerialBase

TIE = 1e-2  # cost of a standard parameter 100 % away from the URDF's, in squared standard deviations of the fit
LINK = 10  # standard parameters per link: m, mx, my, mz, Ixx, Ixy, Ixz, Iyy, Iyz, Izz


def pseudo_inertia(p) -> np.ndarray | list:
    """The 4x4 pseudo-inertia of one link's 10 standard parameters (numpy, or cvxpy expressions
    when `p` is a cvxpy vector: then a list of rows for `cvxpy.bmat`)."""
    m, mx, my, mz, ixx, ixy, ixz, iyy, iyz, izz = (p[k] for k in range(LINK))
    half = 0.5 * (ixx + iyy + izz)
    rows = [[half - ixx, -ixy, -ixz, mx], [-ixy, half - iyy, -iyz, my], [-ixz, -iyz, half - izz, mz], [mx, my, mz, m]]
    return np.array(rows, float) if isinstance(p, np.ndarray) else rows


@dataclass
class Consistency:
    """The physically consistent parameters closest to a fit (`consistent`)."""

    fit: Fit
    theta: np.ndarray  # every parameter of the model, consistent
    standard: np.ndarray  # the standard parameters (10 per link, then armatures) that give them
    already: bool  # the estimate itself is consistent: standard parameters give its rigid part, the rest in bounds
    rel_error: float  # the torque error of the consistent set on the fit's rows
    status: str

    def report(self) -> dict:
        """The `consistent` block of `manus fit`'s JSON (serial chains)."""
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
            "status": self.status,
            "rel_error": self.rel_error,
            "rel_error_of_fit": f.rel_error,
            "params": dict(zip(names, self.theta.tolist(), strict=True)),
            "moved_std": {k: round(v, 3) for k, v in moved.items()},
            "links": links,
            "armature": self.standard[LINK * serial.n_joints :].tolist(),
        }


def consistent(f: Fit) -> Consistency:
    """The physically consistent parameters closest to the fit `f` of a serial chain (module
    docstring). A `ModelError` for another structure, or when the solver fails."""
    cp = require("cvxpy", "consistency")

    s = f.model.structure
    if not isinstance(s, SerialBase):  # the one structure whose rigid parameters are combinations
        raise ModelError(
            "physically consistent parameters are a serial chain's (structure urdf): "
            f"{type(s).__name__} has no standard inertial parameters"
        )
    serial, K = s.serial, np.asarray(s.K, float)
    n = serial.n_joints
    names = f.names
    rigid = [names.index(k) for k in s.base_names]
    Y = Columns(f.data).model(f.model)
    Y = Y.reshape(-1, Y.shape[2])
    tau = f.data.tau(f.delay).reshape(-1)
    G = Y.T @ Y
    scale = np.sqrt(np.maximum(np.diag(G), 1e-300))
    w, V = np.linalg.eigh(G / np.outer(scale, scale))
    R = (V * np.sqrt(np.clip(w, 0, None))).T  # RᵀR = the scaled Gram matrix
    lower = np.full(len(names), -np.inf)
    for e in f.model.effects:
        if e.linear and e.name != "rigid":
            for k, lb in zip(e.names(s), e.lower_bounds(s), strict=True):
                lower[names.index(k)] = lb

    prior = np.asarray(serial.defaults, float)
    pscale = np.maximum(np.abs(prior), 1e-3)

    def problem(extra):
        """(x, φ, the constraints of consistency plus `extra`(x, φ))."""
        x, phi = cp.Variable(len(names)), cp.Variable(len(prior))
        cons = [x[rigid] == K @ phi, phi[LINK * n :] >= 0]
        cons += [cp.bmat(pseudo_inertia(phi[LINK * i : LINK * (i + 1)])) >> 0 for i in range(n)]
        bounded = np.flatnonzero(np.isfinite(lower))
        if bounded.size:
            cons.append(x[bounded] >= lower[bounded])
        return x, phi, cons + extra(x, phi)

    def data_term(x):
        return cp.sum_squares(R @ cp.multiply(scale, x - f.theta))

    def tie(phi):
        return cp.sum_squares(cp.multiply(1 / pscale, phi - prior))

    def run(objective, x, phi, cons):
        prob = cp.Problem(cp.Minimize(objective), cons)
        try:
            prob.solve(solver=cp.CLARABEL)
        except cp.error.SolverError as e:
            return f"solver error: {e}", None
        return prob.status, prob.value

    ok = ("optimal", "optimal_inaccurate")
    # the estimate's own rigid part: do consistent standard parameters give it?
    x, phi, cons = problem(lambda x, phi: [x[rigid] == f.theta[rigid]])
    bounded = np.isfinite(lower)
    already = bool(np.all(f.theta[bounded] >= lower[bounded])) and run(tie(phi), x, phi, cons)[0] in ok
    # the consistent parameters closest to the estimate in the data's metric (in units of the
    # residual's variance per row: one standard deviation of a parameter costs about 1), the
    # standard parameters the data leave free held near the URDF's
    dof = max(tau.size - len(names), 1)
    var = float(np.sum(f.residual**2)) / dof or 1.0
    x, phi, cons = problem(lambda x, phi: [])
    status, _ = run(data_term(x) / var + TIE * tie(phi), x, phi, cons)
    if status not in ok or x.value is None:
        raise ModelError(f"physically consistent parameters: the solver ended {status}")
    x, phi = x.value, phi.value
    residual = tau - Y @ x
    rel = float(np.linalg.norm(residual) / (np.linalg.norm(tau) or 1.0))
    return Consistency(f, np.asarray(x, float), np.asarray(phi, float), already, rel, status)
