"""How the kernel is compiled (:mod:`kernel.jit`): helpers inlined by LLVM, their own libraries kept as IR."""
import numpy as np
from numba import njit

from lpy_light.kernel import jit
from lpy_light.kernel.sampling import search_cdf


@njit(cache=False)
def _caller(cdf, u):
    return search_cdf(cdf, 0, cdf.shape[0] - 1, u)


def test_helpers_are_linked_as_ir_and_their_twins_run_from_python():
    """A compiled caller inlines a helper whose own library has no machine code (``_inline_only``: numba
    neither optimises nor JIT-compiles it on its own); the helper called from Python runs its twin, a plain
    compiled function with its wrapper, and both agree."""
    cdf = np.array([0.2, 0.5, 1.0])
    assert [_caller(cdf, u) for u in (0.1, 0.3, 0.7)] == [0, 1, 2]
    assert [search_cdf(cdf, 0, 2, u) for u in (0.1, 0.3, 0.7)] == [0, 1, 2]
    assert (search_cdf.py_func.__module__, "search_cdf") in jit._HELPERS
    own = [cres.library for cres in search_cdf.overloads.values()]
    assert own and all(getattr(lib, "_inline_only", False) for lib in own)
    assert not getattr(_caller.overloads[next(iter(_caller.overloads))].library, "_inline_only", False)
