"""Organs: the plant as tagged triangle meshes inside the chamber.

An organ is what the light model reports on: a set of triangles (a leaf, an
internode, a bud) with a key (for L-Py, the module's index in the lstring), the
module's name, and the optical material of each side.  Organs are two-sided
receivers: a photon hitting the upper side of a leaf sees ``front``, one
hitting the lower side sees ``back``; each hit is tallied as *incident* on the
organ, and what the organ absorbs is tallied as *absorbed*.

Everything here is plain numpy and runs without L-Py: :func:`organ_from_mesh`
takes any ``(vertices, faces)`` pair (a :class:`trimesh.Trimesh`, or arrays),
checks it, drops degenerate triangles with one warning naming the organ, and
returns an :class:`Organ` in the chamber's units.  :class:`TessellationCache`
keeps the result for a geometry key, so that between growth steps only organs
whose geometry changed are converted again.

Materials come from the chamber's optical library by name (e.g.
``FeuilleVieille_Sup`` from ``optical/Plant/ReflectancesMean``), or as
constant values ``{"reflectance": R, "transmittance": T}``.
"""
from __future__ import annotations

import hashlib
import logging
import math
from dataclasses import dataclass

import numpy as np

from ..errors import InputError
from ..chamber.materials import ABSORB, DIFFUSE_R, DIFFUSE_T, SPECULAR_R, SPECULAR_T, Material

log = logging.getLogger("lpy_light")


@dataclass
class Organ:
    """One organ, in chamber units.

    ``triangles`` (n, 3, 3) float64; ``front``/``back`` material names (the
    front is the side the right-hand-rule normal points to); ``area`` one-sided
    area (chamber units²).
    """

    key: object
    module: str
    triangles: np.ndarray
    front: str
    back: str
    area: float
    dropped: int = 0


def _sides(material, key) -> tuple:
    if isinstance(material, str):
        return material, material
    if isinstance(material, (tuple, list)) and len(material) == 2 and all(isinstance(m, str) for m in material):
        return material[0], material[1]
    raise InputError("organ %r: material must be a name or a (front, back) pair of names, not %r" % (key, material))


def organ_from_mesh(key, mesh, material, module: str = "", scale: float = 1.0, offset=(0.0, 0.0, 0.0)) -> Organ:
    """Check a mesh and place it in the chamber: ``vertices · scale + offset``.

    ``mesh``: a :class:`trimesh.Trimesh` or a ``(vertices (v, 3), faces (f, 3))``
    pair.  Faces pointing outside the vertex list, or an empty mesh, are errors
    naming the organ; zero-area, non-finite and repeated-vertex triangles are
    dropped with one warning per organ.
    """
    front, back = _sides(material, key)
    given = (scale, offset)
    try:
        offset = np.asarray(offset, dtype=np.float64)
        scale = float(scale)
    except (TypeError, ValueError):
        offset, scale = None, math.nan
    if offset is None or offset.shape != (3,) or not np.isfinite(offset).all() or not (
            math.isfinite(scale) and scale > 0):
        raise InputError("organ %r: expected a scale > 0 and an offset (x, y, z) of finite numbers, got %r and %r"
                         % ((key,) + given))
    try:
        if hasattr(mesh, "vertices") and hasattr(mesh, "faces"):
            vertices, faces = mesh.vertices, mesh.faces
        else:
            vertices, faces = mesh
        vertices = np.asarray(vertices, dtype=np.float64)
        faces = np.asarray(faces)
    except (TypeError, ValueError) as exc:
        raise InputError("organ %r: expected a mesh or a (vertices, faces) pair (%s)" % (key, exc)) from None
    if vertices.ndim != 2 or vertices.shape[1] != 3 or faces.ndim != 2 or faces.shape[1] != 3:
        raise InputError("organ %r: expected vertices (v, 3) and faces (f, 3), got %s and %s"
                         % (key, vertices.shape, faces.shape))
    if len(faces) == 0:
        raise InputError("organ %r (%s): the mesh has no triangles" % (key, module or "?"))
    if not np.issubdtype(faces.dtype, np.integer):
        raise InputError("organ %r (%s): face indices must be integers" % (key, module or "?"))
    if faces.min() < 0 or faces.max() >= len(vertices):
        raise InputError("organ %r (%s): face index %d outside the %d vertices"
                         % (key, module or "?", faces.max() if faces.max() >= len(vertices) else faces.min(),
                            len(vertices)))
    with np.errstate(invalid="ignore", over="ignore"):     # non-finite triangles are dropped below
        tris = vertices[faces] * scale + offset
        cross = np.cross(tris[:, 1] - tris[:, 0], tris[:, 2] - tris[:, 0])
        area2 = np.linalg.norm(cross, axis=1)
        extent = np.abs(tris).max(axis=(1, 2)) if len(tris) else np.zeros(0)
    repeated = (faces[:, 0] == faces[:, 1]) | (faces[:, 1] == faces[:, 2]) | (faces[:, 0] == faces[:, 2])
    good = np.isfinite(tris).all(axis=(1, 2)) & ~repeated & (area2 > (1e-12 * np.maximum(extent, 1e-300)) ** 2)
    dropped = int((~good).sum())
    if dropped:
        log.warning("organ %r (%s): dropped %d degenerate triangle(s) of %d (zero area, NaN or repeated vertex)",
                    key, module or "?", dropped, len(tris))
    if not good.any():
        raise InputError("organ %r (%s): every triangle is degenerate" % (key, module or "?"))
    tris = np.ascontiguousarray(tris[good])
    return Organ(key, module, tris, front, back, float(0.5 * area2[good].sum()), dropped)


