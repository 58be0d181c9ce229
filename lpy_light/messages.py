"""Warnings once per kind: a growth run of 150 steps must not print the same warning 1,500 times.

A light model warns through the ``lpy_light`` logger.  While a :class:`OncePerKind`
filter is on that logger, the first warning of each *kind* (its format string:
"organ %r (%s): dropped %d degenerate triangle(s)..." is one kind whatever the
organ) is printed and the others are only counted; :meth:`OncePerKind.summary`
gives the counts (``lpy-light grow`` prints them at the end and writes them into
``summary.json``)::

    with once_per_kind() as seen:
        ...                       # derive the model
    seen.summary()                # [{"kind": ..., "first": ..., "count": n}, ...]
"""
from __future__ import annotations

import logging
from contextlib import contextmanager

LOGGER = "lpy_light"


class OncePerKind(logging.Filter):
    """A logging filter that lets the first record of each format string through and counts all of them."""

    def __init__(self):
        super().__init__()
        self.counts: dict = {}
        self.first: dict = {}

    def filter(self, record: logging.LogRecord) -> bool:
        if record.levelno < logging.WARNING:
            return True
        kind = str(record.msg)
        self.counts[kind] = self.counts.get(kind, 0) + 1
        if kind in self.first:
            return False
        self.first[kind] = record.getMessage()
        return True

    def summary(self) -> list:
        """One entry per kind of warning: ``{"kind", "first" (the message printed), "count"}``."""
        return [{"kind": kind, "first": self.first[kind], "count": n} for kind, n in self.counts.items()]

    def repeated_lines(self) -> list:
        """For the end of a run: one line per kind that was warned more than once."""
        return ["%d warnings like: %s" % (n, self.first[kind]) for kind, n in self.counts.items() if n > 1]


@contextmanager
def once_per_kind():
    """Within the block, each kind of warning of the ``lpy_light`` logger is printed once and counted."""
    seen = OncePerKind()
    logger = logging.getLogger(LOGGER)
    logger.addFilter(seen)
    try:
        yield seen
    finally:
        logger.removeFilter(seen)
