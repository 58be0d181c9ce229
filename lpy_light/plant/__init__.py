"""The plant in the chamber: L-Py/PlantGL scenes turned into tagged organ meshes (``lpy``, ``organs``), the
light model an ``.lpy`` file calls each step (``light``: :class:`~lpy_light.plant.light.LightModel`), each organ's
light in real units (``organ_light``), the precision asked of a step (``precision``), the colours of a lit plant
(``plant_view``) and ``lpy-light grow`` (``grow``).  Imports runs, estimators and the chamber.
"""
