"""How the kernel's functions are compiled: one entry point, helpers inlined into it by LLVM.

:func:`kernel.trace.trace_photons` is the one compiled function Python calls (:func:`kernel.trace.trace_chunk`
allocates its work arrays); every function it calls is a :func:`helper`: compiled by numba once per argument
types, without the wrappers that calling it from Python would need, and marked for LLVM to inline at each
call (``forceinline``).  The machine code is that of one loop with every helper inlined, as with numba's own
``inline="always"``, which however re-processes the caller's whole IR at each call site: the nee kernel's
first compile took ~60 s with it, ~12 s this way (``docs/performance.md``).  Everything is cached on disk
(``cache=True``, :func:`kernel.numba_cache_dir`).

A helper's code is only ever linked into its callers, so its own library is kept as LLVM IR
(:func:`_inline_only`): numba would otherwise optimise each helper's whole subtree at every level of calls
and turn each into machine code that nothing calls (~4-5 s of the nee kernel's ~24 s cold compile).  The entry
point's module, with every helper linked in, is optimised once and compiled as before: the same machine code
(the kernel's digests are bitwise unchanged).  On a first run the helpers compile on two cores
(:mod:`kernel.warm`).
"""
from numba import config, njit
from numba.core.registry import CPUDispatcher

#: numba options of the helpers: inlined by LLVM; no Python wrapper (~4 s of the nee compile: unboxing
#: records of arrays) and no C wrapper, which only calls from outside compiled code would use
HELPER_OPTIONS = {"forceinline": True, "no_cpython_wrapper": True, "no_cfunc_wrapper": True}

#: (module, qualified name) of every helper: their code libraries are kept as IR (:func:`_inline_only`)
_HELPERS = set()


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
    _HELPERS.add((func.__module__, func.__qualname__))
    compiled = _Helper(py_func=func, locals={}, targetoptions=dict(HELPER_OPTIONS, nopython=True))
    compiled.enable_caching()
    return compiled


def _inline_only():
    """Keep the helpers' code libraries as LLVM IR for linking: no module-level optimisation of their own,
    no machine code, cached as bitcode.

    numba finalises every compiled function's library: it links in the callees' modules, runs the module
    optimisation passes over the whole, and has MCJIT emit machine code, which a helper, always inlined and
    never called through a pointer, does not need.  Its callers link its IR as before (``linkonce_odr``), and the
    entry point's library is finalised as usual.  Installed on numba's CPU target when this module is imported;
    a numba whose internals differ (the methods below missing) is left alone and compiles as before.
    """
    try:
        from numba import _dynfunc
        from numba.core import codegen, cpu
        library_cls, context_cls, codegen_cls = codegen.CPUCodeLibrary, cpu.CPUContext, codegen.JITCPUCodegen
        optimize, finalize = library_cls._optimize_final_module, library_cls._finalize_final_module
        serialize, unserialize = library_cls.serialize_using_object_code, library_cls._unserialize.__func__
        executable, set_env = context_cls.get_executable, codegen_cls.set_env
        for name in ("_finalize_dynamic_globals", "_verify_declare_only_symbols", "serialize_using_bitcode"):
            getattr(library_cls, name)            # used below: their absence means another numba
    except AttributeError:        # another numba: compile as it does
        return
    if getattr(context_cls.get_executable, "_inline_only", False):
        return

    def is_helper(library, fndesc):
        """A helper's own build: no Python wrapper (its twin for calls from Python has one)."""
        if (fndesc.modname, fndesc.qualname) not in _HELPERS:
            return False
        try:
            library._final_module.get_function(fndesc.llvm_cpython_wrapper_name)
        except NameError:
            return True
        return False

    def _optimize_final_module(self):
        if not getattr(self, "_inline_only", False):
            optimize(self)

    def _finalize_final_module(self):
        if not getattr(self, "_inline_only", False):
            return finalize(self)
        self._finalize_dynamic_globals()
        self._verify_declare_only_symbols()
        self._finalized = True

    def serialize_using_object_code(self):
        if getattr(self, "_inline_only", False):
            return self.serialize_using_bitcode()
        return serialize(self)

    def _unserialize(cls, codegen_, state):
        name, kind, data = state
        if kind == "bitcode" and any(name == q for _, q in _HELPERS):    # a helper, cached by the method above
            self = codegen_.create_library(name)
            self._inline_only = True
            self._final_module = codegen.ll.parse_bitcode(data)
            self._finalize_final_module()
            return self
        return unserialize(cls, codegen_, state)

    def get_executable(self, library, fndesc, env):
        if not is_helper(library, fndesc):
            return executable(self, library, fndesc, env)
        library._inline_only = True
        library._ensure_finalized()
        # a function object for numba's bookkeeping; its address is never called (no wrapper, always inlined)
        return _dynfunc.make_function(fndesc.lookup_module(), fndesc.qualname.split(".")[-1],
                                      "inlined helper %r" % fndesc.qualname, 0, env, (library,))

    def set_env_if_defined(self, env_name, env):
        # a helper's environment is not in the JIT engine (its code never is): nothing to point at it
        if self._engine.get_global_value_address(env_name):
            set_env(self, env_name, env)

    get_executable._inline_only = True
    codegen_cls.set_env = set_env_if_defined
    library_cls._optimize_final_module = _optimize_final_module
    library_cls._finalize_final_module = _finalize_final_module
    library_cls.serialize_using_object_code = serialize_using_object_code
    library_cls._unserialize = classmethod(_unserialize)
    context_cls.get_executable = get_executable


_inline_only()
