"""`manus demo`: what `make demo` runs."""

from __future__ import annotations

from pathlib import Path

from runs.common import note

NAME = "demo"
HELP = "the main job: simulate the arm with a hidden effect, write the recording and its figure"


def add_arguments(p) -> None:
    p.add_argument("--out", type=Path, default=Path("runs/out/demo"), metavar="DIR")
    p.add_argument("--json", action="store_true", help="print one JSON object on stdout and nothing else")


def run(args) -> dict:
    from runs import cmd_simulate
    from runs.cli import parser, commands

    hidden = "cogging:39"
    note(f"simulating the MANUS-2 arm with a hidden effect ({hidden}) under impedance control ...")
    sim_args = parser(commands()).parse_args(
        ["simulate", "--truth", f"rigid,viscous,coulomb,delay,{hidden}", "--seconds", "20",
         "--out", str(Path(args.out) / "hidden_cogging.csv")])
    return cmd_simulate.run(sim_args)


def render(r: dict) -> str:
    from runs.cmd_simulate import render as sim_render

    return sim_render(r)
