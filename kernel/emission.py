"""Emission: where a photon leaves its lamp and in which direction.

Photons are shared between emitter elements in proportion to their power (``Emitters.cdf``), stratified
over a chunk.  Each lamp kind (``EMIT_*``, defined here, once: :mod:`lpy_light.chamber.emitters` builds elements of
these kinds) is one sampling function: line and point lamps (SEC2's tubes and bulbs) emit isotropically from
their axis or centre; polygons, cylinders and spheres (``lamps = "lambertian"``) by a cosine law from their
surface.  :func:`emit` chooses the function by the element's kind.  Positions in scene units; the returned
origin is already offset off an emitting surface by its round-off scale.

Adding a lamp kind: its ``EMIT_*`` number and sampling function here, one line in :func:`emit`, and its
reading in :mod:`lpy_light.chamber.emitters` (``docs/architecture.md``).
"""
import math

from .jit import helper
from .records import V_ISOTROPIC, V_LAMBERT
from .rays import magnitude
from .rng import uniform
from .sampling import cosine_hemisphere, search_cdf, to_world, uniform_sphere

#: emitter element kinds (``Emitters.kind``): what ``data[e]`` holds for each is said by its sampling function
EMIT_LINE, EMIT_TRIANGLE, EMIT_CYLINDER, EMIT_POINT, EMIT_SPHERE = 0, 1, 2, 3, 4


@helper
def pick_element(emitters, i, count, state):
    """The element photon i of a chunk of ``count`` leaves from: stratified over the chunk by power."""
    cdf = emitters.cdf
    return search_cdf(cdf, 0, cdf.shape[0] - 1, (i + uniform(state)) / count)


@helper
def isotropic(data, e, f, u2, u3):
    """A point on the segment ``data[e, 0]`` → ``data[e, 1]`` at fraction ``f`` (0: the point lamp at
    ``data[e, 0]``), an isotropic direction: ``(o, d, n, mode, scale)`` as :func:`emit`."""
    ox = data[e, 0, 0] + f * (data[e, 1, 0] - data[e, 0, 0])
    oy = data[e, 0, 1] + f * (data[e, 1, 1] - data[e, 0, 1])
    oz = data[e, 0, 2] + f * (data[e, 1, 2] - data[e, 0, 2])
    dx, dy, dz = uniform_sphere(u2, u3)
    return ox, oy, oz, dx, dy, dz, 0.0, 0.0, 1.0, V_ISOTROPIC, max(abs(ox), abs(oy), abs(oz))


@helper
def on_triangle(data, e, u1, u2):
    """EMIT_TRIANGLE: a uniform point on the triangle ``data[e]`` (3 corners), its (unnormalised) normal and
    round-off scale: ``(o, n, scale)``."""
    su = math.sqrt(u1)
    b0, b1 = 1.0 - su, u2 * su
    b2 = 1.0 - b0 - b1
    ox = b0 * data[e, 0, 0] + b1 * data[e, 1, 0] + b2 * data[e, 2, 0]
    oy = b0 * data[e, 0, 1] + b1 * data[e, 1, 1] + b2 * data[e, 2, 1]
    oz = b0 * data[e, 0, 2] + b1 * data[e, 1, 2] + b2 * data[e, 2, 2]
    ax, ay, az = data[e, 1, 0] - data[e, 0, 0], data[e, 1, 1] - data[e, 0, 1], data[e, 1, 2] - data[e, 0, 2]
    bx, by, bz = data[e, 2, 0] - data[e, 0, 0], data[e, 2, 1] - data[e, 0, 1], data[e, 2, 2] - data[e, 0, 2]
    nx, ny, nz = ay * bz - az * by, az * bx - ax * bz, ax * by - ay * bx
    return ox, oy, oz, nx, ny, nz, magnitude(data[e])     # an emitting polygon is also a surface: its round-off


@helper
def on_cylinder(data, e, u1, u2):
    """EMIT_CYLINDER: a uniform point on the side of the cylinder of axis ``data[e, 0]`` → ``data[e, 1]`` and
    radius ``data[e, 2, 0]``, its outward normal and round-off scale: ``(o, n, scale)``."""
    ax, ay, az = data[e, 1, 0] - data[e, 0, 0], data[e, 1, 1] - data[e, 0, 1], data[e, 1, 2] - data[e, 0, 2]
    length = math.sqrt(ax * ax + ay * ay + az * az)
    lx, ly, lz = to_world(math.cos(2 * math.pi * u2), math.sin(2 * math.pi * u2), 0.0,
                          ax / length, ay / length, az / length)
    r = data[e, 2, 0]
    ox, oy, oz = data[e, 0, 0] + u1 * ax + r * lx, data[e, 0, 1] + u1 * ay + r * ly, data[e, 0, 2] + u1 * az + r * lz
    return ox, oy, oz, lx, ly, lz, max(abs(ox), abs(oy), abs(oz))


@helper
def on_sphere(data, e, u1, u2):
    """EMIT_SPHERE: a uniform point on the sphere of centre ``data[e, 0]`` and radius ``data[e, 1, 0]``, its
    outward normal and round-off scale: ``(o, n, scale)``."""
    nx, ny, nz = uniform_sphere(u1, u2)
    r = data[e, 1, 0]
    ox, oy, oz = data[e, 0, 0] + r * nx, data[e, 0, 1] + r * ny, data[e, 0, 2] + r * nz
    return ox, oy, oz, nx, ny, nz, max(abs(ox), abs(oy), abs(oz))


@helper
def lambertian(ox, oy, oz, nx, ny, nz, scale, u3, u4, offset_rel):
    """A cosine-law direction about the unit normal of ``n``, the origin offset off the surface by its round-off
    scale: ``(o, d, n, mode, scale)`` as :func:`emit`."""
    inv = 1.0 / math.sqrt(nx * nx + ny * ny + nz * nz)
    nx, ny, nz = nx * inv, ny * inv, nz * inv
    dx, dy, dz = cosine_hemisphere(nx, ny, nz, u3, u4)
    scale += max(abs(ox), abs(oy), abs(oz), 1e-30)   # as after a hit: triangle's + origin's magnitudes
    eps = offset_rel * scale
    return ox + eps * nx, oy + eps * ny, oz + eps * nz, dx, dy, dz, nx, ny, nz, V_LAMBERT, scale


@helper
def emit(e, emitters, state, offset_rel):
    """Sample an origin and a direction on emitter element e, by its kind's sampling function.

    Returns ``(o (3), d (3), n (3), mode, scale)``: the origin, the unit direction, the emitter's unit
    normal there (0, 0, 1 for isotropic lamps), the vertex mode (V_ISOTROPIC or V_LAMBERT) and the origin's
    round-off scale (as after a hit: the emitting triangle's and the origin's magnitudes)."""
    k = emitters.kind[e]
    data = emitters.data
    u1, u2, u3, u4 = uniform(state), uniform(state), uniform(state), uniform(state)
    if k == EMIT_LINE:
        return isotropic(data, e, u1, u2, u3)
    if k == EMIT_POINT:
        return isotropic(data, e, 0.0, u2, u3)
    if k == EMIT_TRIANGLE:
        ox, oy, oz, nx, ny, nz, scale = on_triangle(data, e, u1, u2)
    elif k == EMIT_CYLINDER:
        ox, oy, oz, nx, ny, nz, scale = on_cylinder(data, e, u1, u2)
    else:  # EMIT_SPHERE
        ox, oy, oz, nx, ny, nz, scale = on_sphere(data, e, u1, u2)
    return lambertian(ox, oy, oz, nx, ny, nz, scale, u3, u4, offset_rel)
