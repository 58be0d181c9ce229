"""χ² tests: each direction sampler draws from the pdf it claims (pbrt-style).

Directions are binned in (cos θ, φ) about the lobe axis; expected counts come from
integrating the claimed pdf over each bin.  A sampler paired with the wrong pdf
must fail the same test (so the test has power).
"""
import math

import numpy as np
import pytest
from numba import njit

from lpy_light.kernel import sampling as smp
from lpy_light.kernel.rng import new_state, seed_stream, uniform

N = 200_000
AXIS = np.array([0.3, -0.5, 0.8]) / np.linalg.norm([0.3, -0.5, 0.8])


@njit(cache=False)     # not cached: numba would not see edits to the kernel functions it calls
def _draw(kind, ax, ay, az, exponent, n, seed):
    out = np.empty((n, 3))
    state = np.zeros(1, dtype=np.uint64)
    for i in range(n):
        seed_stream(state, seed, i)
        u1, u2 = uniform(state), uniform(state)
        if kind == 0:
            d = smp.cosine_hemisphere(ax, ay, az, u1, u2)
        elif kind == 1:
            d = smp.uniform_sphere(u1, u2)
        else:
            d = smp.phong_lobe(ax, ay, az, exponent, u1, u2)
        out[i, 0], out[i, 1], out[i, 2] = d[0], d[1], d[2]
    return out


def _chi2_pvalue(chi2, dof):
    """Upper tail of χ²(dof) by the Wilson–Hilferty normal approximation."""
    z = ((chi2 / dof) ** (1 / 3) - (1 - 2 / (9 * dof))) / math.sqrt(2 / (9 * dof))
    return 0.5 * math.erfc(z / math.sqrt(2))


def _chi2(dirs, axis, cdf_cos, n_theta=20, n_phi=12, cos_range=(0.0, 1.0)):
    """χ² of directions against a pdf given by the CDF of cos θ (φ uniform)."""
    t, b = smp.frame(*axis)
    c = dirs @ axis
    phi = np.arctan2(dirs @ np.array(b), dirs @ np.array(t)) % (2 * np.pi)
    edges = np.linspace(*cos_range, n_theta + 1)
    counts, _, _ = np.histogram2d(c, phi, bins=[edges, np.linspace(0, 2 * np.pi, n_phi + 1)])
    p = np.diff([cdf_cos(e) for e in edges]) / n_phi
    expected = len(dirs) * np.repeat(p[:, None], n_phi, axis=1)
    ok = expected > 5
    chi2 = (((counts - expected) ** 2)[ok] / expected[ok]).sum()
    return _chi2_pvalue(chi2, ok.sum() - 1)


def test_cosine_hemisphere():
    d = _draw(0, *AXIS, 0.0, N, 1)
    np.testing.assert_allclose(np.linalg.norm(d, axis=1), 1, atol=1e-12)
    assert (d @ AXIS >= 0).all()
    assert _chi2(d, AXIS, lambda c: c * c) > 1e-3            # P(cos θ < c) = c² for pdf cos θ/π
    assert _chi2(d, AXIS, lambda c: c) < 1e-6                # the uniform-hemisphere pdf is rejected


def test_uniform_sphere():
    d = _draw(1, *AXIS, 0.0, N, 2)
    assert _chi2(d, AXIS, lambda c: (c + 1) / 2, cos_range=(-1, 1)) > 1e-3
    assert _chi2(d, AXIS, lambda c: ((c + 1) / 2) ** 1.1, cos_range=(-1, 1)) < 1e-6


@pytest.mark.parametrize("exponent", [1.0, 10.0, 200.0])
def test_phong_lobe(exponent):
    d = _draw(2, *AXIS, exponent, N, 3)
    lo = 0.0 if exponent < 50 else 0.9
    cdf = lambda c: (max(c, 0) ** (exponent + 1) - lo ** (exponent + 1)) / (1 - lo ** (exponent + 1))
    sel = d @ AXIS >= lo
    assert _chi2(d[sel], AXIS, cdf, cos_range=(lo, 1)) > 1e-3
    e2 = 1.2 * exponent + 1       # a lobe 20 % too narrow
    wrong = lambda c: (max(c, 0) ** (e2 + 1) - lo ** (e2 + 1)) / (1 - lo ** (e2 + 1))
    assert _chi2(d[sel], AXIS, wrong, cos_range=(lo, 1)) < 1e-6


def test_pdfs_integrate_to_one():
    """The documented pdfs integrate to 1 over their domains (midpoint rule in cos θ)."""
    c = (np.arange(20000) + 0.5) / 20000
    assert np.sum(c / math.pi) * 2 * math.pi / 20000 == pytest.approx(1, rel=1e-6)
    for e in (1.0, 10.0, 200.0):
        assert np.sum((e + 1) / (2 * math.pi) * c ** e) * 2 * math.pi / 20000 == pytest.approx(1, rel=1e-3)


