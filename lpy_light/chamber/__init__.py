"""The chamber as read: its files (Radiance ``.rad``, ``.obj``, optical tables, lamps' spectra, sensors, a scene's
``.toml`` and a calibration's overrides) turned into arrays in scene units, and the units and ratios a reading is
given in.

The ground room: it imports nothing of the package but :mod:`lpy_light.errors`.  Read top-down: ``radiance`` and
``obj`` (geometry files), ``optical`` (tables per wavelength), ``materials``, ``emitters``, ``sensors``,
``geometry`` (triangles: tessellation, normals, coplanar partners, mirror planes), ``chamber`` (the arrays the
kernel needs: :class:`~lpy_light.chamber.chamber.Chamber`), ``overrides``, ``scene`` (a scene file read:
:func:`~lpy_light.chamber.scene.load_scene`), ``units`` (photon counts → µmol m⁻² s⁻¹), ``ratios`` (R:FR and its σ).
"""
