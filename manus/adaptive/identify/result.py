"""The fitted result of identification (`Fit`), and the fit of a model on every prepared row
(`fit_rows`: the least-squares core's `solve` on the model's columns, IV with instruments).

The least-squares solution names redundant parameters (a column that the earlier ones already
explain) instead of failing, and reports each parameter's standard deviation from a
heteroscedasticity- and autocorrelation-consistent (Newey–West) covariance. A serial chain from a
URDF (`structure: urdf`) is fitted in its base parameters (`manus.plants.serial.SerialBase`),
and the report writes each one out (`base_parameters`). `check_rows` and `check_motion` refuse a
recording that cannot identify a model, naming what it lacks.
"""

from __future__ import annotations

from dataclasses import dataclass, field

import numpy as np

from manus.adaptive.identify import lsq
from manus.adaptive.identify.columns import Columns
from manus.adaptive.identify.prepare import MIN_ROWS, Data, prepare
from manus.adaptive.identify.search import delay_of
from manus.estimators.offline import edge
from manus.plants.effects import Model
from manus.plants.errors import ModelError
from manus.plants.recording import Recording
from manus.plants.serial import SerialBase


@dataclass(repr=False)
class Fit:
    """A model's parameters identified from a prepared recording, with what its report needs."""

    model: Model  # with its non-linear parameters as found
    names: list[str]
    theta: np.ndarray
    std: np.ndarray
    redundant: list[str]
    rel_error: float
    residual: np.ndarray  # (rows, n)
    data: Data
    delay: float | np.ndarray  # the command delay the model assumes [s] (`delay_of`)
    search: dict = field(default_factory=dict)  # the search curves: name -> (grid values, rel_errors)
    method: str = "ls"  # "ls" or "iv"
    why: str = ""  # why that method
    instruments: Columns | None = None  # the IV instruments' columns (method "iv")
    # a serial chain's physically consistent stage (`manus.adaptive.identify.consistency.physical`):
    # the estimate these parameters were moved from where it broke physics (None: they are the estimate),
    # and the stage's report (or why it has none)
    unconstrained: Fit | None = None
    consistency: dict | None = None

    def __repr__(self) -> str:
        """One line (its arrays are for code; `report()` holds the numbers)."""
        return (
            f"<Fit {self.model.spec}: rel_error {100 * self.rel_error:.2f} % ({self.method}), "
            f"{len(self.names)} parameters>"
        )

    @property
    def params(self) -> dict[str, float]:
        """Parameter name -> value."""
        return dict(zip(self.names, self.theta.tolist(), strict=True))

    @property
    def stds(self) -> dict[str, float]:
        """Parameter name -> standard deviation (nan where redundant or held)."""
        return dict(zip(self.names, self.std.tolist(), strict=True))

    @property
    def rel_error_per_joint(self) -> list[float | None]:
        """`rel_error` per joint, in joint order: ‖τ_j − τ̂_j‖ / ‖τ_j‖ over the same rows (None for a
        joint without torque on them: a passive joint)."""
        denom = np.linalg.norm(self.data.tau(self.delay), axis=0)
        num = np.linalg.norm(self.residual, axis=0)
        return [float(r / d) if d > 0 else None for r, d in zip(num, denom, strict=True)]

    def predicted(self) -> np.ndarray:
        """The model's torque on the used rows (filtered like the recorded one)."""
        return self.data.tau(self.delay) - self.residual

    def violations(self) -> list[str]:
        """The physical rules the estimate breaks: each effect's own (beyond two standard deviations);
        on a serial chain in base parameters, H(q) positive definite on the recording's states (sampled;
        random configurations besides) and each armature that is a base parameter of its own
        non-negative (beyond two standard deviations). Where the consistent stage moved the estimate
        (`unconstrained`), the rules that estimate breaks, those within two standard deviations of
        their bound and the pseudo-inertias' included (`consistency["breaks"]`): these parameters
        keep them all."""
        if self.unconstrained is not None:  # and the rules the consistent stage found it breaking, strictly
            out = self.unconstrained.violations()
            breaks = (self.consistency or {}).get("breaks", [])
            return out + [b for b in breaks if not any(v.startswith(b.split(" = ")[0] + " = ") for v in out)]
        s, params, stds = self.model.structure, self.params, self.stds
        out = []
        for e in self.model.effects:
            if not (e.inertial and isinstance(s, SerialBase)):
                out += e.violations(s, params, stds)
                continue
            out += s.violations(params, self._states(s.CHECK_STATES)) or s.violations(params)
            for k in s.armatures:
                sd = stds[k] if np.isfinite(stds[k]) else 0.0
                if params[k] + 2 * sd < 0:
                    out.append(f"{k} = {params[k]:.4g} ± {sd:.2g} < 0: an armature (a rotor's inertia) is non-negative")
        if len(out) > 1 and not self.model.violations({k: -v for k, v in self.params.items()}, self.stds):
            out.append(
                "every rule holds with the torque's sign reversed: the recorded torque is probably "
                "positive against the positions' direction (record it positive where it drives q up)"
            )
        return out

    def _states(self, count: int) -> np.ndarray:
        """`count` of the recording's configurations, evenly over its used rows (some twice when fewer)."""
        at = self.data.rows if self.data.rows.size else np.arange(len(self.data.q))
        return self.data.q[at[np.linspace(0, at.size - 1, count).round().astype(int)]]

    def consistency_report(self) -> dict:
        """The `consistency` block of the JSON (serial chains): whether the parameters reported were
        `moved` from the estimate to the closest physically consistent ones, the estimate's torque
        error (`ls_rel_error`: least squares', or IV's where the method is iv) beside theirs
        (`rel_error`), and each parameter's move in the estimate's standard deviations; or, where
        there is no stage, why (`error`). Empty where the stage does not apply."""
        c = self.consistency
        if c is None:
            return {}
        if "error" in c:
            return {"error": c["error"]}
        keys = ("moved", "already", "ls_rel_error", "rel_error", "moved_std", "status")
        return {k: c[k] for k in keys}

    def report(self) -> dict:
        """The JSON contract of `manus fit` (docs/cli.md)."""
        units = self.model.units(self.data.rec.prismatic)
        params = {
            k: {"value": float(v), "std": None if not np.isfinite(s) else float(s), "unit": units.get(k, "")}
            for k, v, s in zip(self.names, self.theta, self.std, strict=True)
        }
        nonlinear = {k: v for e in self.model.effects for k, v in e.describe().items()}
        out = {
            "model": self.model.effect_names,
            "spec": self.model.spec,
            "params": params,
            "rel_error": self.rel_error,
            "rel_error_per_joint": self.rel_error_per_joint,
            "samples": int(self.data.rows.size),
            "cutoff_hz": self.data.cutoff_hz,
            "cutoff_note": self.data.cutoff_note,
            "standstill_excluded": self.data.standstill,
            "hold": self.data.hold,
            "method": self.method,
            "method_why": self.why,
        }
        if nonlinear:
            out["nonlinear"] = nonlinear
        if self.data.lost:
            out["gaps"] = self.data.lost
        combos = self.model.structure.combinations
        if combos is not None:  # a serial chain: what each base parameter is, and its value in the URDF
            s = self.model.structure
            out["base_parameters"] = dict(zip(s.rigid_names, combos, strict=True))
            out["urdf_values"] = {k: float(v) for k, v in zip(s.rigid_names, s.rigid_defaults, strict=True)}
        if self.redundant:
            out["redundant"] = self.redundant
        bad = self.violations()
        if bad:
            out["violations"] = bad
        if self.consistency is not None:
            out["consistency"] = self.consistency_report()
        return out

    def evaluate(self, rec: Recording | Data) -> Fit:
        """These parameters, unchanged, applied to another recording (validation: the EMPS
        reference's 5.98 % on the PULSES file). The recording is prepared at this fit's cut-off
        (the band the parameters were identified in); the result is a `Fit` whose `residual`,
        `rel_error` and `data` are the other recording's, with `theta`/`std` as identified here."""
        data = rec if isinstance(rec, Data) else prepare(rec, self.data.cutoff_hz)
        if data.n_joints != self.model.n_joints:
            raise ModelError(
                f"{data.rec.path}: the fitted model has {self.model.n_joints} joints, the recording {data.n_joints}"
            )
        if data.rec.structure_name != self.data.rec.structure_name:
            raise ModelError(
                f"{data.rec.path}: structure {data.rec.structure_name!r}, but the model was fitted on "
                f"a {self.data.rec.structure_name!r} recording"
            )
        check_rows(data, self.model)
        tau = data.tau(self.delay)
        resid = tau - Columns(data).model(self.model) @ self.theta
        denom = np.linalg.norm(tau)
        rel = float(np.linalg.norm(resid) / denom) if denom else np.inf
        return Fit(
            self.model,
            list(self.names),
            self.theta,
            self.std,
            list(self.redundant),
            rel,
            resid,
            data,
            self.delay,
            {},
            self.method,
            self.why,
        )

    def rel_error_on(self, rec: Recording | Data) -> float:
        """`rel_error` of these parameters on another recording (see `evaluate`)."""
        return self.evaluate(rec).rel_error


