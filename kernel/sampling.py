"""Direction sampling for emission and scattering, with the pdfs they claim.

Every sampler maps uniform numbers ``(u1, u2)`` in [0, 1)² to a unit direction
(three floats) and has a matching ``*_pdf`` in solid-angle measure (sr⁻¹); the χ²
tests in ``tests/test_sampling.py`` check each pair against the other.
"""
import math

from .jit import helper

TWO_PI = 2.0 * math.pi


@helper
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


@helper
def frame(nx, ny, nz):
    """Two unit tangents ``(t, b)`` completing ``n`` to a right-handed frame (Duff et al. 2017)."""
    sign = 1.0 if nz >= 0.0 else -1.0
    a = -1.0 / (sign + nz)
    c = nx * ny * a
    return (1.0 + sign * nx * nx * a, sign * c, -sign * nx), (c, sign + ny * ny * a, -ny)


@helper
def to_world(lx, ly, lz, nx, ny, nz):
    t, b = frame(nx, ny, nz)
    return (lx * t[0] + ly * b[0] + lz * nx,
            lx * t[1] + ly * b[1] + lz * ny,
            lx * t[2] + ly * b[2] + lz * nz)


@helper
def uniform_sphere(u1, u2):
    """Isotropic direction; pdf = 1 / (4π)."""
    z = 1.0 - 2.0 * u1
    r = math.sqrt(max(0.0, 1.0 - z * z))
    phi = TWO_PI * u2
    return r * math.cos(phi), r * math.sin(phi), z


@helper
def uniform_sphere_pdf(dx, dy, dz):
    return 1.0 / (4.0 * math.pi)


@helper
def cosine_hemisphere(nx, ny, nz, u1, u2):
    """Lambertian (cosine-weighted) direction about unit ``n``; pdf = cos θ / π."""
    r = math.sqrt(u1)
    phi = TWO_PI * u2
    lz = math.sqrt(max(0.0, 1.0 - u1))
    return to_world(r * math.cos(phi), r * math.sin(phi), lz, nx, ny, nz)


@helper
def cosine_hemisphere_pdf(nx, ny, nz, dx, dy, dz):
    c = nx * dx + ny * dy + nz * dz
    return c / math.pi if c > 0.0 else 0.0


@helper
def uniform_cone(ax, ay, az, omc, u1, u2):
    """A direction uniform in the cone about unit axis a whose half angle θ has 1 − cos θ = ``omc`` (2: every
    direction), from two uniforms; its density is 1 / (2π · omc)."""
    g = u1 * omc                                  # 1 − cos of the angle to the axis, uniform in the cone
    ct = 1.0 - g
    st = math.sqrt(max(g * (2.0 - g), 0.0))
    tb, bb = frame(ax, ay, az)
    cp, sp = math.cos(2.0 * math.pi * u2), math.sin(2.0 * math.pi * u2)
    return (ct * ax + st * (cp * tb[0] + sp * bb[0]), ct * ay + st * (cp * tb[1] + sp * bb[1]),
            ct * az + st * (cp * tb[2] + sp * bb[2]))


@helper
def mirror(dx, dy, dz, nx, ny, nz):
    """Perfect specular reflection of ``d`` about the plane of unit normal ``n``."""
    c = 2.0 * (dx * nx + dy * ny + dz * nz)
    return dx - c * nx, dy - c * ny, dz - c * nz


@helper
def phong_lobe(ax, ay, az, exponent, u1, u2):
    """Direction about unit axis ``a`` with pdf = (e + 1) / (2π) · cos^e α (α from the axis)."""
    cos_a = u1 ** (1.0 / (exponent + 1.0))
    sin_a = math.sqrt(max(0.0, 1.0 - cos_a * cos_a))
    phi = TWO_PI * u2
    return to_world(sin_a * math.cos(phi), sin_a * math.sin(phi), cos_a, ax, ay, az)


@helper
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


@helper
def _unit(x, y, z):
    n = math.sqrt(x * x + y * y + z * z)
    return x / n, y / n, z / n


@helper
def _cross(ax, ay, az, bx, by, bz):
    return ay * bz - az * by, az * bx - ax * bz, ax * by - ay * bx


