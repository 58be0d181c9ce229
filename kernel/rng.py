"""Counter-based random numbers: one independent SplitMix64 stream per photon.

A photon's stream depends only on ``(seed, photon index)``, so results depend on
the seed alone and never on how photons are spread over threads.
"""
import numpy as np
from numba import uint64

from .jit import helper

_GOLDEN = uint64(0x9E3779B97F4A7C15)
_M1 = uint64(0xBF58476D1CE4E5B9)
_M2 = uint64(0x94D049BB133111EB)
_INV_2_53 = 1.0 / 9007199254740992.0


@helper
def _mix(z):
    z = (z ^ (z >> uint64(30))) * _M1
    z = (z ^ (z >> uint64(27))) * _M2
    return z ^ (z >> uint64(31))


@helper
def seed_stream(state, seed, index):
    """Start the stream of photon ``index`` in ``state`` (a uint64 array of length 1)."""
    state[0] = _mix(_mix(uint64(seed) + _GOLDEN) ^ (uint64(index) * _GOLDEN + _M2))


@helper
def uniform(state):
    """Next double in [0, 1) with 53 random bits."""
    state[0] += _GOLDEN
    return float(_mix(state[0]) >> uint64(11)) * _INV_2_53


@helper
def n_draws(mean, state):
    """A random whole number whose mean is ``mean`` (≥ 0): int(mean), plus one with probability frac(mean);
    no random number is used when ``mean`` is whole."""
    n = int(mean)
    if mean - n > 0.0 and uniform(state) < mean - n:
        n += 1
    return n


def new_state():
    return np.zeros(1, dtype=np.uint64)
