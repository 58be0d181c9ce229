"""The Radiance reader: tokens as Radiance reads them, errors that name file and line."""
import pytest

from lpy_light.errors import InputError
from lpy_light.chamber.radiance import parse_rad, read_rad
from lpy_light.chamber.scene import build_chamber


def test_angers_reads_to_130_primitives(angers_dir):
    prims = read_rad(angers_dir / "geometry/testChamber.rad")
    assert len(prims) == 130
    assert sum(p.type in ("plastic", "metal", "trans", "light", "x") for p in prims) == 26
    assert sum(p.type in ("polygon", "cylinder") for p in prims) == 104
    for name in ("refcaissonY0n", "refcaissonY0a"):
        copies = [p for p in prims if p.identifier == name]
        assert len(copies) == 2 and copies[0].reals != copies[1].reals   # two different real walls
    chamber = build_chamber(prims)
    kept = [s[0] for s in chamber.surfaces]
    assert kept.count("refcaissonY0n") == 2 and kept.count("refcaissonY0a") == 2
    assert len(chamber.emitters) == 4 and len(chamber.skipped) == 1 and ":144:" in chamber.skipped[0]


def test_repeated_names_all_or_the_last(angers_dir):
    """physics.repeated_names = "last" (SEC2's and the photon-mapping engine's reading, a table by name) keeps
    only the last surface of a name: on Angers the lamp-box mirror wall at x = 50 goes, the one at x = 2350
    stays, nothing else changes; "all" (the default, Radiance's reading) keeps both."""
    import numpy as np

    from lpy_light.chamber.scene import Physics
    prims = read_rad(angers_dir / "geometry/testChamber.rad")
    every = build_chamber(prims)
    last = build_chamber(prims, physics=Physics(repeated_names="last"))
    lost = [s for s in every.surfaces if s not in last.surfaces]
    assert [s[0] for s in lost] == ["refcaissonY0n", "refcaissonY0a"]
    for name in ("refcaissonY0n", "refcaissonY0a"):
        src = [i for i, s in enumerate(last.surfaces) if s[0] == name]
        xs = last.triangles[np.isin(last.tri_source, src)][..., 0]
        assert len(src) == 1 and np.all(xs == 2350.0)
    assert len(last.triangles) == len(every.triangles) - 4
    # a lamp (a light cylinder) is a surface too: two of one name leave one
    two = parse_rad("void light l 0 0 3 1 1 1\nl cylinder a 0 0 7 0 0 0 1 0 0 .1\nl cylinder a 0 0 7 0 5 0 1 5 0 .1\n")
    assert len(build_chamber(two).emitters) == 2
    assert len(build_chamber(two, physics=Physics(repeated_names="last")).emitters) == 1


def test_tokens_not_lines():
    text = "void plastic red 0 0 5 .5 .1 .1 0 0  # a comment\nred polygon p 0 0 9 0 0 0 1 0 0\n 1 1 0 #x\n"
    prims = parse_rad(text)
    assert [p.identifier for p in prims] == ["red", "p"]
    assert prims[1].reals == [0, 0, 0, 1, 0, 0, 1, 1, 0]
    assert prims[1].line == 2


@pytest.mark.parametrize("text, line, words", [
    ("void plastic a\n0\n0\n5 1 2 3\n", 4, "end of file"),
    ("void plastic a\nx\n0\n5 1 2 3 4 5\n", 2, "number of string"),
    ("void plastic a\n0\n0\n5 1 2 zz 4 5\n", 4, "real number"),
    ("void plastic a\n0\n0\n5 1 2 nan 4 5\n", 4, "not finite"),
    ("!xform -t 1 0 0 x.rad\n", 1, "inline commands"),
])
def test_syntax_errors_name_the_line(text, line, words):
    with pytest.raises(InputError) as info:
        parse_rad(text, "bad.rad")
    assert info.value.line == line and words in str(info.value) and str(info.value).startswith("bad.rad:%d:" % line)


def test_semantic_errors_name_the_line():
    lamp = "void light l 0 0 3 1 1 1\nl polygon lp 0 0 9 0 0 1 1 0 1 1 1 1\n"
    with pytest.raises(InputError, match=r"s.rad:3: .*undefined modifier 'nope'"):
        build_chamber(parse_rad(lamp + "nope polygon p 0 0 9 0 0 0 1 0 0 1 1 0\n", "s.rad"))
    with pytest.raises(InputError, match=r"s.rad:3: .*needs 3·n reals"):
        build_chamber(parse_rad(lamp + "l polygon p 0 0 6 0 0 0 1 0 0\n", "s.rad"))
    with pytest.raises(InputError, match=r"s.rad:3: .*not supported"):
        build_chamber(parse_rad(lamp + "void glass g 0 0 3 1 1 1\n", "s.rad"))
    with pytest.raises(InputError, match=r"s.rad:4: .*skipped \(s.rad:3\)"):
        build_chamber(parse_rad(lamp + "void x q 0 0 3 1 1 1\nq polygon p 0 0 9 0 0 0 1 0 0 1 1 0\n", "s.rad"))
    with pytest.raises(InputError, match=r"s.rad:3: .*not energy-conserving"):
        build_chamber(parse_rad(lamp + "void trans t 0 0 7 .6 .6 .6 0 0 .6 0\n", "s.rad"))
    with pytest.raises(InputError, match="no light source"):
        build_chamber(parse_rad("void plastic a 0 0 5 1 1 1 0 0\na polygon p 0 0 9 0 0 0 1 0 0 1 1 0\n", "s.rad"))