@helper
def triangle_solid_angle(vx, vy, vz, t0, t1, t2):
    """Solid angle (sr) of the triangle of corners ``t0, t1, t2`` ((3,) each) seen from ``v``
    (Van Oosterom & Strackee 1983: stable for small and large angles alike)."""
    ax, ay, az = t0[0] - vx, t0[1] - vy, t0[2] - vz
    bx, by, bz = t1[0] - vx, t1[1] - vy, t1[2] - vz
    cx, cy, cz = t2[0] - vx, t2[1] - vy, t2[2] - vz
    la = math.sqrt(ax * ax + ay * ay + az * az)
    lb = math.sqrt(bx * bx + by * by + bz * bz)
    lc = math.sqrt(cx * cx + cy * cy + cz * cz)
    kx, ky, kz = _cross(bx, by, bz, cx, cy, cz)
    num = abs(ax * kx + ay * ky + az * kz)
    den = la * lb * lc + (ax * bx + ay * by + az * bz) * lc + (ax * cx + ay * cy + az * cz) * lb \
        + (bx * cx + by * cy + bz * cz) * la
    return 2.0 * math.atan2(num, den)


@helper
def spherical_triangle(vx, vy, vz, t0, t1, t2, u1, u2):
    """A direction from ``v`` uniform in the solid angle of the triangle ``t0, t1, t2`` (Arvo 1995);
    pdf = 1 / Ω.  Returns ``(dx, dy, dz, Ω)``; Ω = 0 (and any direction) for a triangle seen edge-on.

    Used for next events to a mesh target's triangle from a vertex close to it, where a point drawn by
    area would give an estimate ∝ 1/d², unbounded as the vertex nears the triangle: by solid angle the
    estimate is Ω · p(ω) ≤ 2π · max p, bounded however near."""
    omega = triangle_solid_angle(vx, vy, vz, t0, t1, t2)
    if not omega > 1e-12:
        return 0.0, 0.0, 1.0, 0.0
    ax, ay, az = _unit(t0[0] - vx, t0[1] - vy, t0[2] - vz)
    bx, by, bz = _unit(t1[0] - vx, t1[1] - vy, t1[2] - vz)
    cx, cy, cz = _unit(t2[0] - vx, t2[1] - vy, t2[2] - vz)
    # interior angle at a, from the normals of the great circles ab and ac
    n1x, n1y, n1z = _cross(ax, ay, az, bx, by, bz)
    n2x, n2y, n2z = _cross(ax, ay, az, cx, cy, cz)
    l1 = math.sqrt(n1x * n1x + n1y * n1y + n1z * n1z)
    l2 = math.sqrt(n2x * n2x + n2y * n2y + n2z * n2z)
    if not (l1 > 0.0 and l2 > 0.0):
        # v on the line of an edge from t0 (a point of the triangle's plane, e.g. a hit point clamped onto a shared
        # edge): the triangle is seen edge-on, though Van Oosterom's atan2(0, -0.0...) may have said 2π
        return 0.0, 0.0, 1.0, 0.0
    n1x, n1y, n1z = n1x / l1, n1y / l1, n1z / l1
    n2x, n2y, n2z = n2x / l2, n2y / l2, n2z / l2
    cos_alpha = min(1.0, max(-1.0, n1x * n2x + n1y * n2y + n1z * n2z))
    alpha = math.acos(cos_alpha)
    sin_alpha = math.sin(alpha)
    cos_c = min(1.0, max(-1.0, ax * bx + ay * by + az * bz))      # the arc a-b
    # Arvo: the point C' on arc a-c that cuts the sub-triangle of area u1 · Ω
    area = u1 * omega
    s, t = math.sin(area - alpha), math.cos(area - alpha)
    uu = t - cos_alpha
    vv = s + sin_alpha * cos_c
    den = (vv * s + uu * t) * sin_alpha
    q = ((vv * t - uu * s) * cos_alpha - vv) / den if den != 0.0 else 1.0
    q = min(1.0, max(-1.0, q))
    pc = cx * ax + cy * ay + cz * az
    ex, ey, ez = cx - pc * ax, cy - pc * ay, cz - pc * az
    en = math.sqrt(ex * ex + ey * ey + ez * ez)
    if not en > 0.0:
        return ax, ay, az, omega
    r = math.sqrt(max(0.0, 1.0 - q * q))
    hx, hy, hz = q * ax + r * ex / en, q * ay + r * ey / en, q * az + r * ez / en
    # then uniformly in z along the arc b-C'
    hb = min(1.0, max(-1.0, hx * bx + hy * by + hz * bz))
    z = 1.0 - u2 * (1.0 - hb)
    fx, fy, fz = hx - hb * bx, hy - hb * by, hz - hb * bz
    fn = math.sqrt(fx * fx + fy * fy + fz * fz)
    if not fn > 0.0:
        return bx, by, bz, omega
    r = math.sqrt(max(0.0, 1.0 - z * z))
    return z * bx + r * fx / fn, z * by + r * fy / fn, z * bz + r * fz / fn, omega
