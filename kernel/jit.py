"""How the kernel's functions are compiled: one entry point, helpers inlined into it by LLVM.

:func:`kernel.trace.trace_photons` is the one compiled function Python calls (:func:`kernel.trace.trace_chunk`
allocates its work arrays); every function it calls is a :func:`helper`: compiled by numba once per argument
types, without the wrappers that calling it from Python would need, and marked for LLVM to inline at each
call (``forceinline``).  The machine code is that of one loop with every helper inlined, as with numba's own
``inline="always"``, which however re-processes the caller's whole IR at each call site: the nee kernel's
first compile took ~60 s with it, ~12 s this way (``docs/performance.md``).  Everything is cached on disk
(``cache=True``, :func:`kernel.numba_cache_dir`).
"""
from numba import config, njit
from numba.core.registry import CPUDispatcher

#: numba options of the helpers: inlined by LLVM; no Python wrapper (~4 s of the nee compile: unboxing
#: records of arrays) and no C wrapper, which only calls from outside compiled code would use
HELPER_OPTIONS = {"forceinline": True, "no_cpython_wrapper": True, "no_cfunc_wrapper": True}


class _Helper(CPUDispatcher):
    """A helper as compiled code calls it.  Called from Python (tests), it runs a twin compiled with the
    Python wrapper it lacks: compiled on first use in each process and not cached, since numba's cache index
    does not tell the two builds apart."""

    def __call__(self, *args, **kwargs):
        twin = self.__dict__.get("_python_twin")
        if twin is None:
            twin = self._python_twin = njit(self.py_func)
        return twin(*args, **kwargs)


def helper(func):
    """Decorator of the kernel's helpers (see above)."""
    if config.DISABLE_JIT:
        return func
    compiled = _Helper(py_func=func, locals={}, targetoptions=dict(HELPER_OPTIONS, nopython=True))
    compiled.enable_caching()
    return compiled
