"""The thin L-Py / PlantGL layer: an lstring and its PlantGL scene → organs; each organ's light → its module.

:meth:`lpy_light.plant.light.LightModel.intercept` owns the step (it runs the light model); this module only converts
(:func:`plant_organs`) and writes back (:func:`write_parameters`), and knows nothing of the light model.

L-Py and PlantGL come from conda only (``environment.yml``); they are imported
lazily, inside the functions that need them.  The logic that does not need
them — grouping shapes by module, building organs, writing results into
modules — is in plain functions tested in CI with fake lstrings and trimesh
meshes.

In an ``.lpy`` file (see ``lsystems/rose.lpy``)::

    from lpy_light import LightModel
    light = LightModel(organs={"Leaf": ("FeuilleVieille_Sup", "FeuilleVieille_Inf")}, plant_unit="cm")
    module Leaf(length, light)

    def StartEach():
        frameDisplay(True)          # L-Py builds the scene only on the last step otherwise
    def EndEach(lstring, lscene):
        return light.intercept(lstring, lscene)

Facts about L-Py this follows (read in its sources, see
``docs/notes/lpy-plantgl-api.md``): ``Shape.id`` is the module's index in the
lstring and several shapes may share it; ``EndEach`` must be a plain function
and should return ``(lstring, lscene)``; in a batch ``derive()`` the scene is
``None`` on every step but the last unless ``frameDisplay(True)`` is called in
``StartEach``; PlantGL point lists have no numpy view, and converting them point
by point is slow, so we use ``Point3Array.to_str`` (one C++ loop) when present.  ``to_str`` sets the process's
locale to ``C`` and leaves it so: :meth:`LightModel.intercept` runs inside
:func:`lpy_light.process_state.preserved_locale`, which puts it back.
"""
from __future__ import annotations

import logging

import numpy as np

from ..errors import LpyLightError
from .organs import organ_from_mesh
from ..process_state import preserved_locale

log = logging.getLogger("lpy_light")

CONDA_HINT = ("L-Py and PlantGL are installed with conda, not pip: "
              "conda env create -f environment.yml (channels openalea3, conda-forge)")


def require_lpy():
    """Import and return ``openalea.lpy``, or raise a clear error."""
    try:
        import openalea.lpy as lpy
    except ImportError as exc:
        raise LpyLightError("L-Py is not importable (%s). %s" % (exc, CONDA_HINT)) from None
    return lpy


def require_plantgl():
    try:
        import openalea.plantgl.all as pgl
    except ImportError as exc:
        raise LpyLightError("PlantGL is not importable (%s). %s" % (exc, CONDA_HINT)) from None
    return pgl


# -- plain functions (no L-Py needed) --------------------------------------------------------
def organs_from_meshes_by_id(meshes_by_id: dict, module_names: dict, materials_of, scale: float,
                             position, tick=None) -> list:
    """Organs (chamber units) from ``{id: [(vertices, faces), ...]}`` in the plant's unit (a module's several
    shapes are merged into one organ).

    ``module_names`` maps id → module name; ``materials_of(module name)`` gives the module's ``(front, back)``
    material names; ``scale`` (chamber units per plant unit) and ``position`` ((3,) chamber units) place the plant.
    ``tick()``, if given, is called before each organ (the L-Py IDE's window kept alive: :mod:`lpy_light.plant.ide`).
    """
    organs = []
    for key in sorted(meshes_by_id):
        if tick is not None:
            tick()
        parts = meshes_by_id[key]
        name = module_names[key]
        vertices, faces, base = [], [], 0
        for v, f in parts:
            vertices.append(np.asarray(v, dtype=np.float64))
            faces.append(np.asarray(f, dtype=np.int64) + base)
            base += len(v)
        organs.append(organ_from_mesh(key, (np.concatenate(vertices), np.concatenate(faces)), materials_of(name),
                                      name, scale, position))
    return organs


