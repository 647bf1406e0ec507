"""Inverse-dynamics identification of a model from a recording (`manus fit`).

The recording is prepared once (`manus.adaptive.identify.prepare`: band, kinematics, rows), the
model's regressor is the stack of its effects' columns (`manus.adaptive.identify.columns`),
non-linear parameters (the cogging order, the Stribeck velocity, the delay) are found by search
over the space each effect derives from the recording (`manus.adaptive.identify.search`) when
the model does not fix them, and the linear ones by the least-squares core
(`manus.adaptive.identify.lsq`, `result.fit_rows`).

Two estimators share that core: inverse-dynamics least squares (IDIM-LS) and instrumental
variables (IDIM-IV, Janot, Gautier et al.: instruments are the regressor evaluated on the motion
simulated by the current model from the recorded command, `manus.adaptive.identify.instruments`,
iterated). `method="auto"` fits both and keeps IV where the two disagree beyond their standard
deviations (noise in the differentiated regressor has biased least squares), LS otherwise; the
report says which and why. A third, output error (OE, `manus.adaptive.identify.output_error`), fits
the positions simulated from the recorded command instead of the torque: `auto` chooses it where
the encoder's quantization noise in q̈ makes up a large share of what identifies the inertia
(coarse encoders, low rates, chatter), or where LS breaks physics, IV does not rescue it and that
noise is notable.

On a serial chain the fit returned is physically consistent (`manus.adaptive.identify.consistency`):
where the estimate breaks physics (a link's pseudo-inertia not PSD, a negative armature or
friction), the closest consistent parameters in the data's metric, the estimate kept beside them
(`Fit.unconstrained`); IV's instruments are simulated from that consistent model.
"""

from __future__ import annotations

import math
import re
import warnings
from collections.abc import Iterator
from dataclasses import replace

import numpy as np

from manus.adaptive.identify.columns import Columns, identified
from manus.adaptive.identify.consistency import physical
from manus.adaptive.identify.instruments import iv_fit
from manus.adaptive.identify.output_error import oe_reason, output_error, quantization, rescue
from manus.adaptive.identify.prepare import Data, prepare
from manus.adaptive.identify.result import Fit, check_motion, check_rows, fit_rows
from manus.adaptive.identify.search import search_all
from manus.plants.effects import Model
from manus.plants.errors import ManusError, ModelError, RecordingNote
from manus.plants.recording import Recording
from manus.plants.serial import SerialBase

METHODS = ("auto", "ls", "iv", "oe")


def model_from(model: Model | str, structure) -> tuple[Model, set[str]]:
    """The model in the form identification fits (`identified`: a serial chain's base
    parameters), and the names of the effects whose non-linear parameters it fixes: a model given
    as text fixes those written with an argument (cogging:39), a `Model` none."""
    if isinstance(model, Model):
        s = identified(model.structure)
        return (model if s is model.structure else Model(s, model.effects)), set()
    fixed = {t.split(":")[0].strip().lower() for t in model.split(",") if ":" in t}
    return Model(identified(structure), model), fixed


