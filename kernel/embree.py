"""Embree 4 through the ``libembree4`` shipped in the ``embreex`` wheel.

embreex's Python ``run()`` traces one batch per call with ``tnear = 0`` and no
filter callbacks.  The photon kernel needs more: one-sided surfaces (a hit on a
back face is ignored *inside* the traversal, so a coincident front face behind it
is still found), transparent sensors that record every crossing without
stopping the ray, and a compiled bounce loop.  So we bind the handful of C
functions we need with ``ctypes`` and hand their addresses to numba.

Geometry layout of a :class:`EmbreeScene` (geometry ids are fixed):

====  ==================  ===================================================
id    name                behaviour
====  ==================  ===================================================
0     ``one_sided``       triangles hit only from the side their normal faces
1     ``two_sided``       triangles hit from both sides (leaves, opt-in)
2     ``sensors``         bounding quads of transparent sensors; every
                          crossing is recorded and the ray goes on
3     ``organs``          the plant: two-sided triangles, replaced between
                          growth steps (:meth:`EmbreeScene.set_organs`)
                          while the chamber's geometries stay built
                          (one-sided on request: an ablation)
====  ==================  ===================================================
"""
from __future__ import annotations

import ctypes
import glob
import os

import numpy as np
from numba import cfunc, types

from . import raylog
from .ptr import load_f32, load_i64, load_u32, load_u64, store_f32, store_i32, store_i64, store_u32

GEOM_ONE_SIDED, GEOM_TWO_SIDED, GEOM_SENSORS, GEOM_ORGANS = 0, 1, 2, 3
INVALID_ID = 0xFFFFFFFF

# --- byte layout of one thread's scratch block (see trace.py) ---------------------------
RAYHIT = 0            # struct RTCRayHit (ray 48 bytes, then hit)
ARGS = 128            # struct RTCIntersectArguments
CONTEXT = 192         # struct RTCRayQueryContext, followed by our candidate list
CAND_COUNT = CONTEXT + 64
CAND = CAND_COUNT + 8  # (uint32 primID, float32 t) pairs
CAND_CAP = 512
# the ray log (kernel.raylog; 0: none): each ray cast is appended as 8 float32 (origin, direction, tfar, kind)
LOG = CAND + 8 * CAND_CAP + 64      # u64: address of the log's rows
LOG_COUNT = LOG + 8                 # u64: address of the rows' counter (int64), shared by a run's scratch blocks
LOG_CAP = LOG + 16                  # i64: rows the log holds (rays past it are counted, not written)
SCRATCH_BYTES = LOG + 64

# offsets inside RTCRayHit
ORG, TNEAR, DIR, TFAR, MASK, FLAGS = 0, 12, 16, 32, 36, 44
NG, HIT_U, HIT_V, PRIM_ID, GEOM_ID, INST_ID = 48, 60, 64, 68, 72, 76

# enums (embree4/rtcore_*.h)
_GEOMETRY_TYPE_TRIANGLE = 0
_BUFFER_TYPE_INDEX, _BUFFER_TYPE_VERTEX = 0, 1
_FORMAT_UINT3, _FORMAT_FLOAT3 = 0x5003, 0x9003
_SCENE_FLAG_ROBUST = 1 << 2
_BUILD_QUALITY_HIGH = 2
FEATURE_ALL = 0xFFFFFFFF

#: Embree's device configuration.  Embree picks its code path (BVH layout, SIMD width of the triangle tests)
#: from the CPU, and each path rounds its ray tests its own way (as do Intel's and AMD's approximate
#: reciprocals on one path): the kernel takes only which triangle a ray meets from Embree and computes where
#: itself (:func:`kernel.rays.hit_point`), and the path is capped at AVX2, the widest every x86-64 server since
#: ~2013 runs; speed is the same within noise (Angers, 1e7 photons, nee: 8.1-9.4 s either way on an AVX-512
#: machine).  Which machines still give the same bits: :mod:`kernel.fingerprint`.
#: ``LPY_LIGHT_EMBREE_ISA`` (sse4.2, avx, avx2) takes another of Embree's code paths on this machine: how the
#: tests see what another processor's rounding does to a run (``tests/test_kernel_digests.py``).
DEVICE_CONFIG = b"verbose=0,max_isa=" + os.environ.get("LPY_LIGHT_EMBREE_ISA", "avx2").encode()