def test_mirror_reflection():
    d = np.array(smp.mirror(0.6, 0.0, -0.8, 0.0, 0.0, 1.0))
    np.testing.assert_allclose(d, [0.6, 0.0, 0.8])


def test_phong_exponent_follows_roughness():
    assert smp.phong_exponent(0) == math.inf
    assert smp.phong_exponent(0.1) > smp.phong_exponent(0.3) > 0


def _subtriangles(t, levels):
    """The 4**levels triangles of ``t`` ((3, 3)) by midpoint subdivision."""
    tris = [np.asarray(t, float)]
    for _ in range(levels):
        out = []
        for a, b, c in tris:
            ab, bc, ca = (a + b) / 2, (b + c) / 2, (c + a) / 2
            out += [np.array(x) for x in ((a, ab, ca), (ab, b, bc), (ca, bc, c), (ab, bc, ca))]
        tris = out
    return tris


@pytest.mark.parametrize("v, tri", [
    ((0.0, 0.0, 0.0), ((1.0, -1.0, 1.0), (1.0, 1.0, 1.0), (-1.0, 0.0, 1.0))),            # facing, ~1.5 sr
    ((0.05, 0.02, 0.01), ((0.0, 0.0, 0.0), (3.0, 0.0, 0.0), (0.0, 2.0, 0.0))),           # right above a corner
    ((0.3, 0.2, -0.001), ((0.0, 0.0, 0.0), (3.0, 0.1, 0.0), (0.0, 2.0, 0.0))),           # just below: ~2π
    ((0.0, 0.0, 0.0), ((5.0, 0.0, 1.0), (5.0, 0.05, 1.0), (-5.0, 0.02, 1.0))),           # a sliver
])
def test_spherical_triangle_is_uniform_in_solid_angle(v, tri):
    """χ² of directions drawn by ``spherical_triangle`` over the 16 sub-triangles of a midpoint subdivision,
    each expected in proportion to its exact solid angle (Van Oosterom's formula, checked against the
    whole).  A sampler uniform by *area* fails this (the near corner gets far more solid angle)."""
    from lpy_light.kernel.sampling import spherical_triangle, triangle_solid_angle
    t = np.array(tri)
    omega = triangle_solid_angle(*v, t[0], t[1], t[2])
    subs = _subtriangles(t, 2)
    sub_omega = np.array([triangle_solid_angle(*v, s[0], s[1], s[2]) for s in subs])
    assert sub_omega.sum() == pytest.approx(omega, rel=1e-9)
    rng = np.random.default_rng(5)
    n = 40_000
    normal = np.cross(t[1] - t[0], t[2] - t[0])
    counts = np.zeros(len(subs))
    for u1, u2 in rng.random((n, 2)):
        dx, dy, dz, om = spherical_triangle(*v, t[0], t[1], t[2], u1, u2)
        assert om == pytest.approx(omega, rel=1e-12)
        d = np.array([dx, dy, dz])
        p = np.array(v) + d * (np.dot(t[0] - v, normal) / np.dot(d, normal))    # where it meets the plane
        for k, s in enumerate(subs):            # which sub-triangle (barycentric test)
            m = np.array([s[1] - s[0], s[2] - s[0]]).T
            lam = np.linalg.lstsq(m, p - s[0], rcond=None)[0]
            if lam.min() >= -1e-9 and lam.sum() <= 1 + 1e-9:
                counts[k] += 1
                break
    assert counts.sum() >= n * (1 - 1e-3)
    expected = n * sub_omega / omega
    chi2 = ((counts - expected) ** 2 / expected).sum()
    assert chi2 < 45.0, (chi2, counts, expected)          # 15 dof: p = 1e-4 at 42.6


def test_a_point_on_a_triangles_edge_sees_it_edge_on_not_a_division_by_zero():
    """A hit point clamped onto the edge t0-t2 of a bud's triangle (an edge parallel to the x axis: the
    icosphere only translated), next events to that same triangle: Van Oosterom's formula may call its solid
    angle 2π (a rounding-level negative denominator), and Arvo's sampling then crossed two antiparallel
    directions, a zero-length normal: a ZeroDivisionError that ended a 4e6-photon rose run.  Now the triangle is
    seen edge-on: Ω = 0, no deposit (no light from a point reaches the triangle it lies on)."""
    from lpy_light.kernel.sampling import spherical_triangle
    t0 = np.array([999.9524125435388, 919.9743900521419, 1163.2574993194928])
    t1 = np.array([999.3343785547889, 920.5409618166535, 1163.958800936197])
    t2 = np.array([998.7163445660391, 919.9743900521419, 1163.2574993194928])
    for x in np.linspace(998.72, 999.95, 2001):         # ~40 % of these raised before
        dx, dy, dz, omega = spherical_triangle(x, t0[1], t0[2], t0, t1, t2, 0.3, 0.7)
        assert omega == 0.0, (x, omega)
