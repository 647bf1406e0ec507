"""The command line's shared option groups, and what they are read into: a recording, a model's
text checked, a simulated plant. Every command takes its options from here."""

from __future__ import annotations

import argparse
import os
from pathlib import Path

from manus.plants.errors import ManusError

DEFAULT_OUT = Path("runs") / "out"
THESIS_TRUTH = "rigid,viscous,coulomb,delay"  # the thesis's plant: §3.5 friction, §3.2 delay


# -- output --------------------------------------------------------------------------------------
def add_common(parser, out: bool = True) -> None:
    """--json and --progress (`add_json`), and --out DIR where figures go."""
    add_json(parser)
    if out:
        parser.add_argument(
            "--out",
            type=output_dir,
            default=DEFAULT_OUT,
            metavar="DIR",
            help=f"where figures go (default {DEFAULT_OUT}/)",
        )


def add_json(parser, help: str = "print one JSON object on stdout and nothing else") -> None:
    """--json, and --progress: notes and progress bars on stderr with it too."""
    parser.add_argument("--json", action="store_true", help=help)
    parser.add_argument(
        "--progress",
        action="store_true",
        help="notes and progress bars on stderr even with --json (without --json they are always shown)",
    )


def _writable(path: Path) -> None:
    """`path` can be made: its nearest existing ancestor is a directory this process may write in."""
    at = path.absolute().parent
    while not at.exists():
        at = at.parent
    if not at.is_dir():
        raise argparse.ArgumentTypeError(f"{path}: {at} is a file, not a directory")
    if not os.access(at, os.W_OK | os.X_OK):
        raise argparse.ArgumentTypeError(f"{path}: no permission to write in {at}")


def output_dir(text: str) -> Path:
    """A directory outputs go to (made when needed), checked when the command line is read, before
    any work: not a file, somewhere this process may write."""
    path = Path(text)
    if path.exists() and not path.is_dir():
        raise argparse.ArgumentTypeError(f"{text}: a file, not a directory")
    _writable(path / "x")
    return path


def output_file(*suffixes: str):
    """An argparse type: a file to write, one of `suffixes`, checked before any work (a run's
    recording refused after the run would be lost)."""

    def check(text: str) -> Path:
        path = Path(text)
        if path.is_dir() or text.endswith(("/", os.sep)):
            raise argparse.ArgumentTypeError(
                f"{text}: a directory; give a file name (e.g. {path / ('run' + suffixes[0])})"
            )
        if path.suffix.lower() not in suffixes:
            raise argparse.ArgumentTypeError(f"{text}: expected a {' or '.join(suffixes)} file")
        _writable(path)
        return path

    return check


# -- a recording and a model ---------------------------------------------------------------------
def add_robot_option(parser) -> None:
    """--robot: shared by every command that reads a recording."""
    parser.add_argument(
        "--robot",
        metavar="FILE.urdf",
        help="the robot's URDF: the recording is this serial chain's (structure urdf), whatever its "
        "metadata says (a recording can also name it: '# structure: urdf', '# robot: PATH')",
    )


def add_source_options(p) -> None:
    """REC, --robot and how to read a user's own table or bag: --map, --set, --topic, --joints,
    --command-topic (docs/recording.md)."""
    p.add_argument(
        "recording",
        metavar="REC",
        help="a recording: a manus .csv or .npz, any CSV, Parquet, HDF5, MATLAB or .npz table (with --map), "
        "or a ROS 2 bag folder of sensor_msgs/JointState",
    )
    add_robot_option(p)
    g = p.add_argument_group("your own recordings")
    g.add_argument(
        "--map",
        metavar="MAP",
        help="which of the table's columns is each of the recording's, with units where not SI: "
        "'t=stamp:ms,q1=shoulder_pos:deg,tau1=shoulder_eff', SOURCE[k] for column k of a 2-D array, "
        "an HDF5 dataset by its path; or a file of NAME=SOURCE lines",
    )
    g.add_argument(
        "--set",
        action="append",
        default=[],
        metavar="KEY=VALUE",
        help="state a metadata key over the file's own, e.g. --set sample_rate_hz=500 --set counts_per_rev=4096 "
        "--set structure=manus2 (repeatable)",
    )
    g.add_argument("--topic", help="a ROS 2 bag's JointState topic (default: the only one)")
    g.add_argument(
        "--joints", type=_names, metavar="NAMES", help="a ROS 2 bag's joints by name, in order: 'shoulder,elbow'"
    )
    g.add_argument(
        "--command-topic",
        metavar="TOPIC",
        help="a ROS 2 bag's topic of the commanded torque (JointState effort or Float64MultiArray), when the "
        "states' effort is not it",
    )


