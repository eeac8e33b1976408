"""The `mocapdb` command line: one parser per command (in this package), one error path.

Parsers import nothing heavy; a command's run function imports what it needs, so ``--help``
never loads numba, OpenCV, SciPy or pyarrow.
"""
from __future__ import annotations

import argparse
import sys

from mocapdb import __version__
from mocapdb.cli import build, detect, evaluate, reconstruct, render, stereo
from mocapdb.core.errors import MocapdbError

COMMANDS = (build.add_build_parser, build.add_inspect_parser, reconstruct.add_reconstruct_parser,
            reconstruct.add_live_parser, evaluate.add_eval_parser, detect.add_detect_parser, stereo.add_stereo_parser,
            render.add_render_parser)


def parser() -> argparse.ArgumentParser:
    """The top-level parser with every subcommand; ``args.run(args)`` runs the chosen one."""
    top = argparse.ArgumentParser(prog="mocapdb", description="Motion capture from ordinary cameras by "
                                  "retrieval in a database of real motion.")
    top.add_argument("--version", action="version", version=f"mocapdb {__version__}")
    sub = top.add_subparsers(dest="command", required=True, metavar="COMMAND")
    for add in COMMANDS:
        add(sub)
    return top


def error_text(exc: BaseException) -> str:
    """The one line printed for a user error: an OS error names its file."""
    if isinstance(exc, OSError):
        from mocapdb.core.files import os_error_message

        return os_error_message(exc)
    return str(exc)


def main(argv: list[str] | None = None) -> int:
    """Run the command line; returns the exit code: 0 on success, 2 on a user error (one line on
    stderr, no traceback), 130 when interrupted; a command may return its own code."""
    args = parser().parse_args(argv)
    try:
        return args.run(args)
    except (MocapdbError, OSError) as exc:
        print(f"mocapdb {args.command}: error: {error_text(exc)}", file=sys.stderr)
        return 2
    except KeyboardInterrupt:
        print(f"mocapdb {args.command}: interrupted", file=sys.stderr)
        return 130
