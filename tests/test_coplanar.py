"""Coincident coplanar surfaces: a hit picks one of them at random (physics.coplanar = "random").

The Angers chamber has one such place: the cornice tops and the Makrolon ceiling share the plane
z = 1970 along the walls.  Which one a ray meets there used to be decided by Embree's float32
rounding (~76 % Makrolon); SEC2's result is reproduced by a fair choice (docs/validation.md).
"""
import numpy as np
import pytest

from lpy_light.run import simulate
from lpy_light.chamber.geometry import coplanar_partners, triangulate_polygon
from lpy_light.chamber.scene import load_scene
from scenes import lamp_rectangle, rad_polygon, write_scene

MATERIALS = ("void plastic black\n0\n0\n5 0 0 0 0 0\n\n"
             "void trans clear\n0\n0\n7 0 0 0 0 0 1 1\n\n"      # R = 0, T = 1, all straight through
             "void light lamp\n0\n0\n3 10 10 10\n\n")
SQUARE = [(0, 0, 500), (1000, 0, 500), (1000, 1000, 500), (0, 1000, 500)]   # facing up (+z)


def _scene(tmp_path, sheets, physics=""):
    rad = MATERIALS + lamp_rectangle("lamp", (500, 500), 100, 1000)
    for material, name in sheets:
        rad += rad_polygon(material, name, SQUARE)
    return load_scene(write_scene(tmp_path, rad, [(500, 500, 400, 200, 0, 0, 1)], physics))


def _count(chamber, n=200_000, seed=3):
    res = simulate.run(simulate.KernelScene(chamber, "weighted"), n, seed=seed, threads=2)
    p, s = res.sensors()
    return p[0, 0], s[0, 0]


def test_partners_same_plane_other_surface_only():
    a = triangulate_polygon(np.array(SQUARE, float))
    b = triangulate_polygon(np.array(SQUARE, float)[::-1])                    # same plane, facing down
    c = triangulate_polygon(np.array(SQUARE, float) + [0, 0, 1])              # parallel, 1 mm above
    d = triangulate_polygon(np.array(SQUARE, float) + [2000, 0, 0])           # same plane, apart
    tris = np.concatenate([a, b, c, d])
    source = np.repeat([0, 1, 2, 3], 2)
    start, partners = coplanar_partners(tris, source)
    got = [sorted(partners[start[i]:start[i + 1]].tolist()) for i in range(len(tris))]
    assert got[0] == got[1] == [2, 3] and got[2] == got[3] == [0, 1]
    assert got[4:] == [[]] * 4
    # one-sided triangles facing opposite ways never compete
    start, partners = coplanar_partners(tris, source, two_sided=np.zeros(len(tris), bool))
    assert [sorted(partners[start[i]:start[i + 1]].tolist()) for i in range(4)] == [[]] * 4
    start, partners = coplanar_partners(tris, source, two_sided=np.ones(len(tris), bool))
    assert sorted(partners[start[0]:start[1]].tolist()) == [2, 3]


def test_coincident_sheets_share_hits_fairly(tmp_path):
    clear, _ = _count(_scene(tmp_path / "clear", [("clear", "glass")]))
    both, both_std = _count(_scene(tmp_path / "both", [("black", "sheet"), ("clear", "glass")]))
    swapped, swapped_std = _count(_scene(tmp_path / "swapped", [("clear", "glass"), ("black", "sheet")]))
    assert clear > 10_000
    for value, std in ((both, both_std), (swapped, swapped_std)):
        assert abs(value - 0.5 * clear) < 4 * np.hypot(std, 0.5 * np.sqrt(clear)), (value, clear)


def test_arbitrary_is_not_fair_here(tmp_path):
    """Power: Embree's own choice between the two coincident sheets is not a fair coin."""
    clear, _ = _count(_scene(tmp_path / "clear", [("clear", "glass")]))
    value, std = _count(_scene(tmp_path / "arb", [("black", "sheet"), ("clear", "glass")],
                               '[physics]\ncoplanar = "arbitrary"\n'))
    assert abs(value - 0.5 * clear) > 4 * np.hypot(std, 0.5 * np.sqrt(clear)), (value, clear)


def test_bad_coplanar_option(tmp_path):
    from lpy_light.errors import InputError
    with pytest.raises(InputError, match="coplanar"):
        _scene(tmp_path, [("clear", "glass")], '[physics]\ncoplanar = "first"\n')
