"""The arithmetic a run's bits depend on, as one short hash: which machines give the same numbers bit for bit.

A run's numbers are a function of its scene, seed and photon count, and of the arithmetic that computes them.
The kernel's own arithmetic is plain IEEE double precision compiled by numba (the same bits on every x86-64
processor for one numba/LLVM version), but three things beneath it are not fixed by the IEEE standard:

* **Embree's ray tests** run on the processor's SIMD path and divide through an approximate reciprocal
  (``rcpps`` and a Newton step), whose last bits differ between Intel and AMD and between Embree's code paths
  (SSE4.2, AVX, AVX2, AVX-512).  The kernel takes only *which* triangle a ray meets from Embree and computes
  *where* itself (:func:`kernel.rays.hit_point`), so most of those bits never reach a tally; but a ray that
  grazes an edge, or two surfaces within a rounding of each other, can still meet another triangle there,
  and the photon's path then parts from the other machine's.
* **numpy's** and **libm's** transcendental functions (``sin``, ``exp``, ``arctan2``...), dispatched by
  processor (numpy's AVX-512 and AVX2 loops round differently; glibc picks FMA variants).
* **the versions** of numba, llvmlite, numpy, Embree (embreex) and trimesh.

:func:`arithmetic_fingerprint` hashes the answers of each of these to fixed questions: 4,096 rays through a
fixed set of triangles (Embree's t, barycentrics, normal and triangle as returned, the hits and misses of
rays aimed at shared edges), the transcendental functions of numpy and of compiled code on fixed arguments,
and the versions.  Two machines with the same fingerprint give the same numbers for the same run (that is
what ``tests/test_kernel_digests.py`` asserts where its digests were recorded); two with different ones give
the same *statistics* -- every tally within its standard error of the other's -- not the same bits.
"""
from __future__ import annotations

import hashlib
import math

import numpy as np
from numba import njit

from . import embree
from .embree import ARGS, DIR, GEOM_ID, HIT_U, HIT_V, INVALID_ID, NG, PRIM_ID, RAYHIT, TFAR
from .ptr import call_ptr3, load_f32, load_u32
from .rays import set_ray

_RAYS = 4096


def _probe_triangles() -> np.ndarray:
    """(n, 3, 3) triangles: a fan around a point (many rays near shared edges), slivers, a tilted pair
    sharing an edge, two nearly coincident sheets; coordinates at a chamber's scale (mm)."""
    rng = np.random.default_rng(20261128)
    tris = []
    centre = np.array([500.0, 400.0, 300.0])
    angles = np.linspace(0.0, 2.0 * np.pi, 17)
    for a0, a1 in zip(angles[:-1], angles[1:]):
        tris.append([centre, centre + 300.0 * np.array([np.cos(a0), np.sin(a0), 0.1]),
                     centre + 300.0 * np.array([np.cos(a1), np.sin(a1), 0.1])])
    for k in range(8):                                   # slivers, as leaf fans have
        x = 100.0 + 97.3 * k
        tris.append([[x, 0.0, 700.0], [x + 400.0, 3.0e-3 * (k + 1), 701.0], [x + 400.0, 0.0, 700.5]])
    tris += [[[0, 0, 900.0], [1000, 0, 950.0], [0, 1000, 900.0]],
             [[1000, 0, 950.0], [1000, 1000, 950.0], [0, 1000, 900.0]],
             [[0, 0, 1000.0], [1000, 0, 1000.0], [0, 1000, 1000.0]],
             [[0, 0, 1000.0 + 1e-4], [1000, 0, 1000.0 + 1e-4], [0, 1000, 1000.0 + 1e-4]]]
    tris = np.asarray(tris, dtype=np.float64)
    return tris + rng.normal(scale=1e-3, size=tris.shape)


