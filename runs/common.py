"""Pieces every command shares: common options, notes on stderr, figure files."""

from __future__ import annotations

import sys
from pathlib import Path

DEFAULT_OUT = Path("runs") / "out"


def add_common(parser, out: bool = True) -> None:
    parser.add_argument("--json", action="store_true", help="print one JSON object on stdout and nothing else")
    if out:
        parser.add_argument("--out", type=Path, default=DEFAULT_OUT, metavar="DIR",
                            help=f"where figures go (default {DEFAULT_OUT}/)")


def add_robot_option(parser) -> None:
    """--robot: shared by every command that reads a recording."""
    parser.add_argument("--robot", metavar="FILE.urdf",
                        help="the robot's URDF: the recording is this serial chain's (structure urdf), whatever its "
                             "metadata says (a recording can also name it: '# structure: urdf', '# robot: PATH')")


def read_recording(args):
    """The recording `args.recording`, a serial chain's when `--robot` names its URDF."""
    from manus.plants import recording

    return recording.read(args.recording, robot=getattr(args, "robot", None))


def note(*parts) -> None:
    """A progress note or remark for the person at the terminal: stderr, never stdout."""
    print(*parts, file=sys.stderr, flush=True)


def figure_dir(out: Path) -> Path:
    out = Path(out)
    out.mkdir(parents=True, exist_ok=True)
    return out


def pyplot():
    """matplotlib's pyplot on the file-only Agg backend (no screen needed)."""
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    plt.rcParams.update({"figure.dpi": 110, "axes.grid": True, "grid.alpha": 0.3, "font.size": 9})
    return plt


def save(fig, out: Path, name: str) -> str:
    path = figure_dir(out) / name
    fig.savefig(path, bbox_inches="tight")
    fig.clf()
    import matplotlib.pyplot as plt

    plt.close(fig)
    return str(path)


def table(rows: list[list], header: list[str]) -> str:
    """A plain text table, columns aligned."""
    cells = [[str(h) for h in header]] + [[str(c) for c in r] for r in rows]
    widths = [max(len(r[j]) for r in cells) for j in range(len(header))]
    fmt = lambda r: "  ".join(c.rjust(w) if j else c.ljust(w) for j, (c, w) in enumerate(zip(r, widths)))
    return "\n".join([fmt(cells[0]), fmt(["-" * w for w in widths])] + [fmt(r) for r in cells[1:]])
