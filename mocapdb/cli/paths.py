"""The argparse types of the options that name paths and free text, and the check that no output
is, holds or lies inside an input (data_specs/option_domains.md).

Every non-flag option of every command has a declared type: a number's domain
(:mod:`mocapdb.core.domains`), a :class:`PathArg` or a :class:`TextArg`; tests/test_options.py
walks the parser and fails on an option without one.
"""
from __future__ import annotations

import argparse
import os
import stat
from dataclasses import dataclass
from pathlib import Path

from mocapdb.core.files import file_kind

STREAM_PREFIXES = ("tcp://", "udp://", "vmc://", "vrchat://")
MAX_TEXT_CHARS = 4096


def is_stream_spec(text: str) -> bool:
    """``-`` (stdin/stdout), a ``tcp://``/``udp://`` address (``vmc://``/``vrchat://``: sinks), or a camera
    index: not a path."""
    return text == "-" or text.startswith(STREAM_PREFIXES) or text.isdigit()


@dataclass(frozen=True)
class PathArg:
    """A path option. ``role`` "input": it must exist, as a regular file or a folder (``kind``
    "file", "dir" or "any"); "output": anything but an existing special file (a FIFO, a device, a
    socket), ``kind`` "dir" for a folder the run replaces as a whole. ``streams``: ``-``,
    ``tcp://``, ``udp://``, ``vmc://``, ``vrchat://`` and a camera index are taken as they are."""

    role: str
    kind: str = "any"
    streams: bool = False

    def __call__(self, text: str) -> str:
        if not text or "\0" in text or len(text) > MAX_TEXT_CHARS:
            raise argparse.ArgumentTypeError(f"{text[:80]!r}: not a path")
        if self.streams and is_stream_spec(text):
            return text
        try:
            mode = os.stat(text).st_mode
        except FileNotFoundError:
            if self.role == "input":
                raise argparse.ArgumentTypeError(f"{text}: no such {_kind_words(self.kind)}") from None
            return text
        except OSError as exc:  # a symlink loop, a name too long, no permission to look
            if self.role == "output":  # the command's writer names what is wrong with its output
                return text
            raise argparse.ArgumentTypeError(f"{text}: cannot be read ({exc.strerror})") from None
        if not (stat.S_ISREG(mode) or stat.S_ISDIR(mode)):
            raise argparse.ArgumentTypeError(f"{text}: {file_kind(mode)}, not a {_kind_words(self.kind)}")
        if self.role == "input" and self.kind == "file" and not stat.S_ISREG(mode):
            raise argparse.ArgumentTypeError(f"{text}: is a folder, not a file")
        if self.role == "input" and self.kind == "dir" and not stat.S_ISDIR(mode):
            raise argparse.ArgumentTypeError(f"{text}: is a file, not a folder")
        return text

    @property
    def __name__(self) -> str:
        return f"an {self.role} path"


def _kind_words(kind: str) -> str:
    return {"file": "file", "dir": "folder"}.get(kind, "file or folder")


@dataclass(frozen=True)
class TextArg:
    """Free text (names, patterns, lists): at most :data:`MAX_TEXT_CHARS` characters, no control
    characters."""

    what: str

    def __call__(self, text: str) -> str:
        if len(text) > MAX_TEXT_CHARS or any(ord(c) < 32 for c in text):
            raise argparse.ArgumentTypeError(f"{text[:80]!r}: must be {self.what}, at most {MAX_TEXT_CHARS} "
                                             "printable characters")
        return text

    @property
    def __name__(self) -> str:
        return self.what


INPUT_FILE = PathArg("input", "file")
INPUT_DIR = PathArg("input", "dir")
INPUT_ANY = PathArg("input")
OUTPUT = PathArg("output")
OUTPUT_DIR = PathArg("output", "dir")
STREAM_SOURCE = PathArg("input", streams=True)
STREAM_SINK = PathArg("output", streams=True)


def _values(value) -> list[str]:
    return [v for v in (value if isinstance(value, list) else [value]) if isinstance(v, str)]


def check_outputs_apart(command: argparse.ArgumentParser, args: argparse.Namespace) -> None:
    """Refuse (UsageError naming both options) an output path that is or lies inside an input path
    of the same command, or an output folder replaced as a whole that holds one: a run must never
    write over what it reads."""
    from mocapdb.core.errors import UsageError

    paths: dict[str, list[tuple[str, Path, PathArg]]] = {"input": [], "output": []}
    for action in command._actions:
        if isinstance(action.type, PathArg):
            for value in _values(getattr(args, action.dest, None)):
                if not (action.type.streams and is_stream_spec(value)):
                    paths[action.type.role].append((_option_name(action), Path(value).resolve(), action.type))
    for out_name, out, out_type in paths["output"]:
        for in_name, inp, _ in paths["input"]:
            if out == inp or inp in out.parents or (out_type.kind == "dir" and out in inp.parents):
                relation = "is" if out == inp else ("holds" if out in inp.parents else "lies inside")
                raise UsageError(f"{out_name} {out} {relation} the input {in_name} {inp}: choose an output "
                                 "apart from the inputs")


def _option_name(action: argparse.Action) -> str:
    return action.option_strings[-1] if action.option_strings else action.dest.upper()
