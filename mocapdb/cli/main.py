"""The `mocapdb` command line: one parser per command (in this package), one error path.

Parsers import nothing heavy; a command's run function imports what it needs, so ``--help``
never loads numba, OpenCV, SciPy or pyarrow.
"""
from __future__ import annotations

import argparse
import logging
import sys

from mocapdb import __version__
from mocapdb.cli import build, detect, evaluate, reconstruct, render, stereo, view
from mocapdb.cli.paths import check_outputs_apart
from mocapdb.core.errors import MocapdbError

COMMANDS = (build.add_build_parser, build.add_inspect_parser, build.add_verify_parser,
            reconstruct.add_reconstruct_parser, reconstruct.add_live_parser, evaluate.add_eval_parser,
            detect.add_detect_parser, detect.add_models_parser, stereo.add_stereo_parser, render.add_render_parser,
            view.add_view_parser)


class _Parser(argparse.ArgumentParser):
    """An argparse parser whose usage errors are one line, ``mocapdb COMMAND: error: ...`` (as
    every other user error), with a pointer to ``--help`` instead of the whole usage block."""

    def error(self, message: str):
        self.exit(2, f"{self.prog}: error: {message} (see {self.prog} --help)\n")


def parser() -> argparse.ArgumentParser:
    """The top-level parser with every subcommand; ``args.run(args)`` runs the chosen one."""
    top = _Parser(prog="mocapdb", description="Motion capture from ordinary cameras by "
                                  "retrieval in a database of real motion.")
    top.add_argument("--version", action="version", version=f"mocapdb {__version__}")
    top.add_argument("-v", "--verbose", action="count", default=0, help="more diagnostics (-vv: debug)")
    top.add_argument("-q", "--quiet", action="store_true", help="errors only: no warnings, no progress bars")
    sub = top.add_subparsers(dest="command", required=True, metavar="COMMAND")
    for add in COMMANDS:
        add(sub)
    for command in sub.choices.values():  # -v/-q also after the command name (given there, they win)
        command.add_argument("-v", "--verbose", action="count", default=argparse.SUPPRESS,
                             help="more diagnostics (-vv: debug)")
        command.add_argument("-q", "--quiet", action="store_true", default=argparse.SUPPRESS,
                             help="errors only: no warnings, no progress bars")
    return top


def command_parser(name: str) -> argparse.ArgumentParser:
    """The parser of subcommand ``name``."""
    sub = next(a for a in parser()._actions if isinstance(a, argparse._SubParsersAction))
    return sub.choices[name]


def error_text(exc: BaseException) -> str:
    """The one line printed for a user error: an OS error names its file."""
    if isinstance(exc, OSError):
        from mocapdb.core.files import os_error_message

        return os_error_message(exc)
    return str(exc)


class _LowerCaseLevel(logging.Formatter):
    def format(self, record: logging.LogRecord) -> str:
        record.levelname = record.levelname.lower()
        return super().format(record)


def configure_logging(verbose: int, quiet: bool) -> None:
    """Diagnostics of every module (``logging.getLogger("mocapdb...")``) to stderr as
    ``mocapdb: warning: ...``: warnings by default, info with -v, debug with -vv, errors with -q
    (which also hides the progress bars)."""
    level = logging.ERROR if quiet else (logging.WARNING, logging.INFO, logging.DEBUG)[min(verbose, 2)]
    handler = logging.StreamHandler(sys.stderr)
    handler.setFormatter(_LowerCaseLevel("mocapdb: %(levelname)s: %(message)s"))
    logger = logging.getLogger("mocapdb")
    logger.handlers[:] = [handler]
    logger.setLevel(level)
    if quiet:
        from mocapdb.core.progress import set_quiet

        set_quiet(True)


def main(argv: list[str] | None = None) -> int:
    """Run the command line; returns the exit code: 0 on success (and for --help), 2 on a user error
    (one line on stderr, no traceback), 130 when interrupted; a command may return its own code."""
    try:
        args = parser().parse_args(argv)
    except SystemExit as exc:  # --help, --version, or an option outside its domain (one line printed)
        return exc.code if isinstance(exc.code, int) else 2
    configure_logging(args.verbose, args.quiet)
    try:
        check_outputs_apart(command_parser(args.command), args)
        return args.run(args)
    except (MocapdbError, OSError) as exc:
        print(f"mocapdb {args.command}: error: {error_text(exc)}", file=sys.stderr)
        return 2
    except KeyboardInterrupt:
        print(f"mocapdb {args.command}: interrupted", file=sys.stderr)
        return 130