def fit(
    rec: Recording | Data,
    model: Model | str,
    cutoff_hz: float | None = None,
    fixed: set[str] | None = None,
    columns: Columns | None = None,
    method: str = "auto",
    readings: bool | None = None,
) -> Fit:
    """Identify `model`'s parameters from `rec`. Non-linear parameters of effects not in
    `fixed` are searched (a model given as text fixes those written with an argument).
    `method`: "ls" (IDIM-LS), "iv" (IDIM-IV), "oe" (output error) or "auto" (IV or OE where LS
    is biased, see the module docstring). `columns`: the columns of this data computed already (a
    loop over one recording). `readings`: where least squares fits poorly, try the other ways the
    recording may have been meant and note one that fits far better (`other_readings`); by default
    on a fit on its own (no `columns`), the first of a command's."""
    if method not in METHODS:
        raise ModelError(f"unknown method {method!r}: expected one of {', '.join(METHODS)}")
    data = rec if isinstance(rec, Data) else prepare(rec, cutoff_hz)
    model, fixed_text = model_from(model, data.rec.structure)
    fixed = fixed_text | (fixed or set())
    if model.n_joints != data.n_joints:
        raise ModelError(f"the model has {model.n_joints} joints, the recording {data.n_joints}")
    for e in model.effects:
        if e.modal:
            raise ModelError(
                f"{e.name} is a structural mode above the identification bandwidth: "
                "`manus diagnose` detects it from the spectrum; it has no inverse-dynamics columns"
            )
        given = e.unresolved(data.span().of(e)) if e.name in fixed else None
        why = e.applies(model.structure, data.rec.prismatic) or given
        if why:
            raise ModelError(why if why.startswith(e.spec) else f"{e.name}: {why}")
    if not np.any(data.rec.tau):
        raise ModelError(
            f"{data.rec.path}: the recorded torque is zero throughout: no model of it can be identified "
            "(is the torque column filled?)"
        )
    cols = columns or Columns(data)
    check_rows(data, model)
    check_motion(data, model)
    model, search = search_all(data, cols, model, fixed)
    ls = fit_rows(data, cols, model, search)
    if columns is None if readings is None else readings:
        other_readings(data, model, ls)
        urdf_scale(ls)
    start = physical(ls, cols)  # IV's simulations start from a consistent model
    if method == "ls":
        return replace(start, why="least squares (asked for)")
    noise = quantization(data, cols, ls) if method in ("auto", "oe") else None  # errors in variables
    oe_why = "output error (asked for)" if method == "oe" else oe_reason(data, ls, noise) if noise else ""
    if oe_why:
        return output_error(data, cols, ls, oe_why, start, noise)
    chosen = iv_fit(data, cols, ls, method, start)
    if chosen.method == "ls":  # least squares kept: its stage is done
        return rescue(data, cols, ls, replace(start, why=chosen.why), noise)
    return physical(chosen, cols)


POOR_FIT = 0.1  # a least-squares error from which the recording's other readings are tried
NOTHING_FIT = 0.5  # ... and from which its angles are read in degrees (a model that explains next to nothing)
OTHER_STRUCTURE = {"manus2": "axis", "axis": "manus2"}  # the structures of two joints: each the other's reading
DEGREES = math.pi / 180  # radians per degree


def other_readings(data: Data, model: Model, ls: Fit) -> None:
    """Where least squares leaves `POOR_FIT` of the torque or more, the same model fitted to the
    recording read the other ways it may have been meant. A reading that leaves under half the
    error contradicts the recording as read, and a note says so:

    - two revolute joints in the other structure two joints can have (the thesis's arm in
      absolute angles, or two independent axes): the structure stated, or the default for two
      joints, is contradicted;
    - a serial chain's (a URDF's) revolute angles in degrees, where the model explains next to
      nothing (`NOTHING_FIT`). A log in degrees printed to a few places lies on no encoder grid
      that `read` could check, and a chain's gravity and couplings, sines and cosines of its
      angles, then fit nothing. Elsewhere, reading the angles 57 times smaller changes the model's
      function more than it tests the unit: on the thesis's planar arm, without gravity, the sines
      become linear in the angles, and a recording in radians whose model left most of the torque
      (a shaft mode ringing) fitted better read that way.
    """
    if not ls.rel_error >= POOR_FIT:
        return
    rec = data.rec
    for alt, said, hint in _readings(rec, ls.rel_error):
        try:
            alt_data = prepare(alt, data.cutoff_hz)
            alt_ls = fit_rows(alt_data, Columns(alt_data), Model(identified(alt.structure), model.spec), None)
        except (ManusError, ValueError, np.linalg.LinAlgError):  # (a reading that cannot be fitted contradicts nothing)
            continue
        if alt_ls.rel_error < 0.5 * ls.rel_error:
            warnings.warn(
                f"{rec.path}: {said}: {model.spec} leaves {100 * alt_ls.rel_error:.3g} % of the torque, "
                f"against {100 * ls.rel_error:.3g} % as read ({hint})",
                RecordingNote,
                stacklevel=3,
            )