def write_parameters(lstring, lights: dict, parameter) -> int:
    """Write ``lights[i]`` into module ``lstring[i]``; return how many were written.

    ``parameter`` is a parameter's name (``module Leaf(length, light)``: ``"light"``), its position
    (``2``: the third parameter, as L-Py's own light example writes ``lstring[k][2] = v``: models with
    positional parameters), or a mapping module name → name or position (``{"Leaf": 3, "Bud": 2}``).
    Modules without it are warned about once per module name and left unchanged.
    """
    written, missing = 0, {}
    for key, light in lights.items():
        module = lstring[key]
        where = parameter.get(module.name) if isinstance(parameter, dict) else parameter
        if where is None:
            continue
        if isinstance(where, int) and not isinstance(where, bool):
            if 0 <= where < len(module):
                module[where] = light
                written += 1
                continue
        elif module.hasParameter(where):
            module.setParameter(where, light)
            written += 1
            continue
        missing[module.name] = where
    for name, where in sorted(missing.items()):
        if isinstance(where, int):
            log.warning("module %s has no parameter at position %d: give it one more parameter to receive its light",
                        name, where)
        else:
            log.warning("module %s has no parameter %r: declare 'module %s(..., %s)' to receive its light",
                        name, where, name, where)
    return written


# -- PlantGL ---------------------------------------------------------------------------------
_KNOWN = {"Translated", "Oriented", "Scaled", "AxisRotated", "EulerRotated", "Tapered", "Cylinder", "Frustum",
          "Cone", "Sphere", "Disc", "Box", "Paraboloid", "Revolution"}
_FIELDS = ("translation", "primary", "secondary", "scale", "axis", "angle", "azimuth", "elevation", "roll",
           "radius", "height", "taper", "slices", "stacks", "solid", "size", "baseRadius", "topRadius", "shape")
_CHILDREN = ("geometry", "primitive")


def _value(v):
    if isinstance(v, (bool, int, float, str)):
        return v
    if all(hasattr(v, a) for a in ("x", "y", "z")):
        return (float(v.x), float(v.y), float(v.z))
    return None


def geometry_key(geometry):
    """A content key for a PlantGL geometry built by the turtle, or None (do not cache).

    Walks the transform wrappers (Translated, Oriented, Scaled, ...) down to the
    primitive and keeps each node's type and parameters: equal keys mean equal
    world-space geometry.  Types not known here give None.
    """
    parts = []
    node = geometry
    for _ in range(32):
        kind = type(node).__name__
        if kind not in _KNOWN:
            # a shared surface the model named (e.g. a leaf blade set with turtle.setSurface) is keyed
            # by its name: name only geometry you do not modify afterwards
            name = getattr(node, "name", "")
            named = node.isNamed() if hasattr(node, "isNamed") else bool(name)
            if named and isinstance(name, str) and name:
                return tuple(parts) + (("named", kind, name),)
            return None
        parts.append(kind)
        for name in _FIELDS:
            if hasattr(node, name):
                v = _value(getattr(node, name))
                if v is None:
                    return None
                parts.append((name, v))
        child = next((getattr(node, c) for c in _CHILDREN if hasattr(node, c)), None)
        if child is None:
            return tuple(parts)
        node = child
    return None


def _points(point_list) -> np.ndarray:
    """(n, 3) float64 points of a PlantGL ``Point3Array``."""
    if hasattr(point_list, "to_str"):
        with preserved_locale():      # to_str sets the C locale and leaves it so
            text = point_list.to_str("%.9g %.9g %.9g", " ")
        return np.array(text.split(), dtype=np.float64).reshape(-1, 3)
    return np.array([(p.x, p.y, p.z) for p in point_list], dtype=np.float64).reshape(-1, 3)


def topology_key(key):
    """The part of a :func:`geometry_key` that fixes the tessellation's faces: the node types and their
    whole-number fields (``slices``, ``stacks``, ``solid``), without positions, sizes or angles.  Two
    geometries with the same topology key tessellate into the same triangles over the same number of points
    (a growing internode: new radius and length each step, the same faces)."""
    if key is None:
        return None
    return tuple(part for part in key if isinstance(part, str) or (isinstance(part, tuple) and (
        part[0] == "named" or isinstance(part[1], (bool, int, str)))))


