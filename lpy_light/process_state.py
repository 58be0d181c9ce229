"""Process-wide state that a dependency changes, put back as it was: :func:`preserved_locale`.

lpy-light runs inside the modeller's process (the L-Py IDE, a notebook, a script): whatever it calls must leave
that process as it found it.  PlantGL does not: its C++ calls ``setlocale(LC_ALL, "C")`` and never restores it in

* ``Point2Array.to_str``, ``Point3Array.to_str``, ``Point4Array.to_str`` (``pa*_to_str`` in PlantGL's
  ``src/wrapper/scenegraph/export_pointarrays.cpp``) — how :mod:`lpy_light.plant.lpy` reads a tessellation's points;
* the ``.geom`` scene reader (``scne_scanner.l``, at every real number) and the ``.vgs`` reader (``vgsfile.cpp``).

With the locale ``C``, Python's default text encoding becomes ASCII (``locale.getpreferredencoding()``): after
one lit step, ``open(path, "w").write("µ")`` raises, and the L-Py IDE saves a model holding µ as an empty file.
Every entry point that calls PlantGL (:meth:`lpy_light.plant.light.LightModel.intercept`, the command line) runs
inside :func:`preserved_locale`.
"""
from __future__ import annotations

import locale
import logging
from contextlib import contextmanager

log = logging.getLogger("lpy_light")


def current_locale() -> str:
    """The process's locale, all categories (glibc: ``LC_CTYPE=...;LC_NUMERIC=...`` where they differ)."""
    return locale.setlocale(locale.LC_ALL)


@contextmanager
def preserved_locale():
    """Within the block, calls may change the C locale; on leaving it (normally or by an exception, Ctrl-C
    included) the locale is as it was on entering."""
    saved = current_locale()
    try:
        yield
    finally:
        if current_locale() != saved:
            try:
                locale.setlocale(locale.LC_ALL, saved)
            except locale.Error as exc:     # it was in force a moment ago: not expected
                log.warning("could not restore the process's locale %r (%s)", saved, exc)