URDF_SCALE = 5.0  # a chain's gravity moments identified this many times its URDF's (or 1/this), all alike
TORQUE_UNITS = ((1e3, "mN·m (mN)"), (1e2, "N·cm"), (1e-3, "kN·m (kN)"))  # (scale, the unit it suggests)


def urdf_scale(ls: Fit) -> None:
    """A serial chain's torque in another unit than N·m (N on a prismatic joint): least squares
    fits a scaled torque as well as the true one, with every parameter scaled alike. The chain's
    gravity moments (the base parameters m·x, m·y, m·z, which gravity identifies well) are
    compared with its URDF's; where those identified within 10 % of their value (at least 2, each
    a tenth or more of the URDF's largest) are all `URDF_SCALE` times the URDF's or more (or as
    many times less), within a factor of 3 of each other, a note names the scale and the unit it
    suggests."""
    s = ls.model.structure
    if not isinstance(s, SerialBase):
        return
    urdf = dict(zip(s.rigid_names, s.rigid_defaults, strict=True))
    params, stds = ls.params, ls.stds
    moments = [k for k in urdf if re.fullmatch(r"m[xyz]\d+R?", k) and k in params]
    largest = max((abs(urdf[k]) for k in moments), default=0.0)
    known = [
        k
        for k in moments
        if abs(urdf[k]) >= 0.1 * largest > 0 and np.isfinite(stds[k]) and stds[k] < 0.1 * abs(params[k])
    ]
    ratio = np.array([params[k] / urdf[k] for k in known])
    if ratio.size < 2 or np.any(ratio <= 0):
        return  # (too few to tell, or signs that no one scale explains)
    logs = np.log10(ratio)
    scale = float(10 ** np.median(logs))
    if 1 / URDF_SCALE < scale < URDF_SCALE or np.ptp(logs) > np.log10(3.0):
        return
    unit = next((u for f, u in TORQUE_UNITS if abs(np.log10(scale / f)) < 0.15), None)
    warnings.warn(
        f"{ls.data.rec.path}: the chain's gravity moments are identified {scale:.3g} times its URDF's "
        f"({len(known)} of them, each within 10 %: {', '.join(known[:4])}{', ...' if len(known) > 4 else ''}): "
        + (f"the torque in {unit}? " if unit else "a torque not converted to N·m (a gear ratio, a torque constant)? ")
        + "manus reads N·m (N on a prismatic joint), or the URDF's masses are not the robot's",
        RecordingNote,
        stacklevel=3,
    )


def _readings(rec: Recording, rel_error: float) -> Iterator[tuple[Recording, str, str]]:
    """(the recording read another way, what the note says of it, what to do) for each reading
    `other_readings` tries on `rec`, fitted as read to `rel_error`."""
    revolute = ~np.asarray(rec.prismatic, bool)
    if rec.structure_name == "urdf" and revolute.any() and rel_error >= NOTHING_FIT:
        scale = np.where(revolute, DEGREES, 1.0)
        yield (
            replace(rec, q=rec.q * scale, qd=None if rec.qd is None else rec.qd * scale),
            "the angles look like degrees: read in degrees",
            "manus reads radians: convert them",
        )
    other = OTHER_STRUCTURE.get(rec.structure_name)
    if other is None or rec.n_joints != 2 or any(rec.prismatic) or "transmission" in rec.meta:
        return  # (a prismatic axis is no arm's joint; a stated transmission is a structure of its own)
    said = (
        "`structure: " + rec.structure_name + "`"
        if "structure" in rec.meta
        else f"{rec.structure_name} (the default for two joints)"
    )
    yield (
        replace(rec, meta={**rec.meta, "structure": other}),
        f"the data contradict {said}: read as {other}",
        f"state the rig's structure: `# structure: {other}`",
    )