def _names(text: str) -> list[str]:
    names = [n.strip() for n in text.split(",")]
    if not all(names) or len(set(names)) != len(names):
        raise argparse.ArgumentTypeError(f"{text!r}: expected distinct names separated by commas")
    return names


def stated_meta(items: list[str]) -> dict[str, str]:
    """--set KEY=VALUE items as metadata."""
    out = {}
    for item in items:
        key, sep, value = item.partition("=")
        if not sep or not key.strip() or not value.strip():
            raise ManusError(f"--set {item!r}: expected KEY=VALUE, e.g. --set sample_rate_hz=500")
        out[key.strip()] = value.strip()
    return out


def add_model_options(p, required: bool = True) -> None:
    """REC and its source options, --model, --cutoff, --method, --transmission and --hold: shared by
    fit, diagnose and discover."""
    add_source_options(p)
    p.add_argument(
        "--model",
        required=required,
        metavar="EFFECTS",
        help="effects of the model, e.g. rigid,viscous,coulomb (an argument fixes a non-linear "
        "parameter: cogging:39, delay:1ms; without one it is searched)",
    )
    p.add_argument(
        "--cutoff",
        type=float,
        metavar="HZ",
        help="identification bandwidth (default: from the motion's band and the encoder's quantization-noise budget)",
    )
    p.add_argument(
        "--method",
        choices=("auto", "ls", "iv", "oe"),
        default="auto",
        help="least squares (IDIM-LS), instrumental variables (IDIM-IV, instruments from a simulation "
        "of the model driven by the recorded command), output error (OE: the simulated positions fitted "
        "to the recorded ones, in short windows), or auto (IV or OE where LS is biased; default)",
    )
    p.add_argument(
        "--transmission",
        metavar="STATEMENT",
        help="how the actuators turn with the joints, θ = N q, e.g. 'q1; q2 - q1', 'm5 = q5 + q6; m6 = q5 - q6' or "
        "[[1,0],[-1,1]]: friction and the other motor-side effects act on the actuators (replaces the "
        "recording's '# transmission:' and the URDF's <transmission>)",
    )
    p.add_argument(
        "--hold",
        choices=("zoh", "none"),
        help="how the recorded command was held (default: the file's command_hold, else zoh: a digital "
        "controller holds each command over its period)",
    )


def read_recording(args):
    """The recording `args.recording` as `add_source_options` say to read it, a serial chain's when
    `--robot` names its URDF."""
    from manus.plants import recording

    return recording.read(
        args.recording,
        robot=args.robot,
        columns=args.map,
        meta=stated_meta(args.set),
        topic=args.topic,
        joints=args.joints,
        command_topic=args.command_topic,
    )


def load_recording(args, proposing: bool = False):
    """The recording and the model text of `add_model_options`, checked: a one-line error for bad
    input. `proposing` (diagnose, discover): a model holding every effect leaves nothing to propose."""
    from manus.plants.effects import ORDER, parse_effects
    from manus.runs.progress import note
    from manus.runs.text import describe

    if args.cutoff is not None and args.cutoff <= 0:
        raise ManusError(f"--cutoff {args.cutoff:g}: must be positive")
    effects = parse_effects(args.model)  # unknown names, duplicates: refused before the file is read
    if proposing and len(effects) == len(ORDER):
        raise ManusError(
            f"the model {args.model} already holds every effect of the vocabulary: nothing is left to propose"
        )
    rec = read_recording(args)
    if args.hold:
        rec.meta["command_hold"] = args.hold
    if getattr(args, "transmission", None) is not None:
        from manus.plants.transmission import stated

        stated(rec.structure, args.transmission, "--transmission")  # a malformed statement: a one-line error
        rec.meta["transmission"] = args.transmission
    note(describe(rec))
    return rec


