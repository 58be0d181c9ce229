"""Dot products and lengths of single vectors, the same bits on every machine.

numpy sends a 1-d ``np.dot``, ``a @ b`` and ``np.linalg.norm(v)`` (no ``axis``) to BLAS, whose kernel is chosen
by the processor (OpenBLAS's Haswell, SkylakeX, Zen, ... kernels), and the kernels round differently: the same
scene then gave other tallies on another machine (``tests/test_kernel_digests.py``, ``tests/test_machine.py``).
These go through numpy's own loops instead.  Vectors (n,) float64; results Python floats.
"""
import math

import numpy as np


def dot(a, b) -> float:
    """Σ a_i b_i of two (n,) vectors, without BLAS."""
    return float(np.einsum("i,i->", np.asarray(a, float), np.asarray(b, float)))


def norm(a) -> float:
    """The Euclidean length of an (n,) vector, without BLAS."""
    return math.sqrt(dot(a, a))
