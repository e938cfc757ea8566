"""Command line: ``python -m lagsplat.synth.continuum_robot`` writes one simulated recording.

Part of :mod:`lagsplat.synth.continuum_robot` (its docstring describes the model).
"""

from __future__ import annotations

import argparse
import sys
from collections.abc import Sequence

from lagsplat.synth.continuum_robot.constants import DEFAULT_DURATION_S, SEGMENTS
from lagsplat.synth.continuum_robot.writer import write_robot_npz


class _Parser(argparse.ArgumentParser):
    def error(self, message: str) -> None:  # one line, exit status 2
        self.exit(2, f"{self.prog}: error: {message}\n")


def main(argv: Sequence[str] | None = None) -> int:
    """``python -m lagsplat.synth.continuum_robot --segments {1,2} --out PATH.npz [--duration-s S] [--seed N]``.

    Prints the written path. Returns 0; bad arguments exit with status 2 and
    a one-line message on stderr.
    """
    p = _Parser(prog="python -m lagsplat.synth.continuum_robot", description="Write the offline soft-robot surrogate clip (Krauss NPZ layout).")
    p.add_argument("--segments", type=int, choices=SEGMENTS, required=True, help="number of segments (1 or 2)")
    p.add_argument("--out", required=True, help="output .npz path (metadata goes to <out>.json)")
    p.add_argument("--duration-s", type=float, default=DEFAULT_DURATION_S, help=f"clip length in seconds (default {DEFAULT_DURATION_S:g})")
    p.add_argument("--seed", type=int, default=0, help="seed of the pressures and the background texture (default 0)")
    args = p.parse_args(argv)
    try:
        write_robot_npz(args.out, args.segments, args.duration_s, args.seed)
    except ValueError as exc:
        print(f"{p.prog}: error: {str(exc).splitlines()[0]}", file=sys.stderr)
        return 2
    print(args.out)
    return 0


if __name__ == "__main__":  # pragma: no cover - exercised through a subprocess in the tests
    sys.exit(main())
