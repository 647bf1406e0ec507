"""Building plants and controllers from command-line options (shared by several commands)."""

from __future__ import annotations

from manus.plants.errors import ManusError

THESIS_TRUTH = "rigid,viscous,coulomb,delay"  # the thesis's plant: §3.5 friction, §3.2 delay


def add_plant_options(parser, truth_default: str = THESIS_TRUTH, robot: bool = False) -> None:
    g = parser.add_argument_group("plant")
    if robot:
        g.add_argument("--robot", metavar="FILE.urdf",
                       help="a serial robot from its URDF instead of --structure (its joints' <dynamics damping "
                            "friction> are the default viscous and Coulomb levels)")
    g.add_argument("--truth", default=truth_default, metavar="EFFECTS",
                   help=f"effects of the simulated plant, e.g. rigid,viscous,coulomb,cogging:39,delay:1ms "
                        f"(default {truth_default})")
    g.add_argument("--param", action="append", default=[], metavar="NAME=VALUE",
                   help="set a truth parameter, e.g. --param Fc1=0.2 (repeatable)")
    g.add_argument("--structure", choices=("manus2", "axis"), default="manus2")
    g.add_argument("--joints", type=int, default=1, help="number of joints of an axis structure")
    g.add_argument("--rate", type=float, default=1000.0, help="control rate [Hz] (default 1000)")
    g.add_argument("--substeps", type=int, default=10, help="physics sub-steps per control period")
    g.add_argument("--counts", type=float, default=131072, help="encoder counts per revolution (0: no quantization)")
    g.add_argument("--torque-noise", type=float, default=0.0, help="white torque disturbance std [N·m]")


def parse_params(items: list[str]) -> dict[str, float]:
    out = {}
    for item in items:
        name, sep, value = item.partition("=")
        try:
            if not sep:
                raise ValueError
            out[name.strip()] = float(value)
        except ValueError:
            raise ManusError(f"--param {item!r}: expected NAME=VALUE with a number, e.g. Fc1=0.2") from None
    return out


def build_plant(args, robot_torque_limit: float | None = None):
    """The simulator the options describe. A serial robot gets the torque it is commanded, or,
    with `robot_torque_limit` [N·m] (a rig behind the device protocol needs a D/A), an ideal
    24-bit ±10 V D/A reaching that torque."""
    import math

    from manus.plants import Encoder, Model, Simulator, structure_named

    if not args.rate > 0 or args.substeps < 1:
        raise ManusError("--rate must be positive and --substeps at least 1")
    if args.joints < 1:
        raise ManusError(f"--joints {args.joints}: an axis structure has at least one joint")
    if not args.torque_noise >= 0 or not args.counts >= 0:
        raise ManusError("--torque-noise is a standard deviation and --counts a count: neither can be negative")
    robot = getattr(args, "robot", None)
    if robot:
        from manus.plants.serial import Serial

        structure = Serial.from_urdf(robot)
    else:
        structure = structure_named(args.structure, 2 if args.structure == "manus2" else args.joints)
    model = Model(structure, args.truth)
    for e in model.effects:  # an effect that cannot act on these joints (gravity is in a chain's rigid)
        why = e.applies(structure, tuple(getattr(structure, "prismatic", ())))
        if why:
            raise ManusError(f"--truth: {e.name}: {why}")
    encoder = Encoder(step=2 * math.pi / args.counts) if args.counts > 0 else None
    # a serial robot gets the torque it is commanded (the thesis's 12-bit D/A and its ±22 N·m are
    # MANUS-2's, not a URDF robot's)
    extra = {}
    if robot:
        from manus.plants.simulator import Actuator

        extra["actuator"] = None if robot_torque_limit is None else Actuator(
            dac_bits=24, volts=10.0, amps_per_volt=1.0, torque_constant=robot_torque_limit / 10.0)
    sim = Simulator(model, parse_params(args.param), rate_hz=args.rate, substeps=args.substeps,
                    encoder=encoder, torque_noise=args.torque_noise, **extra)
    bad = model.violations({k: float(v) for k, v in sim.params.items()})
    if bad:  # a plant that breaks its effects' physics (a negative inertia, friction that pushes)
        raise ManusError("--param: the plant breaks physics: " + "; ".join(bad))
    return sim
