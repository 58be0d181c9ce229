"""The photon kernel: Embree scene, random streams, sampling and the bounce loop.

Installed as ``lpy_light.kernel``.  It knows triangles, materials as event
tables, emitters, sensors and receivers as arrays — nothing of files or L-Py.
"""