def _find_library() -> str:
    import embreex

    root = os.path.dirname(os.path.dirname(embreex.__file__))
    patterns = ["embreex.libs/libembree4*", "embreex/.dylibs/libembree4*", "embreex.libs/embree4*.dll",
                "embreex/libembree4*", "embreex/embree4*.dll"]
    for pattern in patterns:
        found = sorted(glob.glob(os.path.join(root, pattern)))
        if found:
            return found[0]
    raise ImportError("libembree4 not found beside the embreex package (looked in %s)" % root)


def _bind():
    lib = ctypes.CDLL(_find_library())
    p, u32, i32, sz = ctypes.c_void_p, ctypes.c_uint32, ctypes.c_int, ctypes.c_size_t
    sigs = {
        "rtcNewDevice": (p, [ctypes.c_char_p]),
        "rtcReleaseDevice": (None, [p]),
        "rtcGetDeviceError": (i32, [p]),
        "rtcNewScene": (p, [p]),
        "rtcSetSceneFlags": (None, [p, i32]),
        "rtcSetSceneBuildQuality": (None, [p, i32]),
        "rtcCommitScene": (None, [p]),
        "rtcReleaseScene": (None, [p]),
        "rtcNewGeometry": (p, [p, i32]),
        "rtcSetNewGeometryBuffer": (p, [p, i32, u32, i32, sz, sz]),
        "rtcSetGeometryIntersectFilterFunction": (None, [p, p]),
        "rtcSetGeometryOccludedFilterFunction": (None, [p, p]),
        "rtcCommitGeometry": (None, [p]),
        "rtcAttachGeometryByID": (None, [p, p, u32]),
        "rtcDetachGeometry": (None, [p, u32]),
        "rtcReleaseGeometry": (None, [p]),
    }
    for name, (res, args) in sigs.items():
        fn = getattr(lib, name)
        fn.restype, fn.argtypes = res, args
    return lib


_lib = None


def lib():
    global _lib
    if _lib is None:
        _lib = _bind()
    return _lib


def intersect1_address() -> int:
    """Address of ``rtcIntersect1(scene, rayhit*, args*)`` for :func:`kernel.ptr.call_ptr3`."""
    return ctypes.cast(lib().rtcIntersect1, ctypes.c_void_p).value


def occluded1_address() -> int:
    """Address of ``rtcOccluded1(scene, ray*, args*)`` (shadow rays; ``tfar`` becomes -inf when blocked).

    ``RTCOccludedArguments`` starts like ``RTCIntersectArguments`` (flags,
    feature mask, context), so one scratch block serves both calls."""
    return ctypes.cast(lib().rtcOccluded1, ctypes.c_void_p).value


# --- filter callbacks (C ABI, compiled once and cached) -----------------------------------
# struct RTCFilterFunctionNArguments { int* valid; void* userPtr; context*; RTCRayN* ray;
#                                      RTCHitN* hit; unsigned N; }  -- N == 1 for rtcIntersect1,
# for which RTCRayN/RTCHitN have the single-ray layout.

@cfunc(types.void(types.uint64), cache=True)
def _reject_back_faces(args):
    ray = load_u64(args + 24)
    hit = load_u64(args + 32)
    cos = (load_f32(ray + 16) * load_f32(hit + 0) + load_f32(ray + 20) * load_f32(hit + 4)
           + load_f32(ray + 24) * load_f32(hit + 8))
    # Embree's Ng is the right-hand-rule normal: a front hit has cos < 0.
    if cos >= 0.0:
        store_i32(load_u64(args), 0)


@cfunc(types.void(types.uint64), cache=True)
def _record_sensor_crossing(args):
    ctx = load_u64(args + 16)
    ray = load_u64(args + 24)
    hit = load_u64(args + 32)
    n = load_i64(ctx + 64)
    if n < CAND_CAP:
        store_u32(ctx + 72 + 8 * n, load_u32(hit + 20))
        store_f32(ctx + 76 + 8 * n, load_f32(ray + 32))
    store_i64(ctx + 64, n + 1)
    store_i32(load_u64(args), 0)


