"""The photon kernel: Embree scene, random streams, sampling and the bounce loop.

Installed as ``lpy_light.kernel``.  It knows triangles, materials as event
tables, emitters, sensors and receivers as arrays — nothing of files or L-Py.

numba caches the kernel's compiled code in a folder named by the kernel's version (:func:`kernel_cache_dir`):
the digest of its sources and numba's version.  Every clone, venv or install of one version finds the code that
another compiled; a change to any kernel source is a new folder, so no caller is ever loaded compiled against an
older callee of another file (numba alone keys each function on its own file).
"""
from __future__ import annotations

import hashlib
import time
from pathlib import Path

#: this package's folder: its functions are cached by :class:`KernelCacheLocator`
_HERE = Path(__file__).resolve().parent
#: version folders kept in the cache's root (the most recently used; a kernel source edited is a new one)
KEEP_VERSIONS = 8
#: the file whose time says when a version folder was last used (touched at most once an hour)
_USED = "last-used"


def sources_digest(here=_HERE) -> str:
    """sha256 of the kernel's sources (every ``*.py`` in ``here``, names and contents), hex."""
    h = hashlib.sha256()
    for p in sorted(Path(here).glob("*.py")):
        h.update(p.name.encode() + b"\0" + p.read_bytes() + b"\0")
    return h.hexdigest()


def cache_root() -> Path | None:
    """Where the kernel's version folders go: ``$NUMBA_CACHE_DIR/lpy-light`` if set, else the user's cache
    (``~/.cache/lpy-light``, ``$XDG_CACHE_HOME`` if set; numba's rule for its own user-wide cache)."""
    from numba.core import config
    if config.CACHE_DIR:
        return Path(config.CACHE_DIR) / "lpy-light"
    try:
        from numba.misc.appdirs import AppDirs
        return Path(AppDirs(appname="lpy-light", appauthor=False).user_cache_dir)
    except Exception:       # noqa: BLE001 -- no home: numba's own folders (numba_cache_dir)
        return None


_DIRS = {}


def kernel_cache_dir(here=_HERE) -> Path | None:
    """The folder of this kernel version's compiled code: ``<cache_root>/kernel-<numba>-<digest>`` (the digest:
    :func:`sources_digest`, 16 digits), made if missing; None where it cannot be written (numba then caches as it
    does for any package: :func:`numba_cache_dir`).  Once per process and folder."""
    import numba
    here = Path(here).resolve()
    root = cache_root()
    if root is None:
        return None
    key = (here, str(root))
    if key not in _DIRS:
        path = root / ("kernel-%s-%s" % (numba.__version__, sources_digest(here)[:16]))
        try:
            new = not path.is_dir()
            path.mkdir(parents=True, exist_ok=True)
            used = path / _USED
            if new or not used.exists() or time.time() - used.stat().st_mtime > 3600:
                used.touch()
            if new:
                _prune(root, keep=path)
        except OSError:
            path = None
        _DIRS[key] = path
    return _DIRS[key]


def _prune(root: Path, keep: Path, versions: int = KEEP_VERSIONS) -> None:
    """Delete the version folders in ``root`` beyond the ``versions`` most recently used (``keep`` stays)."""
    import shutil

    def last_used(p):
        try:
            return (p / _USED).stat().st_mtime
        except OSError:
            return 0.0
    folders = sorted((p for p in root.glob("kernel-*") if p.is_dir() and p != keep), key=last_used, reverse=True)
    for p in folders[max(0, versions - 1):]:
        shutil.rmtree(p, ignore_errors=True)


def _locator_class():
    """numba's cache locator for the kernel's functions (:func:`kernel_cache_dir`), or None for a numba
    without the locator interface used here (it then caches as it would)."""
    from numba.core import caching
    impl = getattr(caching, "CacheImpl", None) or getattr(caching, "_CacheImpl", None)    # "_CacheImpl" in older numba
    base = getattr(caching, "_CacheLocator", None)
    if impl is None or base is None or not isinstance(getattr(impl, "_locator_classes", None), list):
        return None

    class KernelCacheLocator(base):
        """A kernel function's cache in its version's folder; its freshness stamp is the version's digest (the
        folder's name), not the file's path or time: the same in any clone of the version."""

        def __init__(self, py_func, path):
            self._lineno = py_func.__code__.co_firstlineno
            self._path = str(path)
            self._stamp = path.name

        def get_cache_path(self):
            return self._path

        def get_source_stamp(self):
            return self._stamp

        def get_disambiguator(self):
            return str(self._lineno)

        @classmethod
        def from_function(cls, py_func, py_file):
            try:
                here = Path(py_file).resolve().parent
            except (OSError, TypeError):
                return None
            if here != _HERE:
                return None             # not the kernel's: numba's own locators
            path = kernel_cache_dir(here)
            if path is None:
                return None
            self = cls(py_func, path)
            try:
                self.ensure_cache_path()
            except OSError:
                return None
            return self

    if not any(c.__name__ == "KernelCacheLocator" for c in impl._locator_classes):
        impl._locator_classes = [KernelCacheLocator] + impl._locator_classes
    return KernelCacheLocator


KernelCacheLocator = _locator_class()


def numba_cache_dir(here=_HERE) -> Path | None:
    """The folder numba caches the kernel's compiled code in: :func:`kernel_cache_dir`, or where it cannot be
    written, the folder numba would choose for any package (``numba.core.caching``): ``NUMBA_CACHE_DIR``,
    else the package's ``__pycache__`` where it is writable, else numba's user cache.  None if numba can cache
    nowhere."""
    if KernelCacheLocator is not None:
        path = kernel_cache_dir(here)
        if path is not None:
            return path
    from numba.core import caching

    def probe():
        pass

    source = str(min(Path(here).glob("*.py"), default=Path(here) / "__init__.py"))   # numba locates by a source file
    for name in ("UserProvidedCacheLocator", "InTreeCacheLocator", "UserWideCacheLocator"):
        locator = getattr(caching, name, None) or getattr(caching, "_" + name, None)   # "_" before numba 0.61
        try:
            found = locator.from_function(probe, source) if locator else None
        except OSError:
            found = None
        if found is not None:
            return Path(found.get_cache_path())
    return None


def _drop_stale_numba_cache(here=_HERE, cache=None):
    """Delete the kernel's numba cache (``cache``, default :func:`numba_cache_dir`) when any kernel source
    file changed, where the cache is not a version's own folder (:func:`kernel_cache_dir`: nothing in it can be
    stale).

    Numba keys each cached function on its *own* file only, yet a compiled function contains the code
    of what it calls in other files (``trace_chunk`` holds ``next_event`` of ``nee.py``): after an edit
    to a callee -- or an upgrade of an install whose code numba cached in the user's cache -- the caller
    would load stale code.  A digest of all the kernel's sources, kept beside the cache, makes any
    change recompile everything.  Nothing happens where the cache cannot be written.
    """
    if cache is None:
        if KernelCacheLocator is not None and kernel_cache_dir(here) is not None:
            return
        cache = numba_cache_dir(here)
        if cache is None:
            return
    cache = Path(cache)
    stamp = cache / "numba-sources.sha256"
    try:
        digest = hashlib.sha256(b"".join(p.read_bytes() for p in sorted(Path(here).glob("*.py")))).hexdigest()
        if stamp.is_file() and stamp.read_text() == digest:
            return
        cache.mkdir(exist_ok=True)
        for f in list(cache.glob("*.nbi")) + list(cache.glob("*.nbc")):
            f.unlink(missing_ok=True)
        stamp.write_text(digest)
    except OSError:
        pass


_drop_stale_numba_cache()