def mesh_key(vertices, faces) -> bytes:
    """A content key for a mesh (its bytes' digest): equal geometry, equal key."""
    h = hashlib.blake2b(digest_size=16)
    h.update(np.ascontiguousarray(vertices, dtype=np.float64).tobytes())
    h.update(np.ascontiguousarray(faces, dtype=np.int64).tobytes())
    return h.digest()


class TessellationCache:
    """Converted meshes by geometry key, kept across growth steps.

    ``get(key, make)`` returns the cached ``(vertices, faces)`` for ``key`` or
    calls ``make()`` once; keys not used during a step are forgotten at
    :meth:`end_step`, so the cache holds one plant, not its whole history.
    """

    def __init__(self):
        self._items: dict = {}
        self._used: set = set()
        self.faces: dict = {}     # topology key -> (faces, points), for lpy._tessellate (kept: a handful of them)
        self.hits = 0
        self.misses = 0

    def get(self, key, make):
        if key is None:
            self.misses += 1
            return make()
        self._used.add(key)
        if key in self._items:
            self.hits += 1
            return self._items[key]
        self.misses += 1
        value = make()
        self._items[key] = value
        return value

    def end_step(self):
        self._items = {k: v for k, v in self._items.items() if k in self._used}
        self._used = set()


def _band_values(value, what, name, chamber) -> np.ndarray:
    """(B,) values of one optical quantity: a constant for every band, or a table of the chamber's library
    (``what``: "reflectance" or "transmittance") averaged over each band."""
    n_bands = chamber.n_bands
    if not isinstance(value, str):
        return np.full(n_bands, float(value))
    optical = getattr(chamber, "optical", None)
    tables = (optical.reflectance if what == "reflectance" else optical.transmittance) if optical else {}
    if value not in tables:
        raise InputError("organ material %r: no %s table %r (known: %s)"
                         % (name, what, value, ", ".join(sorted(tables)) or "none — the scene has no 'optical' folder"))
    if chamber.bands is None:
        raise InputError("organ material %r: the scene has no bands to read its tables on" % name)
    return np.array([tables[value].band_mean(a, b) for a, b in chamber.bands])


def plant_material(spec, name: str, chamber) -> Material:
    """A :class:`Material` for organs, per the chamber's bands.

    ``spec`` is a name of the chamber's optical library (reflectance and, when
    present, transmittance tables; all diffuse), or a mapping with
    ``reflectance`` / ``transmittance`` each a constant or a table's name (and an
    optional constant ``specular`` fraction): ``{"reflectance": "FeuilleVieille_Sup"}``
    is green tissue that transmits nothing (a stem, a closed bud).
    """
    bands = chamber.bands
    n_bands = chamber.n_bands
    optical = getattr(chamber, "optical", None)
    if isinstance(spec, str):
        tables_r = optical.reflectance if optical else {}
        tables_t = optical.transmittance if optical else {}
        if spec not in tables_r and spec not in tables_t:
            known = sorted(set(tables_r) | set(tables_t))
            raise InputError("organ material %r: no optical table of that name (known: %s)"
                             % (spec, ", ".join(known) or "none — the scene has no 'optical' folder"))
        if bands is None:
            raise InputError("organ material %r: the scene has no bands to read its tables on" % spec)
        R = np.array([tables_r[spec].band_mean(a, b) for a, b in bands]) if spec in tables_r else np.zeros(n_bands)
        T = np.array([tables_t[spec].band_mean(a, b) for a, b in bands]) if spec in tables_t else np.zeros(n_bands)
        s = 0.0
    else:
        try:
            unknown = set(spec) - {"reflectance", "transmittance", "specular"}
            R = _band_values(spec.get("reflectance", 0.0), "reflectance", name, chamber)
            T = _band_values(spec.get("transmittance", 0.0), "transmittance", name, chamber)
            s = float(spec.get("specular", 0.0))
        except (AttributeError, TypeError, ValueError):
            raise InputError("organ material %r: expected a table name or {'reflectance': R, "
                             "'transmittance': T}" % (spec,)) from None
        if unknown:
            raise InputError("organ material %r: unknown key %r (expected reflectance, transmittance, specular)"
                             % (name, sorted(unknown)[0]))
        if not (np.all((0 <= R) & (R <= 1)) and np.all((0 <= T) & (T <= 1))) or (
                not isinstance(spec.get("reflectance", 0.0), str) and not isinstance(spec.get("transmittance", 0.0), str)
                and R[0] + T[0] > 1):
            raise InputError("organ material %r: expected reflectance R and transmittance T in [0, 1] with "
                             "R + T <= 1, got R = %g, T = %g" % (name, R.max(), T.max()))
    R, T = np.clip(R, 0, 1), np.clip(T, 0, 1)
    if not 0 <= s <= 1:
        raise InputError("organ material %r: specular fraction must be in [0, 1]" % (name,))
    over = R + T > 1
    if np.any(over):
        # measured leaf tables can exceed 1 in the far red (measurement noise): scale R and T down to sum 1
        b = int(np.argmax(R + T))
        log.warning("organ material %r: reflectance + transmittance = %.3f > 1 in band %s; scaled to 1 "
                    "(no absorption) in %d band(s)", name, (R + T)[b],
                    chamber.band_labels[b], int(over.sum()))
        total = np.where(over, R + T, 1.0)
        R, T = R / total, T / total
    events = np.zeros((5, n_bands))
    events[DIFFUSE_R] = R * (1 - s)
    events[SPECULAR_R] = R * s
    events[DIFFUSE_T] = T
    events[SPECULAR_T] = 0.0
    events[ABSORB] = np.clip(1 - R - T, 0, 1)
    return Material(name, "organ", events)