class EmbreeScene:
    """A committed Embree scene of up to four triangle geometries (see module doc).

    Parameters
    ----------
    one_sided, two_sided, sensors : (n, 3, 3) float arrays or None
        Triangles by vertex, in scene units.  Their row order is the ``primID``
        Embree reports within each geometry.
    """

    def __init__(self, one_sided=None, two_sided=None, sensors=None):
        L = lib()
        self._device = L.rtcNewDevice(DEVICE_CONFIG)
        if not self._device:
            raise RuntimeError("Embree could not create a device")
        self._scene = L.rtcNewScene(self._device)
        L.rtcSetSceneFlags(self._scene, _SCENE_FLAG_ROBUST)
        L.rtcSetSceneBuildQuality(self._scene, _BUILD_QUALITY_HIGH)
        filters = {GEOM_ONE_SIDED: _reject_back_faces.address, GEOM_TWO_SIDED: None,
                   GEOM_SENSORS: _record_sensor_crossing.address}
        for gid, tris in ((GEOM_ONE_SIDED, one_sided), (GEOM_TWO_SIDED, two_sided), (GEOM_SENSORS, sensors)):
            if tris is not None and len(tris):
                self._attach(gid, np.asarray(tris, dtype=np.float64), filters[gid])
        self._has_organs = False
        self._commit()

    def _commit(self):
        L = lib()
        L.rtcCommitScene(self._scene)
        err = L.rtcGetDeviceError(self._device)
        if err:
            raise RuntimeError("Embree error %d while building the scene" % err)

    def set_organs(self, tris, one_sided=False):
        """Replace the organ geometry (id 3) by ``tris`` (n, 3, 3) and recommit; the rest is kept.
        ``one_sided``: back faces are ignored as on geometry 0 (an ablation, not a leaf)."""
        if self._has_organs:
            lib().rtcDetachGeometry(self._scene, GEOM_ORGANS)
            self._has_organs = False
        if tris is not None and len(tris):
            self._attach(GEOM_ORGANS, np.asarray(tris, dtype=np.float64),
                         _reject_back_faces.address if one_sided else None)
            self._has_organs = True
        self._commit()

    def _attach(self, gid, tris, filter_address):
        L = lib()
        n = len(tris)
        geom = L.rtcNewGeometry(self._device, _GEOMETRY_TYPE_TRIANGLE)
        vbuf = L.rtcSetNewGeometryBuffer(geom, _BUFFER_TYPE_VERTEX, 0, _FORMAT_FLOAT3, 12, 3 * n)
        ibuf = L.rtcSetNewGeometryBuffer(geom, _BUFFER_TYPE_INDEX, 0, _FORMAT_UINT3, 12, n)
        if not vbuf or not ibuf:
            raise MemoryError("Embree could not allocate buffers for %d triangles" % n)
        np.ctypeslib.as_array((ctypes.c_float * (9 * n)).from_address(vbuf))[:] = \
            tris.reshape(-1).astype(np.float32)
        np.ctypeslib.as_array((ctypes.c_uint32 * (3 * n)).from_address(ibuf))[:] = np.arange(3 * n, dtype=np.uint32)
        if filter_address is not None:
            L.rtcSetGeometryIntersectFilterFunction(geom, filter_address)
            L.rtcSetGeometryOccludedFilterFunction(geom, filter_address)
        L.rtcCommitGeometry(geom)
        L.rtcAttachGeometryByID(self._scene, geom, gid)
        L.rtcReleaseGeometry(geom)

    @property
    def handle(self) -> int:
        return int(self._scene)

    def close(self):
        if getattr(self, "_scene", None):
            lib().rtcReleaseScene(self._scene)
            self._scene = None
        if getattr(self, "_device", None):
            lib().rtcReleaseDevice(self._device)
            self._device = None

    def __del__(self):
        try:
            self.close()
        except Exception:  # interpreter shutdown
            pass


def new_scratch() -> np.ndarray:
    """One thread's scratch block: RTCRayHit, arguments and query context, 64-byte aligned.

    Returns a uint8 view whose ``ctypes.data`` is the block's base address.
    """
    raw = np.zeros(SCRATCH_BYTES + 64, dtype=np.uint8)
    shift = (-raw.ctypes.data) % 64
    block = raw[shift:shift + SCRATCH_BYTES]
    base = block.ctypes.data
    args = block[ARGS:ARGS + 64].view(np.uint32)
    args[0] = 0                     # RTC_RAY_QUERY_FLAG_INCOHERENT
    args[1] = FEATURE_ALL
    block[ARGS + 8:ARGS + 16].view(np.uint64)[0] = base + CONTEXT   # context*
    raylog.attach(block[LOG:LOG + 24].view(np.uint64))
    return block
