"""The photon kernel: Embree scene, random streams, sampling and the bounce loop.

Installed as ``lpy_light.kernel``.  It knows triangles, materials as event
tables, emitters, sensors and receivers as arrays — nothing of files or L-Py.
"""
from __future__ import annotations

import hashlib
from pathlib import Path


def numba_cache_dir(here=Path(__file__).parent) -> Path | None:
    """The folder numba caches the kernel's compiled code in, chosen as numba chooses it
    (``numba.core.caching``): ``NUMBA_CACHE_DIR`` if set, else the package's ``__pycache__`` where it is
    writable (a clone, an editable install), else the user's cache (``~/.cache/numba/…``, e.g. a
    ``pip install`` into a read-only site-packages).  None if numba can cache nowhere."""
    from numba.core import caching

    def probe():
        pass

    source = str(min(here.glob("*.py"), default=here / "__init__.py"))     # numba locates by a source file
    for name in ("UserProvidedCacheLocator", "InTreeCacheLocator", "UserWideCacheLocator"):
        locator = getattr(caching, name, None) or getattr(caching, "_" + name, None)   # "_" before numba 0.61
        try:
            found = locator.from_function(probe, source) if locator else None
        except OSError:
            found = None
        if found is not None:
            return Path(found.get_cache_path())
    return None


def _drop_stale_numba_cache(here=Path(__file__).parent, cache=None):
    """Delete the kernel's numba cache (``cache``, default :func:`numba_cache_dir`) when any kernel source
    file changed.

    Numba keys each cached function on its *own* file only, yet a compiled function contains the code
    of what it calls in other files (``trace_chunk`` holds ``next_event`` of ``nee.py``): after an edit
    to a callee -- or an upgrade of an install whose code numba cached in the user's cache -- the caller
    would load stale code.  A digest of all the kernel's sources, kept beside the cache, makes any
    change recompile everything.  Nothing happens where the cache cannot be written.
    """
    cache = Path(cache) if cache is not None else numba_cache_dir(here)
    if cache is None:
        return
    stamp = cache / "numba-sources.sha256"
    try:
        digest = hashlib.sha256(b"".join(p.read_bytes() for p in sorted(here.glob("*.py")))).hexdigest()
        if stamp.is_file() and stamp.read_text() == digest:
            return
        cache.mkdir(exist_ok=True)
        for f in list(cache.glob("*.nbi")) + list(cache.glob("*.nbc")):
            f.unlink(missing_ok=True)
        stamp.write_text(digest)
    except OSError:
        pass


_drop_stale_numba_cache()