# -- a simulated plant ---------------------------------------------------------------------------
def add_plant_options(parser, truth_default: str = THESIS_TRUTH, robot: bool = False) -> None:
    """The simulated plant: its effects and parameters, structure, rates, encoder and noise;
    with `robot`, --robot FILE.urdf as well."""
    g = parser.add_argument_group("plant")
    if robot:
        g.add_argument(
            "--robot",
            metavar="FILE.urdf",
            help="a serial robot from its URDF instead of --structure (its joints' <dynamics damping "
            "friction> are the default viscous and Coulomb levels)",
        )
    else:
        parser.set_defaults(robot=None)
    g.add_argument(
        "--truth",
        default=truth_default,
        metavar="EFFECTS",
        help=f"effects of the simulated plant, e.g. rigid,viscous,coulomb,cogging:39,delay:1ms "
        f"(default {truth_default})",
    )
    g.add_argument(
        "--param",
        action="append",
        default=[],
        metavar="NAME=VALUE",
        help="set a truth parameter, e.g. --param Fc1=0.2 (repeatable)",
    )
    g.add_argument("--structure", choices=("manus2", "axis"), default="manus2")
    g.add_argument("--joints", type=int, default=1, help="number of joints of an axis structure")
    g.add_argument("--rate", type=float, default=1000.0, help="control rate [Hz] (default 1000)")
    g.add_argument("--substeps", type=int, default=10, help="physics sub-steps per control period")
    g.add_argument("--counts", type=float, default=131072, help="encoder counts per revolution (0: no quantization)")
    g.add_argument("--torque-noise", type=float, default=0.0, help="white torque disturbance std [N·m]")


def plant_options(**values) -> argparse.Namespace:
    """The plant options at their defaults, with `values` (option names with underscores) set."""
    p = argparse.ArgumentParser(add_help=False)
    add_plant_options(p, robot=True)
    args = p.parse_args([])
    unknown = set(values) - set(vars(args))
    if unknown:
        raise ValueError(f"no plant option {', '.join(sorted(unknown))}")
    return argparse.Namespace(**{**vars(args), **values})


def parse_pairs(items: list[str], flag: str, example: str = "") -> dict[str, float]:
    """NAME=VALUE items (a repeatable option `flag`) as a dict of numbers."""
    out = {}
    for item in items:
        name, sep, value = item.partition("=")
        try:
            if not sep:
                raise ValueError
            out[name.strip()] = float(value)
        except ValueError:
            raise ManusError(f"{flag} {item!r}: expected NAME=VALUE with a number{example}") from None
    return out


def parse_params(items: list[str]) -> dict[str, float]:
    """--param NAME=VALUE items."""
    return parse_pairs(items, "--param", ", e.g. Fc1=0.2")


def build_plant(args, robot_torque_limit: float | None = None):
    """The simulator the plant options describe. A serial robot gets the torque it is commanded,
    or, with `robot_torque_limit` [N·m] (a rig behind the device protocol needs a D/A), an ideal
    24-bit ±10 V D/A reaching that torque."""
    import math

    from manus.plants import Encoder, Model, Simulator, structure_named

    if not args.rate > 0 or args.substeps < 1:
        raise ManusError("--rate must be positive and --substeps at least 1")
    if args.joints < 1:
        raise ManusError(f"--joints {args.joints}: an axis structure has at least one joint")
    if not args.torque_noise >= 0 or not args.counts >= 0:
        raise ManusError("--torque-noise is a standard deviation and --counts a count: neither can be negative")
    if args.robot:
        from manus.plants.serial import Serial

        structure = Serial.from_urdf(args.robot)
    else:
        structure = structure_named(args.structure, 2 if args.structure == "manus2" else args.joints)
    model = Model(structure, args.truth)
    for e in model.effects:  # an effect that cannot act on these joints (gravity is in a chain's rigid)
        why = e.applies(structure, tuple(structure.prismatic))
        if why:
            raise ManusError(f"--truth: {e.name}: {why}")
    encoder = Encoder(step=2 * math.pi / args.counts) if args.counts > 0 else None
    # a serial robot gets the torque it is commanded (the thesis's 12-bit D/A and its ±22 N·m are
    # MANUS-2's, not a URDF robot's)
    extra = {}
    if args.robot:
        from manus.plants.simulator import Actuator

        extra["actuator"] = (
            None
            if robot_torque_limit is None
            else Actuator(dac_bits=24, volts=10.0, amps_per_volt=1.0, torque_constant=robot_torque_limit / 10.0)
        )
    sim = Simulator(
        model,
        parse_params(args.param),
        rate_hz=args.rate,
        substeps=args.substeps,
        encoder=encoder,
        torque_noise=args.torque_noise,
        **extra,
    )
    bad = model.violations({k: float(v) for k, v in sim.params.items()})
    if bad:  # a plant that breaks its effects' physics (a negative inertia, friction that pushes)
        raise ManusError("--param: the plant breaks physics: " + "; ".join(bad))
    return sim