def fit_rows(
    data: Data, cols: Columns, model: Model, search: dict | None = None, icols: Columns | None = None, held: tuple = ()
) -> Fit:
    """The fit of `model` (its non-linear parameters as they are) on every used row of `data`,
    its columns from `cols`: least squares, or instrumental variables with the instruments'
    columns `icols`. Parameters named in `held` are held at 0 (their bound). `search`: the
    search curves that found the model's values, kept in the result."""
    delay = delay_of(model)
    names = list(model.names)
    out = [j for j, k in enumerate(names) if k in held]
    Y = cols.model(model)
    Z = None if icols is None else icols.model(model)
    if out:
        Y = np.delete(Y, out, axis=2)
        Z = None if Z is None else np.delete(Z, out, axis=2)
    sol = lsq.solve(Y, data.tau(delay), Z)
    kept = [k for k in names if k not in held]
    theta, std = np.zeros(len(names)), np.full(len(names), np.nan)
    idx = [names.index(k) for k in kept]
    theta[idx], std[idx] = sol.theta, sol.std
    return Fit(
        model,
        names,
        theta,
        std,
        [kept[j] for j in sol.redundant],
        sol.rel_error,
        sol.residual,
        data,
        delay,
        {} if search is None else search,
        "ls" if icols is None else "iv",
        "",
        icols,
    )