def _probe_rays(tris: np.ndarray) -> np.ndarray:
    """(n, 6) rays (origin, unit direction) aimed at points of the triangles, half of them on an edge."""
    rng = np.random.default_rng(7)
    k = rng.integers(0, len(tris), _RAYS)
    u, v = rng.random(_RAYS), rng.random(_RAYS)
    flip = u + v > 1.0
    u[flip], v[flip] = 1.0 - u[flip], 1.0 - v[flip]
    v[: _RAYS // 2] = 1.0 - u[: _RAYS // 2]              # on the edge between vertices 1 and 2
    a = tris[k]
    target = a[:, 0] + u[:, None] * (a[:, 1] - a[:, 0]) + v[:, None] * (a[:, 2] - a[:, 0])
    origin = target + rng.normal(scale=400.0, size=target.shape)
    d = target - origin
    d /= np.sqrt((d * d).sum(axis=1))[:, None]
    return np.hstack([origin, d])


@njit(cache=True)
def _trace_probe(intersect, scene, scratch, rays, out):
    """Embree's raw answer for each ray: t, u, v, Ng (float32 as returned) and the triangle, (n, 7) float64."""
    for i in range(rays.shape[0]):
        r = rays[i]
        set_ray(scratch, r[0], r[1], r[2], r[3], r[4], r[5], 1.0e30)
        call_ptr3(intersect, scene, scratch + RAYHIT, scratch + ARGS)
        rh = scratch + RAYHIT
        gid = load_u32(rh + GEOM_ID)
        if gid == INVALID_ID:
            out[i, 6] = -1.0
            continue
        out[i, 0] = load_f32(rh + TFAR)
        out[i, 1] = load_f32(rh + HIT_U)
        out[i, 2] = load_f32(rh + HIT_V)
        for j in range(3):
            out[i, 3 + j] = load_f32(rh + DIR + 32 + 4 * j)     # Ng follows the ray (DIR + 32 = NG)
        out[i, 6] = load_u32(rh + PRIM_ID)


@njit(cache=True)
def _compiled_math(x):
    out = np.empty((x.shape[0], 7))
    for i in range(x.shape[0]):
        a = x[i]
        out[i, 0] = math.sin(a * 100.0)
        out[i, 1] = math.cos(a * 100.0)
        out[i, 2] = math.exp(a * 10.0)
        out[i, 3] = math.log(a + 1e-3)
        out[i, 4] = math.atan2(a - 0.5, 0.3)
        out[i, 5] = math.acos(2.0 * a - 1.0)
        out[i, 6] = math.pow(a + 0.1, 2.4)
    return out


def _embree_answers() -> np.ndarray:
    tris = _probe_triangles()
    scene = embree.EmbreeScene(two_sided=tris)
    scratch = embree.new_scratch()
    rays = _probe_rays(tris)
    out = np.zeros((len(rays), 7))
    assert DIR + 32 == NG
    _trace_probe(embree.intersect1_address(), scene.handle, scratch.ctypes.data, rays, out)
    scene.close()
    return out


def _numpy_answers() -> list:
    x = np.random.default_rng(3).random(4099)          # an odd length: every SIMD loop's tail as well
    return [np.sin(x * 100.0), np.cos(x * 100.0), np.exp(x * 10.0), np.log(x + 1e-3), np.arctan2(x - 0.5, 0.3),
            np.arccos(2.0 * x - 1.0), np.power(x + 0.1, 2.4), np.sqrt(x), np.tan(x), np.expm1(x), np.log1p(x),
            x.sum(), np.cumsum(x), x.astype(np.float32).sum()]


def versions() -> dict:
    """The versions a run's numbers depend on."""
    import embreex
    import llvmlite
    import numba
    import trimesh

    return {"numpy": np.__version__, "numba": numba.__version__, "llvmlite": llvmlite.__version__,
            "embreex": getattr(embreex, "__version__", "?"), "trimesh": trimesh.__version__,
            "embree_config": embree.DEVICE_CONFIG.decode()}


_CACHED = None


def arithmetic_fingerprint() -> str:
    """16 hex digits: equal on two machines (and environments) that give a run the same numbers bit for bit.
    Computed once per process (~0.1 s after numba's cache is warm)."""
    global _CACHED
    if _CACHED is None:
        h = hashlib.sha256()
        for part in [_embree_answers(), _compiled_math(np.random.default_rng(5).random(1021))] + _numpy_answers():
            a = np.ascontiguousarray(np.asarray(part, dtype=np.float64))
            h.update(a.tobytes())
        h.update(repr(sorted(versions().items())).encode())
        _CACHED = h.hexdigest()[:16]
    return _CACHED


def describe() -> dict:
    """The fingerprint with what it stands for, for a run's summary: processor, versions."""
    import platform

    cpu = platform.processor() or platform.machine()
    try:
        with open("/proc/cpuinfo") as f:
            cpu = next((line.split(":", 1)[1].strip() for line in f if line.startswith("model name")), cpu)
    except OSError:
        pass
    return {"fingerprint": arithmetic_fingerprint(), "cpu": cpu, "versions": versions()}


if __name__ == "__main__":
    import json

    print(json.dumps(describe(), indent=1))
