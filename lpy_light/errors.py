"""Errors that name the file and line at fault.

Every problem with user input raises :class:`InputError`; the command line prints
its one-line message (``file:line: what was expected``) and exits with status 2.
"""
from __future__ import annotations


class LpyLightError(Exception):
    """Base class of every error lpy-light raises on purpose."""


class InputError(LpyLightError):
    """Bad input: a file (and where known, a line) that does not say what we expect."""

    def __init__(self, message: str, path=None, line: int | None = None):
        self.path = str(path) if path is not None else None
        self.line = line
        self.reason = message
        where = ""
        if self.path:
            where = self.path + (":%d" % line if line else "") + ": "
        super().__init__(where + message)


class ResourceError(LpyLightError):
    """A run that would exceed memory or another limit, refused before it starts."""
