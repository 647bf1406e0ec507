"""`manus demo` (what `make demo` runs): the model-vs-measurement story, twice.

(a) The MANUS-2 arm is simulated under impedance control with effects the analysis is not told
    about (the thesis's plant plus 39/rev cogging: `rigid,viscous,coulomb,delay,cogging:39`).
    Starting from the thesis's nominal model (`rigid,viscous,coulomb`), `discover` diagnoses,
    adds the missing effect, refits, until nothing significant is missing.
(b) The same loop on the real EMPS recording (../shared/data/emps/DATA_EMPS.mat beside the
    repository, or `--emps FILE`, or the MANUS_EMPS environment variable), from `rigid` alone.
    On a machine without it, the demo says so and runs part (a) only.

Both go into one Markdown report with its figures; the demo ends by printing where it is.
"""

from __future__ import annotations

import os
from pathlib import Path

from manus.runs.args import add_json, output_dir
from manus.runs.progress import note
from manus.runs.text import discovery_text

NAME = "demo"
HELP = "the main job: discover a hidden effect in a simulated arm, then the same loop on the real EMPS data; a report"
HIDDEN = "cogging:39"
TRUTH = f"rigid,viscous,coulomb,delay,{HIDDEN}"
NOMINAL = "rigid,viscous,coulomb"  # the thesis's model (§3.5)
EMPS_START = "rigid"
EMPS_NAME = "DATA_EMPS.mat"


def default_emps() -> Path:
    """$MANUS_EMPS, else ../shared/data/emps/DATA_EMPS.mat beside the repository."""
    env = os.environ.get("MANUS_EMPS")
    if env:
        return Path(env)
    return Path(__file__).resolve().parents[3] / "shared" / "data" / "emps" / EMPS_NAME


def add_arguments(p) -> None:
    p.add_argument(
        "--out",
        type=output_dir,
        default=Path("runs/out/demo"),
        metavar="DIR",
        help="where the recording, the figures and the report go (default runs/out/demo/)",
    )
    p.add_argument("--seconds", type=float, default=20.0, help="length of the simulated recording (default 20 s)")
    p.add_argument(
        "--emps",
        type=Path,
        metavar="FILE",
        help=f"the EMPS recording (default $MANUS_EMPS or ../shared/data/emps/{EMPS_NAME} beside the repository)",
    )
    p.add_argument("--no-emps", action="store_true", help="part (a) only")
    p.add_argument("--max-steps", type=int, default=6, help="stop each loop after this many additions")
    add_json(p)


def simulate_hidden(out: Path, seconds: float) -> str:
    """Part (a)'s recording (written into `out`, its figure beside it): the arm with the hidden
    effect under impedance control following the default multi-sine, as `manus simulate --truth
    TRUTH` makes it."""
    import numpy as np

    from manus.experiments.simulated import controller_for, simulated_recording
    from manus.plants import recording
    from manus.plants.references import reference_named
    from manus.plants.simulator import workspace_centre
    from manus.runs.args import build_plant, plant_options
    from manus.runs.figures.common import plot_recording

    plant = build_plant(plant_options(truth=TRUTH))
    reference = reference_named("multisine", np.asarray(workspace_centre(plant.model)))
    controller, how = controller_for(plant, serial=False)
    note(f"simulating {seconds:g} s of {plant.model.spec} at {plant.rate_hz:g} Hz ...")
    rec = simulated_recording(plant, controller, how, reference, "multisine", seconds, 0, 131072)
    path = recording.write(rec, Path(out) / "hidden_cogging.csv")
    rec.path = str(path)
    plot_recording(rec, path.with_suffix(".png"), f"{path.name}: truth {plant.model.spec}")
    return str(path)


def run(args) -> dict:
    from manus.plants import recording
    from manus.plants.errors import ManusError
    from manus.runs import report

    if args.seconds < 5:
        raise ManusError(f"--seconds {args.seconds:g}: the loop needs at least 5 s of recording")
    out = Path(args.out)
    sections = []
    note(f"(a) simulating {args.seconds:g} s of the MANUS-2 arm with a hidden effect: truth {TRUTH} ...")
    simulated = simulate_hidden(out, args.seconds)
    rec = recording.read(simulated)
    note(f"(a) discovering from the thesis's nominal model {NOMINAL} (the analysis is not told the truth) ...")
    intro = (
        f"The MANUS-2 arm simulated for {args.seconds:g} s under impedance control (K = 30 N·m/rad, B = 1 N·m·s/rad) "
        f"following a multi-sine, with truth `{TRUTH}` (131072 counts/rev encoder, 12-bit D/A). The analysis "
        f"starts from the thesis's nominal model `{NOMINAL}` and is not told about the 39/rev cogging or the 1 ms "
        "amplifier delay."
    )
    sections.append(
        report.discover_section(
            rec, NOMINAL, out, "a_", "(a) Simulated arm with a hidden effect", intro, max_steps=args.max_steps
        )
    )
    emps = None if args.no_emps else (args.emps or default_emps())
    emps_note = "skipped (--no-emps)" if args.no_emps else None
    if emps is not None and not emps.is_file():
        emps_note = f"no EMPS recording at {emps} (give --emps FILE or set MANUS_EMPS): part (b) skipped"
        note(emps_note)
        emps = None
    if emps is not None:
        note(f"(b) the same loop on the real EMPS recording {emps}, from {EMPS_START} alone ...")
        intro = (
            "The EMPS benchmark (Janot, Gautier, Brunot 2019): a real ball-screw axis in closed loop at 1 kHz. "
            "The published model is force = M q̈ + Fv q̇ + Fc sgn(q̇) + offset, rel_error 4.08 % "
            f"(M = 95.11 kg, Fv = 203.5 N·s/m, Fc = 20.39 N, offset = −3.16 N). The loop starts from `{EMPS_START}` "
            "alone."
        )
        sections.append(
            report.discover_section(
                recording.read(emps), EMPS_START, out, "b_", "(b) Real data: EMPS", intro, max_steps=args.max_steps
            )
        )
    path = report.write(sections, out / "report.md", "manus demo: fit, see where it fails, name the missing effect")
    r = {
        "simulated": {
            "recording": simulated,
            "truth": TRUTH,
            "start": NOMINAL,
            "hidden": HIDDEN,
            "discovery": report.section_result(sections[0]),
        },
        "emps": report.section_result(sections[1]) if len(sections) > 1 else {"skipped": emps_note},
        "report": path,
    }
    return r


def render(r: dict) -> str:
    s = r["simulated"]
    lines = [f"(a) simulated arm, truth {s['truth']}, starting from {s['start']}:", discovery_text(s["discovery"]), ""]
    if "skipped" in r["emps"]:
        lines += [f"(b) EMPS: {r['emps']['skipped']}", ""]
    else:
        lines += [
            f"(b) real EMPS recording {r['emps']['recording']}, starting from {r['emps']['start']['model']}:",
            discovery_text(r["emps"]),
            "",
        ]
    lines.append(f"the report (Markdown with its figures): {r['report']}")
    return "\n".join(lines)
