"""lpy-light: light interception for virtual plants in a modelled growth chamber.

Quick start::

    from lpy_light import LightModel                # in an .lpy file's EndEach: light.intercept(lstring, lscene)

    from lpy_light.chamber.scene import load_scene  # a chamber alone
    from lpy_light.run import simulate
    chamber = load_scene("scene.toml")
    result = simulate.run(simulate.KernelScene(chamber), photons=1_000_000, seed=1)
    photons, photons_std = result.sensors()          # (S, B) each

The package's rooms, each importing only those below it (``docs/architecture.md``): ``errors``, ``messages`` and
``process_state`` at the ground; :mod:`~lpy_light.chamber` (the chamber as read), :mod:`~lpy_light.estimators`
(chamber and plant → tallies), :mod:`~lpy_light.run` (threads, Dask, sweeps, output files),
:mod:`~lpy_light.plant` (L-Py, organs, the light model), :mod:`~lpy_light.report` (figures, SEC2, validation),
:mod:`~lpy_light.calibration` (a chamber fitted to its survey); the command line (``cli``) on top.
"""
__version__ = "0.1.0"


def __getattr__(name):
    # LightModel is imported lazily so that ``import lpy_light`` stays light
    if name == "LightModel":       # in the L-Py IDE, with its window alive (lpy_light.plant.ide)
        from .plant.ide import imported
        return imported("lpy_light.plant.light").LightModel
    if name == "par_colour":
        from .plant.plant_view import par_colour
        return par_colour
    raise AttributeError(name)
