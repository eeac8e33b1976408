"""The detector's one error type and the readability check shared by the model and the video reader."""
from __future__ import annotations

from pathlib import Path

from mocapdb.core.errors import MocapdbError
from mocapdb.core.files import os_error_message


class DetectError(MocapdbError, RuntimeError):
    """A model, video or option that cannot be used; the message says which and why."""


def check_readable(path: Path, what: str) -> None:
    """DetectError naming ``path`` when it is a folder or cannot be opened for reading."""
    if path.is_dir():
        raise DetectError(f"{path}: is a folder, not a {what} file")
    try:
        with open(path, "rb"):
            pass
    except OSError as exc:
        raise DetectError(os_error_message(exc, path, f"read the {what}")) from None
