"""Small scenes written to disk for tests, and their analytic answers."""
from __future__ import annotations

import math
from pathlib import Path

import numpy as np


def rad_polygon(material, name, points) -> str:
    pts = "\n".join("%r %r %r" % tuple(map(float, p)) for p in points)
    return "%s polygon %s\n0\n0\n%d\n%s\n\n" % (material, name, 3 * len(points), pts)


def box(material, lo, hi, inward=True) -> str:
    """Six walls of an axis-aligned box, fronts facing inward (one-sided room)."""
    (x0, y0, z0), (x1, y1, z1) = lo, hi
    faces = {
        "floor": [(x0, y0, z0), (x1, y0, z0), (x1, y1, z0), (x0, y1, z0)],
        "ceiling": [(x0, y0, z1), (x0, y1, z1), (x1, y1, z1), (x1, y0, z1)],
        "wx0": [(x0, y0, z0), (x0, y1, z0), (x0, y1, z1), (x0, y0, z1)],
        "wx1": [(x1, y0, z0), (x1, y0, z1), (x1, y1, z1), (x1, y1, z0)],
        "wy0": [(x0, y0, z0), (x0, y0, z1), (x1, y0, z1), (x1, y0, z0)],
        "wy1": [(x0, y1, z0), (x1, y1, z0), (x1, y1, z1), (x0, y1, z1)],
    }
    out = ""
    for name, pts in faces.items():
        out += rad_polygon(material, name, pts if inward else pts[::-1])
    return out


def lamp_rectangle(material, center, half, z, facing_down=True) -> str:
    cx, cy = center
    pts = [(cx - half, cy - half, z), (cx + half, cy - half, z), (cx + half, cy + half, z), (cx - half, cy + half, z)]
    return rad_polygon(material, "panel", pts[::-1] if facing_down else pts)


def sensors_csv(rows) -> str:
    return "X,Y,Z,rayon_capteur,Xnorm,Ynorm,Znorm\n" + "".join(",".join(repr(float(v)) for v in r) + "\n"
                                                             for r in rows)


def write_scene(folder: Path, rad: str, sensors=None, toml_extra: str = "") -> Path:
    folder.mkdir(parents=True, exist_ok=True)
    (folder / "scene.rad").write_text(rad)
    toml = 'geometry = "scene.rad"\n'
    if sensors is not None:
        (folder / "sensors.csv").write_text(sensors_csv(sensors))
        toml += 'sensors = "sensors.csv"\n'
    (folder / "scene.toml").write_text(toml + toml_extra)
    return folder / "scene.toml"


# --- analytic (quadrature) answers ---------------------------------------------------------
def _gauss(n, a, b):
    x, w = np.polynomial.legendre.leggauss(n)
    return 0.5 * (b - a) * x + 0.5 * (b + a), 0.5 * (b - a) * w


def rectangle_to_disc_fraction(center, half, z_src, n_src, disc_c, disc_n, radius, n=24):
    """Fraction of the photons of a Lambertian square (side 2·half, at height z_src, normal n_src =
    ±z) that cross a disc from its front:  (1/(π A)) ∫_A ∫_disc cosθ_e cosθ_r / d² dA_r dA_e."""
    xs, wx = _gauss(n, center[0] - half, center[0] + half)
    ys, wy = _gauss(n, center[1] - half, center[1] + half)
    src = np.array([[x, y, z_src] for x in xs for y in ys])
    w_src = np.outer(wx, wy).ravel()
    disc_n = np.asarray(disc_n, float) / np.linalg.norm(disc_n)
    helper = np.array([1.0, 0, 0]) if abs(disc_n[0]) < 0.9 else np.array([0, 1.0, 0])
    t = np.cross(disc_n, helper)
    t /= np.linalg.norm(t)
    b = np.cross(disc_n, t)
    rs, wr = _gauss(12, 0, radius)
    phis = 2 * np.pi * (np.arange(32) + 0.5) / 32
    pts, w_pts = [], []
    for r, w in zip(rs, wr):
        for phi in phis:
            pts.append(np.asarray(disc_c) + r * (math.cos(phi) * t + math.sin(phi) * b))
            w_pts.append(w * r * 2 * np.pi / 32)
    pts, w_pts = np.array(pts), np.array(w_pts)
    d = pts[None, :, :] - src[:, None, :]
    dist2 = (d ** 2).sum(-1)
    dist = np.sqrt(dist2)
    cos_e = (d @ np.asarray(n_src, float)) / dist
    cos_r = -(d @ disc_n) / dist
    k = np.clip(cos_e, 0, None) * np.clip(cos_r, 0, None) / dist2
    area = (2 * half) ** 2
    return float((w_src[:, None] * w_pts[None, :] * k).sum() / (np.pi * area))
