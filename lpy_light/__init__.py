"""lpy-light: light interception for virtual plants in a modelled growth chamber.

Quick start::

    from lpy_light.scene import load_scene
    from lpy_light import simulate
    chamber = load_scene("scene.toml")
    result = simulate.run(simulate.KernelScene(chamber), photons=1_000_000, seed=1)
    photons, photons_std = result.sensors()          # (S, B) each
"""
__version__ = "0.1.0"


def __getattr__(name):
    # LightModel is imported lazily so that ``import lpy_light`` stays light
    if name == "LightModel":
        from .light import LightModel
        return LightModel
    if name == "par_colour":
        from .plant_view import par_colour
        return par_colour
    raise AttributeError(name)