def _faces(index_list) -> np.ndarray:
    """(m, 3) int64 vertex indices of a PlantGL ``Index3Array``.

    Read from the array's text, ``Index3Array([Index3(0,992,31),...])``, made in one call (4-5x faster than a
    Python object per face, which is what PlantGL's iteration gives); the faces one by one where that text is
    not of that form."""
    text = repr(index_list)
    opening, closing = text.find("(["), text.rfind("])")
    if opening >= 0 and closing > opening:
        body = text[opening + 2:closing].replace("Index3(", " ").replace(")", " ").replace(",", " ")
        try:
            numbers = np.array(body.split(), dtype=np.int64)
        except ValueError:
            numbers = None
        if numbers is not None and len(numbers) == 3 * len(index_list):
            return numbers.reshape(-1, 3)
    return np.array([tuple(f) for f in index_list], dtype=np.int64).reshape(-1, 3)


def _tessellate(shape, pgl, topology=None, faces_of=None):
    """``(vertices (n, 3), faces (m, 3))`` of a shape, or None if it has no triangles.  ``faces_of`` (a dict
    kept across steps) holds ``(faces, number of points)`` for each ``topology`` key already met; a face list is
    reused only where the counts and the first and last face agree."""
    t = pgl.Tesselator()
    shape.apply(t)
    ts = t.result
    if ts is None:
        return None
    index_list = ts.indexList
    m = len(index_list)
    if m == 0:
        return None
    points = _points(ts.pointList)
    known = faces_of.get(topology) if faces_of is not None and topology is not None else None
    if known is not None:
        faces, n_points = known
        if (len(faces) == m and len(points) == n_points and tuple(index_list[0]) == tuple(faces[0])
                and tuple(index_list[m - 1]) == tuple(faces[-1])):
            return points, faces
    faces = _faces(index_list)
    faces.flags.writeable = False          # shared by every shape of this topology
    if faces_of is not None and topology is not None:
        faces_of[topology] = (faces, len(points))
    return points, faces


def shapes_by_module(lstring, lscene, names, cache, tick=None):
    """``({id: [(vertices, faces), ...]}, {id: module name})`` for the shapes of modules in ``names``; ``tick()``, if
    given, is called before each shape."""
    pgl = require_plantgl()
    meshes, modules = {}, {}
    for i in range(len(lscene)):
        if tick is not None:
            tick()
        shape = lscene[i]
        sid = shape.id
        if sid == pgl.Shape.NOID or sid < 0 or sid >= len(lstring):
            continue
        name = lstring[sid].name
        if name not in names:
            continue
        key = geometry_key(shape.geometry)
        mesh = cache.get(key, lambda: _tessellate(shape, pgl, topology_key(key), cache.faces))
        if mesh is None:
            continue
        meshes.setdefault(sid, []).append(mesh)
        modules[sid] = name
    cache.end_step()
    return meshes, modules


def plant_organs(lstring, lscene, materials_of, scale, position, cache, tick=None) -> list:
    """The organs of an L-Py step: the shapes of the modules ``materials_of`` knows (a mapping module name →
    ``(front, back)``), tessellated (``cache``: by geometry, across steps) and placed in the chamber.  ``tick()``, if
    given, is called between shapes and between organs: the L-Py IDE's window turns its event loop there
    (:meth:`lpy_light.plant.ide.Live.tick`), PlantGL being called from this thread only."""
    if lscene is None:
        raise LpyLightError("intercept() got no scene (lscene is None): L-Py builds it only on the last step of a "
                             "derive() unless the model calls frameDisplay(True) in StartEach — add "
                             "'def StartEach(): frameDisplay(True)' to the .lpy file")
    meshes, modules = shapes_by_module(lstring, lscene, set(materials_of), cache, tick)
    return organs_from_meshes_by_id(meshes, modules, materials_of.__getitem__, scale, position, tick)
