"""The photon kernel: Embree scene, random streams, sampling and the bounce loop.

Installed as ``lpy_light.kernel``.  It knows triangles, materials as event
tables, emitters, sensors and receivers as arrays — nothing of files or L-Py.
"""
import hashlib
from pathlib import Path


def _drop_stale_numba_cache(here=Path(__file__).parent):
    """Delete the kernel's numba cache when any kernel source file changed.

    Numba keys each cached function on its *own* file's timestamp only, yet a compiled function
    contains the code of what it calls in other files (``trace_chunk`` holds ``next_event`` of
    ``nee.py``): after an edit to a callee, the caller would load stale code.  A digest of all the
    kernel's sources, kept beside the cache, makes any edit recompile everything.  Nothing happens
    where the package folder is read-only (numba then caches elsewhere, and installs do not change).
    """
    cache = here / "__pycache__"
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
