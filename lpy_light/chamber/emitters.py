"""Light sources: Radiance ``light``/``glow`` surfaces as photon emitters.

===========  ==========================  ==================================================
surface      ``lamps = "line"`` (SEC2)    ``lamps = "lambertian"`` (Radiance)
===========  ==========================  ==================================================
cylinder     isotropic line source on    Lambertian emission from the cylinder's outer
             its axis                     surface
sphere       isotropic point at centre    Lambertian emission from the sphere's surface
polygon      Lambertian, front face       same
ring         Lambertian, front face       same
SEC2 point   isotropic point              same
===========  ==========================  ==================================================

Photons are shared between emitters in proportion to their power
Φ = π · L · A (L: mean of the RGB radiance, A: emitting area; for line and point
sources the area of the cylinder or sphere they stand for), so identical lamps
get identical shares.  SEC2's ``point``/``point_light`` have no area: their light's
value is read as a radiant intensity I, Φ = 4π · I.  Within a chunk the choice is
stratified.

A lamp's output may differ by band (``output``, set by a scene's ``[lamps.NAME]`` table, e.g. a fitted
chamber: :mod:`lpy_light.calibration.calibrate`): element e's power in band b is ``power[e] · output[e, b]``.  Photons
are then shared in proportion to ``power · mean_b output`` and start with the weight ``output / mean_b
output`` in each band; without ``output`` every weight starts at 1, as before.
"""
from __future__ import annotations

import math
from dataclasses import dataclass

import numpy as np

from .geometry import triangle_areas
from ..kernel.emission import EMIT_CYLINDER, EMIT_LINE, EMIT_POINT, EMIT_SPHERE, EMIT_TRIANGLE  # the kinds, once
from ..kernel.vectors import norm as vnorm


@dataclass
class Emitters:
    """E emitter elements: ``kind`` (E,) int32, ``data`` (E, 3, 3) float64, ``power`` (E,) float64,
    ``name`` (E,) identifiers of the surfaces they come from; ``output`` (E, B) each element's relative output
    per band, or None (1 in every band)."""

    kind: np.ndarray
    data: np.ndarray
    power: np.ndarray
    name: list
    output: np.ndarray | None = None

    def __len__(self):
        return len(self.kind)

    @property
    def sampled_power(self) -> np.ndarray:
        """(E,) what photons are shared by: ``power · mean_b output``."""
        return self.power if self.output is None else self.power * self.output.mean(axis=1)

    @property
    def cdf(self) -> np.ndarray:
        c = np.cumsum(self.sampled_power)
        return c / c[-1]

    def start_weight(self, n_bands: int) -> np.ndarray:
        """(E, B) a photon's weight per band as it leaves element e: ``output / mean_b output`` (1 without)."""
        if self.output is None:
            return np.ones((len(self.kind), n_bands))
        mean = self.output.mean(axis=1, keepdims=True)
        return np.divide(self.output, mean, out=np.zeros_like(self.output), where=mean > 0)

    def band_share(self) -> np.ndarray | None:
        """(B,) Σ_e power·output[e, b] / Σ_e power·mean_b output[e]: the expected start weight of a photon in
        each band (None without ``output``: 1 in every band)."""
        if self.output is None:
            return None
        return (self.power[:, None] * self.output).sum(axis=0) / self.sampled_power.sum()


class EmitterBuilder:
    def __init__(self, lamps: str = "line"):
        if lamps not in ("line", "lambertian"):
            raise ValueError("lamps must be 'line' or 'lambertian'")
        self.lamps = lamps
        self.kind, self.data, self.power, self.name = [], [], [], []

    def _add(self, kind, data, power, name):
        d = np.zeros((3, 3))
        d[:len(data)] = data
        self.kind.append(kind)
        self.data.append(d)
        self.power.append(power)
        self.name.append(name)

    def triangles(self, tris, radiance, name):
        for tri, area in zip(tris, triangle_areas(tris)):
            if area > 0:
                self._add(EMIT_TRIANGLE, tri, math.pi * radiance * float(area), name)   # inf, not a warning

    def cylinder(self, p0, p1, radius, radiance, name):
        area = 2 * math.pi * radius * vnorm(np.subtract(p1, p0))
        kind = EMIT_LINE if self.lamps == "line" else EMIT_CYLINDER
        self._add(kind, [p0, p1, [radius, 0, 0]], math.pi * radiance * area, name)

    def sphere(self, center, radius, radiance, name):
        kind = EMIT_POINT if self.lamps == "line" else EMIT_SPHERE
        self._add(kind, [center, [radius, 0, 0]], math.pi * radiance * 4 * math.pi * radius ** 2, name)

    def point(self, center, intensity, name):
        """SEC2's point light: isotropic from ``center``, power 4π · ``intensity`` (whatever ``lamps`` says)."""
        self._add(EMIT_POINT, [center], 4 * math.pi * intensity, name)

    def build(self) -> Emitters:
        return Emitters(np.array(self.kind, np.int32), np.array(self.data).reshape(-1, 3, 3),
                        np.array(self.power, float), list(self.name))