def test_concave_polygon_keeps_area_and_winding():
    import numpy as np
    from lpy_light.chamber.geometry import triangle_areas, triangulate_polygon, triangle_normals
    L = [(0, 0, 0), (2, 0, 0), (2, 1, 0), (1, 1, 0), (1, 2, 0), (0, 2, 0)]   # L-shape, area 3
    tris = triangulate_polygon(L)
    assert triangle_areas(tris).sum() == pytest.approx(3)
    np.testing.assert_allclose(triangle_normals(tris), [[0, 0, 1]] * len(tris))
    tris = triangulate_polygon(L[::-1])
    np.testing.assert_allclose(triangle_normals(tris), [[0, 0, -1]] * len(tris))



@pytest.mark.parametrize("seam_at", ["left edge", "right edge"])
def test_polygon_with_a_hole_cut_by_a_seam(seam_at):
    """Radiance cuts a hole by a seam: the outline runs to the hole, around it the other way, and back along
    the same edge, so the seam's two ends appear twice.  Area 100 − 4 = 96, every triangle facing the
    polygon's way, none over the hole.  (Ear clipping that let the seam's copies block every ear fell back
    to a fan: area 140, triangles facing backwards, and the hole covered.)"""
    import numpy as np
    from lpy_light.chamber.geometry import triangle_areas, triangle_normals, triangulate_polygon
    if seam_at == "left edge":
        pts = [(0, 0, 0), (10, 0, 0), (10, 10, 0), (0, 10, 0), (0, 5, 0), (4, 5, 0), (4, 6, 0), (6, 6, 0),
               (6, 4, 0), (4, 4, 0), (4, 5, 0), (0, 5, 0)]
    else:
        pts = [(0, 0, 0), (10, 0, 0), (10, 5, 0), (6, 5, 0), (6, 4, 0), (4, 4, 0), (4, 6, 0), (6, 6, 0),
               (6, 5, 0), (10, 5, 0), (10, 10, 0), (0, 10, 0)]
    tris = triangulate_polygon(pts)
    assert triangle_areas(tris).sum() == pytest.approx(96)
    np.testing.assert_allclose(triangle_normals(tris), [[0, 0, 1]] * len(tris))
    centroids = tris.mean(axis=1)
    assert not np.any((np.abs(centroids[:, 0] - 5) < 1) & (np.abs(centroids[:, 1] - 5) < 1))

def test_many_sided_polygons():
    """A tessellated disc of 12 000 sides (convex: one fan, at once) and a 3 000-point star (ear clipping, each
    round vectorised) keep their exact area and winding; a pentagram, whose corners all turn the same way but
    which turns twice, is not taken for convex."""
    import numpy as np
    from lpy_light.chamber.geometry import triangle_areas, triangle_normals, triangulate_polygon
    for n, bumpy in ((12000, 0.0), (3000, 0.3)):
        a = np.linspace(0, 2 * np.pi, n + 1)[:-1]
        r = 1 + bumpy * (np.arange(n) % 2)
        pts = np.stack([r * np.cos(a), r * np.sin(a), np.zeros(n)], axis=1)
        tris = triangulate_polygon(pts)
        x, y = pts[:, 0], pts[:, 1]
        shoelace = 0.5 * abs(np.dot(x, np.roll(y, -1)) - np.dot(y, np.roll(x, -1)))
        assert len(tris) == n - 2
        assert triangle_areas(tris).sum() == pytest.approx(shoelace, rel=1e-12)
        np.testing.assert_allclose(triangle_normals(tris)[:, 2], 1)
    k = np.arange(5) * 4 * np.pi / 5
    star = triangulate_polygon(np.stack([np.cos(k), np.sin(k), 0 * k], axis=1))
    fan = np.stack([np.cos(k), np.sin(k), 0 * k], axis=1)[[[4, 0, 1], [4, 1, 2], [2, 3, 4]]]
    assert not np.array_equal(star, fan)


def test_material_readings_sec2_and_radiance():
    """SEC2 reads trans as (R = colour, T = trans); Radiance splits C(1-s)(1-t) / s / C(1-s)t."""
    import numpy as np

    from lpy_light.chamber.materials import ABSORB, DIFFUSE_R, DIFFUSE_T, SPECULAR_R, SPECULAR_T, build_material

    text = ("void trans t 0 0 7 0.6 0.6 0.6 0.1 0 0.5 0.2\nvoid plastic p 0 0 5 0.5 0.5 0.5 0.1 0\n"
            "void metal m 0 0 5 0.5 0.5 0.5 0.1 0\n")
    t, p, m = parse_rad(text, "x.rad")
    with pytest.raises(InputError, match="materials = .radiance"):
        build_material(t, None, reading="sec2")             # 0.6 + 0.5 > 1: SEC2's reading is not conserving
    e = build_material(t, None, reading="radiance").events[:, 0]
    C, s, tr, ts = 0.6, 0.1, 0.5, 0.2
    assert np.allclose(e[[DIFFUSE_R, SPECULAR_R, DIFFUSE_T, SPECULAR_T]],
                       [C * (1 - s) * (1 - tr), s, C * (1 - s) * tr * (1 - ts), C * (1 - s) * tr * ts])
    assert np.isclose(e.sum(), 1) and e[ABSORB] > 0
    assert np.allclose(build_material(p, None, reading="radiance").events[[DIFFUSE_R, SPECULAR_R], 0], [0.45, 0.1])
    assert np.allclose(build_material(m, None, reading="radiance").events[[DIFFUSE_R, SPECULAR_R], 0], [0.45, 0.05])
    assert np.allclose(build_material(p, None).events[[DIFFUSE_R, SPECULAR_R], 0], [0.45, 0.05])   # SEC2: R·s
