"""Emission: where a photon leaves its lamp and in which direction.

Photons are shared between emitter elements in proportion to their power (``Emitters.cdf``), stratified
over a chunk; line and point lamps (SEC2's tubes and bulbs) emit isotropically from their axis or centre,
polygons, cylinders and spheres (``lamps = "lambertian"``) by a cosine law from their surface
(``lpy_light.emitters``).  Positions in scene units; the returned origin is already offset off an emitting
surface by its round-off scale.
"""
import math

from .jit import helper
from .records import EMIT_CYLINDER, EMIT_LINE, EMIT_POINT, EMIT_TRIANGLE, V_ISOTROPIC, V_LAMBERT
from .rays import magnitude
from .rng import uniform
from .sampling import cosine_hemisphere, search_cdf, to_world, uniform_sphere


@helper
def pick_element(emitters, i, count, state):
    """The element photon i of a chunk of ``count`` leaves from: stratified over the chunk by power."""
    cdf = emitters.cdf
    return search_cdf(cdf, 0, cdf.shape[0] - 1, (i + uniform(state)) / count)


@helper
def emit(e, emitters, state, offset_rel):
    """Sample an origin and a direction on emitter element e.

    Returns ``(o (3), d (3), n (3), mode, scale)``: the origin, the unit direction, the emitter's unit
    normal there (0, 0, 1 for isotropic lamps), the vertex mode (V_ISOTROPIC or V_LAMBERT) and the origin's
    round-off scale (as after a hit: the emitting triangle's and the origin's magnitudes)."""
    k = emitters.kind[e]
    data = emitters.data
    u1, u2, u3, u4 = uniform(state), uniform(state), uniform(state), uniform(state)
    if k == EMIT_LINE or k == EMIT_POINT:
        f = u1 if k == EMIT_LINE else 0.0
        ox = data[e, 0, 0] + f * (data[e, 1, 0] - data[e, 0, 0])
        oy = data[e, 0, 1] + f * (data[e, 1, 1] - data[e, 0, 1])
        oz = data[e, 0, 2] + f * (data[e, 1, 2] - data[e, 0, 2])
        dx, dy, dz = uniform_sphere(u2, u3)
        return ox, oy, oz, dx, dy, dz, 0.0, 0.0, 1.0, V_ISOTROPIC, max(abs(ox), abs(oy), abs(oz))
    if k == EMIT_TRIANGLE:
        su = math.sqrt(u1)
        b0, b1 = 1.0 - su, u2 * su
        b2 = 1.0 - b0 - b1
        ox = b0 * data[e, 0, 0] + b1 * data[e, 1, 0] + b2 * data[e, 2, 0]
        oy = b0 * data[e, 0, 1] + b1 * data[e, 1, 1] + b2 * data[e, 2, 1]
        oz = b0 * data[e, 0, 2] + b1 * data[e, 1, 2] + b2 * data[e, 2, 2]
        ax, ay, az = data[e, 1, 0] - data[e, 0, 0], data[e, 1, 1] - data[e, 0, 1], data[e, 1, 2] - data[e, 0, 2]
        bx, by, bz = data[e, 2, 0] - data[e, 0, 0], data[e, 2, 1] - data[e, 0, 1], data[e, 2, 2] - data[e, 0, 2]
        nx, ny, nz = ay * bz - az * by, az * bx - ax * bz, ax * by - ay * bx
        scale = magnitude(data[e])     # an emitting polygon is also a surface: its own round-off
    elif k == EMIT_CYLINDER:
        ax, ay, az = data[e, 1, 0] - data[e, 0, 0], data[e, 1, 1] - data[e, 0, 1], data[e, 1, 2] - data[e, 0, 2]
        length = math.sqrt(ax * ax + ay * ay + az * az)
        lx, ly, lz = to_world(math.cos(2 * math.pi * u2), math.sin(2 * math.pi * u2), 0.0,
                              ax / length, ay / length, az / length)
        r = data[e, 2, 0]
        ox, oy, oz = data[e, 0, 0] + u1 * ax + r * lx, data[e, 0, 1] + u1 * ay + r * ly, data[e, 0, 2] + u1 * az + r * lz
        nx, ny, nz = lx, ly, lz
        scale = max(abs(ox), abs(oy), abs(oz))
    else:  # EMIT_SPHERE
        nx, ny, nz = uniform_sphere(u1, u2)
        r = data[e, 1, 0]
        ox, oy, oz = data[e, 0, 0] + r * nx, data[e, 0, 1] + r * ny, data[e, 0, 2] + r * nz
        scale = max(abs(ox), abs(oy), abs(oz))
    inv = 1.0 / math.sqrt(nx * nx + ny * ny + nz * nz)
    nx, ny, nz = nx * inv, ny * inv, nz * inv
    dx, dy, dz = cosine_hemisphere(nx, ny, nz, u3, u4)
    scale += max(abs(ox), abs(oy), abs(oz), 1e-30)   # as after a hit: triangle's + origin's magnitudes
    eps = offset_rel * scale
    return ox + eps * nx, oy + eps * ny, oz + eps * nz, dx, dy, dz, nx, ny, nz, V_LAMBERT, scale
