"""``python -m lagsplat.synth.realistic --list | --list-nuisance | --list-backdrops | --list-impacts | --clip NAME --out DIR``: build one clip of the realistic suite.

``--list`` prints the suite's clips and the clips outside the model class; ``--list-nuisance`` the nuisance clips
(:func:`lagsplat.synth.realistic.nuisance_clips`); ``--list-backdrops`` the backdrop clips
(:func:`lagsplat.synth.realistic.backdrop_clips`); ``--list-impacts`` the impact clips
(:func:`lagsplat.synth.realistic.impact_clips`); ``--clip`` builds any of them.
"""

from __future__ import annotations

import argparse
import sys

from lagsplat.synth.realistic import backdrop_clips, impact_clips, make_clip, nuisance_clips, outside_class_clips, realistic_suite


#: ``--list...`` flag -> (what it lists, the clips it prints)
LISTS = {
    "list": ("the clip names", lambda: realistic_suite() + outside_class_clips()),
    "list-nuisance": ("the nuisance clips' names", nuisance_clips),
    "list-backdrops": ("the backdrop clips' names", backdrop_clips),
    "list-impacts": ("the impact clips' names", impact_clips),
}


def main(argv: list[str] | None = None) -> int:
    """Entry point; returns the exit code (0 ok, 2 bad arguments)."""
    p = argparse.ArgumentParser(prog="python -m lagsplat.synth.realistic", description="Render one clip of the realistic (MuJoCo) suite.")
    for flag, (what, _) in LISTS.items():
        p.add_argument(f"--{flag}", action="store_true", help=f"print {what} and exit")
    p.add_argument("--clip", help="clip name (see --list)")
    p.add_argument("--out", help="output folder: <clip>.mp4 and <clip>.truth.npz")
    args = p.parse_args(argv)
    for flag, (_, clips) in LISTS.items():
        if getattr(args, flag.replace("-", "_")):
            print("\n".join(e["name"] for e in clips()))
            return 0
    if not args.clip or not args.out:
        p.print_usage(sys.stderr)
        print(f"{p.prog}: error: give --clip and --out (or {', '.join('--' + f for f in LISTS)})", file=sys.stderr)
        return 2
    try:
        print(make_clip(args.clip, args.out))
    except KeyError as exc:
        print(f"{p.prog}: error: {exc.args[0]}", file=sys.stderr)
        return 2
    return 0


if __name__ == "__main__":
    sys.exit(main())
