"""A chamber fitted to its survey: measured readings read (``survey``) and lamps, positions and materials fitted to
them (``calibrate``), written as a scene's overrides (:mod:`lpy_light.chamber.overrides`).  Imports reports, runs
and the chamber.
"""
