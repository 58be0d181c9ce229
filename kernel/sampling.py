"""Direction sampling for emission and scattering, with the pdfs they claim.

Every sampler maps uniform numbers ``(u1, u2)`` in [0, 1)² to a unit direction
(three floats) and has a matching ``*_pdf`` in solid-angle measure (sr⁻¹); the χ²
tests in ``tests/test_sampling.py`` check each pair against the other.
"""
import math

from numba import njit

TWO_PI = 2.0 * math.pi


@njit(inline="always", cache=True)
def search_cdf(cdf, lo, hi, u):
    """The first index i in [lo, hi] with cdf[i] > u (hi if none): the entry a uniform u draws from the
    cumulative probabilities ``cdf[lo : hi + 1]`` (ending at 1)."""
    while lo < hi:
        mid = (lo + hi) // 2
        if cdf[mid] > u:
            hi = mid
        else:
            lo = mid + 1
    return lo


@njit(inline="always", cache=True)
def frame(nx, ny, nz):
    """Two unit tangents ``(t, b)`` completing ``n`` to a right-handed frame (Duff et al. 2017)."""
    sign = 1.0 if nz >= 0.0 else -1.0
    a = -1.0 / (sign + nz)
    c = nx * ny * a
    return (1.0 + sign * nx * nx * a, sign * c, -sign * nx), (c, sign + ny * ny * a, -ny)


@njit(inline="always", cache=True)
def to_world(lx, ly, lz, nx, ny, nz):
    t, b = frame(nx, ny, nz)
    return (lx * t[0] + ly * b[0] + lz * nx,
            lx * t[1] + ly * b[1] + lz * ny,
            lx * t[2] + ly * b[2] + lz * nz)


@njit(inline="always", cache=True)
def uniform_sphere(u1, u2):
    """Isotropic direction; pdf = 1 / (4π)."""
    z = 1.0 - 2.0 * u1
    r = math.sqrt(max(0.0, 1.0 - z * z))
    phi = TWO_PI * u2
    return r * math.cos(phi), r * math.sin(phi), z


@njit(inline="always", cache=True)
def uniform_sphere_pdf(dx, dy, dz):
    return 1.0 / (4.0 * math.pi)


@njit(inline="always", cache=True)
def cosine_hemisphere(nx, ny, nz, u1, u2):
    """Lambertian (cosine-weighted) direction about unit ``n``; pdf = cos θ / π."""
    r = math.sqrt(u1)
    phi = TWO_PI * u2
    lz = math.sqrt(max(0.0, 1.0 - u1))
    return to_world(r * math.cos(phi), r * math.sin(phi), lz, nx, ny, nz)


@njit(inline="always", cache=True)
def cosine_hemisphere_pdf(nx, ny, nz, dx, dy, dz):
    c = nx * dx + ny * dy + nz * dz
    return c / math.pi if c > 0.0 else 0.0


@njit(inline="always", cache=True)
def mirror(dx, dy, dz, nx, ny, nz):
    """Perfect specular reflection of ``d`` about the plane of unit normal ``n``."""
    c = 2.0 * (dx * nx + dy * ny + dz * nz)
    return dx - c * nx, dy - c * ny, dz - c * nz


@njit(inline="always", cache=True)
def phong_lobe(ax, ay, az, exponent, u1, u2):
    """Direction about unit axis ``a`` with pdf = (e + 1) / (2π) · cos^e α (α from the axis)."""
    cos_a = u1 ** (1.0 / (exponent + 1.0))
    sin_a = math.sqrt(max(0.0, 1.0 - cos_a * cos_a))
    phi = TWO_PI * u2
    return to_world(sin_a * math.cos(phi), sin_a * math.sin(phi), cos_a, ax, ay, az)


@njit(inline="always", cache=True)
def phong_lobe_pdf(ax, ay, az, exponent, dx, dy, dz):
    c = ax * dx + ay * dy + az * dz
    return (exponent + 1.0) / TWO_PI * c ** exponent if c > 0.0 else 0.0


def phong_exponent(roughness: float) -> float:
    """Phong exponent of a specular lobe whose width follows Radiance's roughness α.

    e = 2/α² − 2 makes the rms angle between the reflected direction and the
    mirror direction equal to α (α → 0 is a mirror).  Radiance reads α as the
    rms *facet slope*, whose lobe is about twice as wide (e ≈ 1/(2α²) − 2);
    see docs/physics.md.  Returns ``inf`` for α ≤ 0.
    """
    if roughness <= 0:
        return math.inf
    return max(0.0, 2.0 / roughness ** 2 - 2.0)
