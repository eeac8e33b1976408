"""The errors a user can cause (bad files, bad options, bad streams).

A leaf module: it imports nothing of mocapdb. Every module's error class derives from
:class:`MocapdbError` (and from the built-in exception it has always been, so ``except ValueError``
still catches a bad file); the command line prints any :class:`MocapdbError` or ``OSError`` as one
line, without a traceback, and exits with code 2.
"""
from __future__ import annotations


class MocapdbError(Exception):
    """Base of every error mocapdb raises about its inputs; the message says what to change."""


class UsageError(MocapdbError, ValueError):
    """A command-line value that cannot be used."""


USER_ERRORS: tuple[type[BaseException], ...] = (MocapdbError, OSError)
