"""How the kernel's functions are compiled: one entry point, helpers inlined into it by LLVM.

:func:`kernel.trace.trace_photons` is the one compiled function Python calls (:func:`kernel.trace.trace_chunk`
allocates its work arrays); every function it calls is a :data:`helper`: compiled by numba once per argument
types, without the wrappers that calling it from Python would need, and marked for LLVM to inline at each
call (``forceinline``).  The machine code is that of one loop with every helper inlined, as with numba's own
``inline="always"``, which however re-processes the caller's whole IR at each call site: the nee kernel's
first compile took ~60 s with it, ~12 s this way (``docs/performance.md``).  Everything is cached on disk
(``cache=True``, :func:`kernel.numba_cache_dir`).
"""
from numba import njit

#: decorator of the kernel's helpers (see above)
helper = njit(forceinline=True, no_cpython_wrapper=True, no_cfunc_wrapper=True, cache=True)