def check_rows(data: Data, model: Model) -> None:
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
        lost = [names[j] for j in lsq.unidentifiable(Y)]
    else:
        lost = names
    rec = data.rec
    why = (
        f"{len(rec)} samples ({len(rec) * data.dt:.3g} s) leave {data.rows.size} usable rows "
        f"(at least {MIN_ROWS} needed) once the filter's start-up ({edge(data.dt, data.cutoff_hz)} samples at "
        f"each end, {data.cutoff_hz:.3g} Hz cut-off) and standstill are left out"
    )
    what = (
        f"parameters {', '.join(lost)} are not identifiable (the regressor has rank {len(names) - len(lost)} "
        f"of {len(names)})"
        if lost
        else "too few rows to identify the parameters reliably"
    )
    raise ModelError(
        f"{rec.path}: recording too short or without motion: {why}; {what}; record longer, "
        "with the joints moving (e.g. a multi-sine reference)"
    )


def check_motion(data: Data, model: Model) -> None:
    """A joint that does not move identifies none of its velocity- or inertia-driven terms."""
    still = [i for i, f in enumerate(data.moving()) if f < 0.02]
    if not still:
        return
    lost = [
        k
        for e in model.effects
        if e.evidence in ("velocity", "acceleration")
        for k in e.names(model.structure)
        if any(k.endswith(str(i + 1)) for i in still) or (e.inertial and model.n_joints == 2)
    ]
    joints = ", ".join(f"joint {i + 1}" for i in still)
    raise ModelError(
        f"{data.rec.path}: no motion on {joints}: parameters {', '.join(lost)} are not "
        "identifiable (record the joints moving, e.g. a multi-sine reference)"
    )
