"""SEC2's scene files (its dialect of the Radiance format), the chambre2 scene, and OBJ chambers.

Each dialect form is read as SEC2 gives it; every malformed form is refused with one line naming
the file and line; a pure Radiance file is read as before; point lights emit isotropically (against
the solid angle of a disc); chambre2 closes its energy; the Angers OBJ is the Angers .rad but for
three primitives, and with those restored gives the same sensors within 4σ.
"""
from __future__ import annotations

import json
import logging
import math
import sys
from pathlib import Path

import numpy as np
import pytest

from lpy_light import cli
from lpy_light.run import simulate
from lpy_light.chamber.emitters import EMIT_POINT
from lpy_light.errors import InputError
from lpy_light.chamber.obj import parse_obj, read_obj
from lpy_light.chamber.radiance import parse_rad, read_rad
from lpy_light.chamber.scene import build_chamber, load_scene
from scenes import box, write_scene

ROOT = Path(__file__).resolve().parents[1]
DATA = ROOT / "lpy_light" / "data"
ANGERS = DATA / "angers-chamber"
SIMPLE = Path(__file__).parent / "sec2" / "simple.rad"
sys.path.insert(0, str(ROOT / "benchmarks"))

LIGHT = "void light lamp\n0\n0\n3 1 1 1\n\n"
GREY = "void plastic grey\n0\n0\n5 0.5 0.5 0.5 0 0\n\n"


# ------------------------------------------------------------------------------------------
# the dialect's forms, read as SEC2 gives them
def test_simple_rad_as_its_comments_say():
    """SEC2's own commented example: scale_factor 100, a `point` with its centre only (the comment says
    4 parameters; the file gives 3), three polygons."""
    prims = read_rad(SIMPLE)
    assert prims.sec2 and prims.scale_factor == 100 and prims.scale_line == 9
    lamp = next(p for p in prims if p.type == "point")
    assert (lamp.modifier, lamp.identifier, lamp.reals, lamp.line) == ("eclairage", "lampe", [0, 0, 1000], 31)
    chamber = build_chamber(prims)
    assert list(chamber.emitters.kind) == [EMIT_POINT] and np.allclose(chamber.emitters.data[0, 0], [0, 0, 1000])
    assert [s[0] for s in chamber.surfaces] == ["dalle", "paroi_X", "paroi_y"]


def test_simple_rad_scene_takes_the_unit_of_scale_factor(tmp_path):
    (tmp_path / "simple.rad").write_bytes(SIMPLE.read_bytes())
    (tmp_path / "s.toml").write_text('geometry = "simple.rad"\n')
    assert load_scene(tmp_path / "s.toml").unit == "cm"
    (tmp_path / "mm.toml").write_text('geometry = "simple.rad"\nunit = "mm"\n')
    chamber = load_scene(tmp_path / "mm.toml")          # 1/100 m into mm: every length x 10
    assert chamber.unit == "mm" and np.allclose(chamber.emitters.data[0, 0], [0, 0, 10000])
    assert np.abs(chamber.triangles).max() == 10000


@pytest.mark.parametrize("text, reals", [
    ("lamp point p\n1 2 3\n", [1, 2, 3]),
    ("lamp point p 1 2 3 0.5\n", [1, 2, 3, 0.5]),                 # the radius is read (and ignored)
    ("lamp point p\n0\n0\n4 1 2 3 0.5\n", [1, 2, 3, 0.5]),        # Radiance's counts are read too
    ("lamp point p\n0 0 3\n", [0, 0, 3]),                          # a centre that looks like counts
    ("lamp point_light n1\n86 21 85 # centre\n#150 # longueur\n#2.6 # diametre\n", [86, 21, 85]),
    ("lamp point_light n1 0 0 3 1 2 3\n", [1, 2, 3]),
    ("lamp spot_light s\n12 5 2\n170\n1 0 1\n", [12, 5, 2, 170, 1, 0, 1]),
])
def test_point_lights_without_counts(text, reals):
    prims = parse_rad(LIGHT + text + GREY, "d.rad")
    assert prims.sec2 and [p.type for p in prims][-1] == "plastic"     # the next primitive is read whole
    assert prims[1].reals == reals and prims[1].line == 6


def test_a_count_short_of_its_line_reads_the_line_in_sec2_files(caplog):
    """chambre2.rad's light: `1` then `0.32 0.32 0.32`; SEC2-era readers read the line."""
    light = "void light lamp32w\n0\n0\n1\n0.32 0.32 0.32\n\n"
    with caplog.at_level(logging.WARNING, logger="lpy_light"):
        prims = parse_rad("scale_factor 100\n" + light + "lamp32w point_light n 1 2 3\n", "c.rad")
    assert prims[0].reals == [0.32] * 3 and "c.rad:6: light lamp32w: its count says 1" in caplog.text
    # a pure Radiance file keeps Radiance's reading, and today's error
    with pytest.raises(InputError, match=r"^c.rad:5: expected a primitive type .* got the number '0.32'"):
        parse_rad(light + GREY, "c.rad")


def test_pure_radiance_files_are_not_sec2(angers_dir):
    prims = read_rad(angers_dir / "geometry" / "testChamber.rad")
    assert not prims.sec2 and prims.scale_factor is None
    # scale_factor as a Radiance modifier name (followed by a type, not a number) stays one
    prims = parse_rad("void plastic scale_factor 0 0 5 1 1 1 0 0\nscale_factor polygon p 0 0 9 0 0 0 1 0 0 0 1 0\n")
    assert prims.scale_factor is None and prims[1].modifier == "scale_factor"


# every malformed form: one line naming the file and line
BAD = [
    ("scale_factor 0\n", 1, "scale_factor must be a positive number"),
    ("scale_factor -5\n", 1, "scale_factor must be a positive number"),
    ("scale_factor nan\n", 1, "scale_factor must be a positive number"),
    ("scale_factor 1e999\n", 1, "scale_factor must be a positive number"),
    ("scale_factor 100\nscale_factor 10\n", 2, "given twice (first at line 1)"),
    (LIGHT + "scale_factor 100\n", 6, "after the first primitive (line 1)"),
    (LIGHT + "lamp point_light n\n86 21 85\n150 # longueur\n", 8, "point_light n takes its centre x y z"),
    (LIGHT + "lamp point_light n\n86 21\n", 6, "3 numbers, got 2 (86 21)"),
    (LIGHT + "lamp point_light n\n", 6, "got 0 (none)"),
    (LIGHT + "lamp point p 1 2 3 4 5\n", 6, "3 or 4 numbers, got 5"),
    (LIGHT + "lamp spot_light s 12 5 2 170 1 0\n", 6, "an angle (degrees) and a direction"),
    (LIGHT + "lamp point_light n\n86 1e999 85\n", 7, "not finite"),
    (LIGHT + "lamp point_light n\n86 nan 85\n", 7, "not finite"),
    (LIGHT + "lamp point_light\n", 6, "unexpected end of file"),
    # numbers left on a line that goes on are not the primitive's: read as Radiance reads them
    ("scale_factor 100\n" + LIGHT + "void plastic g 0 0 5\n1 1 1 0 0 0.5 grey polygon p\n", 8,
     "expected the number of string arguments (a non-negative integer) of 0.5 grey polygon"),
]


@pytest.mark.parametrize("text, line, words", BAD)
def test_dialect_errors_name_file_and_line(text, line, words):
    with pytest.raises(InputError) as info:
        parse_rad(text, "bad.rad")
    message = str(info.value)
    assert message.startswith("bad.rad:%d: " % line) and words in message and "\n" not in message, message


BAD_SCENES = [
    (LIGHT + "lamp spot_light s 12 5 2 170 1 0 1\n", 6, "spot lights are not supported"),
    (LIGHT + GREY + "grey point_light n 1 2 3\n", 11, "a point light needs a light (or glow) material"),
    (LIGHT + "nolamp point_light n 1 2 3\n", 6, "undefined modifier 'nolamp'"),
    (LIGHT + "lamp point_light n 1 2 1e13\n", 6, "beyond"),
]


@pytest.mark.parametrize("text, line, words", BAD_SCENES)
def test_dialect_scene_errors_name_file_and_line(text, line, words):
    with pytest.raises(InputError) as info:
        build_chamber(parse_rad(text, "bad.rad"))
    assert str(info.value).startswith("bad.rad:%d: " % line) and words in str(info.value), str(info.value)


def test_scene_level_errors(tmp_path, capsys):
    (tmp_path / "odd.rad").write_text("scale_factor 2.54\n" + LIGHT + "lamp point_light n 1 2 3\n")
    (tmp_path / "s.toml").write_text('geometry = "odd.rad"\n')
    out = tmp_path / "out"
    assert cli.main(["run", str(tmp_path / "s.toml"), "--photons", "100", "--out", str(out), "--quiet"]) == 2
    lines = capsys.readouterr().err.splitlines()
    assert len(lines) == 1 and lines[0].startswith("lpy-light: error: %s:1: scale_factor 2.54" % (tmp_path / "odd.rad"))
    (tmp_path / "s.toml").write_text('geometry = "odd.rad"\nunit = "cm"\n')      # with a unit it is converted
    chamber = load_scene(tmp_path / "s.toml")
    assert np.allclose(chamber.emitters.data[0, 0], np.array([1, 2, 3]) * 100 / 2.54)
    (tmp_path / "solid.rad").write_text(LIGHT + "lamp point_light n 1 2 3\n")
    (tmp_path / "s.toml").write_text('geometry = "odd.rad"\nunit = "cm"\nsolid_sensors = "solid.rad"\n')
    with pytest.raises(InputError, match=r"solid.rad:6: point_light n: a light source cannot be a solid sensor"):
        load_scene(tmp_path / "s.toml")
    (tmp_path / "s.toml").write_text('geometry = "odd.rad"\nflip_normals = 1\n')
    with pytest.raises(InputError, match=r"s.toml:2: 'flip_normals' must be true or false"):
        load_scene(tmp_path / "s.toml")


def test_point_lights_with_other_lamps_warn(caplog):
    text = LIGHT + "lamp point_light n 1 2 3\nlamp polygon p 0 0 9 0 0 0 1 0 0 0 1 0\n"
    with caplog.at_level(logging.WARNING, logger="lpy_light"):
        chamber = build_chamber(parse_rad(text, "m.rad"))
    assert len(chamber.emitters) == 2 and "SEC2's own share between them is not known" in caplog.text
    # the shares: 4π·I for the point, π·L·A for the polygon (A = 0.5)
    assert np.allclose(chamber.emitters.power, [4 * math.pi, math.pi * 0.5])


# ------------------------------------------------------------------------------------------
# point lights are isotropic points: the solid angle of a disc
def test_point_light_matches_solid_angle(tmp_path):
    """A point_light 500 mm above a disc of radius 40 mm in a black room: the disc gets the fraction
    Ω/4π = (1 − h/√(h² + r²))/2 of the photons (4σ).  A point emitting into the lower hemisphere only,
    or Lambertian, would give 2× or 4× as much on axis, and fail by > 20σ."""
    rad = ("scale_factor 1000\nvoid plastic black\n0\n0\n5 0 0 0 0 0\n\nvoid light lum\n0\n0\n1\n2 2 2\n\n"
           + box("black", (0, 0, 0), (1000, 1000, 1100))
           + "lum point_light lamp\n500 500 1000 # centre\n#150 # longueur\n")
    discs = [(500, 500, 500, 40, 0, 0, 1), (800, 600, 400, 40, 0, 0, 1), (700, 500, 600, 40, -1, 0, 0)]
    chamber = load_scene(write_scene(tmp_path, rad, discs))
    assert chamber.unit == "mm" and list(chamber.emitters.kind) == [EMIT_POINT]
    n = 400_000
    photons, std = simulate.run(simulate.KernelScene(chamber, "weighted"), n, seed=3, threads=2).sensors()
    for s, (x, y, z, r, nx, ny, nz) in enumerate(discs):
        d = np.array([x, y, z]) - [500, 500, 1000]
        dist = np.linalg.norm(d)
        cos = abs(np.dot(d / dist, [nx, ny, nz]))          # a small disc seen from afar: Ω ≈ π r² cosθ / d²
        omega = 2 * math.pi * (1 - dist / math.hypot(dist, r)) if s == 0 else math.pi * r * r * cos / dist ** 2
        expected = n * omega / (4 * math.pi)
        assert abs(photons[s, 0] - expected) < 4 * std[s, 0], (s, photons[s, 0], expected, std[s, 0])
        assert std[s, 0] < 0.06 * expected
    assert abs(photons[0, 0] - 2 * n * (1 - 500 / math.hypot(500, 40)) / 2) > 20 * std[0, 0]


# ------------------------------------------------------------------------------------------
# chambre2
def test_chambre2_is_what_its_readme_says():
    chamber = load_scene(cli.resolve_scene("chambre2"))
    assert chamber.unit == "cm" and len(chamber.surfaces) == 32 and len(chamber.triangles) == 64
    assert len(chamber.emitters) == 64 and set(chamber.emitters.kind) == {EMIT_POINT}
    assert np.allclose(chamber.emitters.power, chamber.emitters.power[0])        # one light, equal shares
    assert len(chamber.sensors) == 120 and set(chamber.sensors.center[:, 2]) == {27.0, 87.0}
    assert np.allclose(chamber.sensors.radius, 1.0)
    # flipped: the floor faces up, into the room
    floor = [i for i, s in enumerate(chamber.surfaces) if s[0] == "sol_1"][0]
    tri = chamber.triangles[chamber.tri_source == floor][0]
    assert np.cross(tri[1] - tri[0], tri[2] - tri[0])[2] > 0


def test_chambre2_energy_closure_and_picture(tmp_path, capsys):
    """Every photon's weight is absorbed by the room's materials and none escapes (the room is closed once
    its polygons face inward); the picture of each bench is written.  Without flip_normals (below) three
    quarters of the photons leave through the walls: this test would fail."""
    pytest.importorskip("matplotlib")
    out = tmp_path / "run"
    assert cli.main(["run", "chambre2", "--photons", "2e5", "--seed", "1", "--estimator", "nee", "--plot",
                     "--out", str(out), "--quiet"]) == 0
    closure = json.loads((out / "summary.json").read_text())["energy_closure"]["rad"]
    assert closure["escaped"] == 0 and closure["cut_at_max_depth"] == 0 and closure["lost"] == 0
    assert abs(closure["residual"]) < 4 * closure["residual_std"]
    assert set(closure["absorbed"]) == {"MurBlanc", "Sol", "Aquanappe", "MiroirCaissonLampes", "jaune"}
    assert sorted(p.name for p in out.glob("*.png")) == ["map_z27.png", "map_z87.png"]
    assert all(p.stat().st_size > 10_000 for p in out.glob("*.png"))


def test_chambre2_as_written_leaks(tmp_path):
    """The orientation claim of its README: read with SEC2's one-sided surfaces as written, ~75 % escape."""
    (tmp_path / "s.toml").write_text('geometry = "%s"\n' % (DATA / "chambre2" / "geometry" / "chambre2.rad"))
    result = simulate.run(simulate.KernelScene(load_scene(tmp_path / "s.toml"), "weighted"), 50_000, seed=1, threads=2)
    escaped = result.fate[-3, 0]            # rows: materials, escaped, cut, lost
    assert 0.6 < escaped / 50_000 < 0.9


# ------------------------------------------------------------------------------------------
# OBJ chambers
OBJ_MATERIALS = GREY + LIGHT


def test_obj_faces_are_polygons_with_their_usemtl(tmp_path):
    text = ("mtllib x.mtl\n# a comment\nv 0 0 0\nv 1 0 0\nv 1 1 0\nv 0 1 0 1.0\nvn 0 0 1\nvt 0 0\n"
            "o floor\nusemtl grey\ns off\nf 1/1/1 2/1/1 3/1/1 4/1/1\ng wall\nf -4//1 -2//1 -1//1\n"
            "f 1 2 \\\n 3\n")
    prims = parse_obj(text, "c.obj")
    assert [(p.modifier, p.type, p.identifier, p.line) for p in prims] == [
        ("grey", "polygon", "floor", 12), ("grey", "polygon", "wall", 14), ("grey", "polygon", "wall", 15)]
    assert prims[1].reals == [0, 0, 0, 1, 1, 0, 0, 1, 0]
    chamber = build_chamber(parse_rad(OBJ_MATERIALS + "lamp point_light n 0.5 0.5 2\n", "m.rad") + list(prims))
    assert len(chamber.triangles) == 4 and np.allclose(chamber.triangles[0, :, 2], 0)


BAD_OBJ = [
    ("v 0 0\n", 1, "a vertex needs x y z"),
    ("v 0 0 x\n", 1, "must be numbers"),
    ("v 0 0 nan\n", 1, "not finite"),
    ("v 0 0 0\nv 1 0 0\nv 0 1 0\nf 1 2 3\n", 4, "face before any 'usemtl'"),
    ("v 0 0 0\nv 1 0 0\nusemtl grey\nf 1 2 3\n", 4, "face vertex 3 does not exist (2 vertices so far)"),
    ("v 0 0 0\nusemtl grey\nf 1 0 1\n", 3, "face vertex 0 does not exist"),
    ("v 0 0 0\nusemtl grey\nf 1 2\n", 3, "at least 3 vertices"),
    ("v 0 0 0\nusemtl grey\nf 1 a/2 3\n", 3, "not a vertex index"),
    ("usemtl\n", 1, "'usemtl' needs one material name"),
    ("usemtl white wall\n", 1, "got 2 words"),
    ("v 0 0 0\ncurv 0 1 1 2\n", 2, "free-form geometry"),
    ("v 0 0 0\n\nfoo 1 2\n", 3, "unknown OBJ statement 'foo'"),
    ("v 0 0 0\x00\n", 1, "NUL byte"),
]


@pytest.mark.parametrize("text, line, words", BAD_OBJ)
def test_obj_errors_name_file_and_line(text, line, words):
    with pytest.raises(InputError) as info:
        parse_obj(text, "bad.obj")
    assert str(info.value).startswith("bad.obj:%d: " % line) and words in str(info.value), str(info.value)


def _obj_scene(tmp_path, obj, rad=OBJ_MATERIALS + "lamp point_light n 0.5 0.5 2\n", extra=""):
    (tmp_path / "c.obj").write_text(obj)
    (tmp_path / "m.rad").write_text(rad)
    (tmp_path / "s.toml").write_text('geometry = ["m.rad", "c.obj"]\n' + extra)
    return tmp_path / "s.toml"


def test_obj_material_errors_and_zero_area_faces(tmp_path, caplog):
    square = "v 0 0 0\nv 1 0 0\nv 1 1 0\nv 0 1 0\n"
    path = _obj_scene(tmp_path, square + "usemtl nowhere\nf 1 2 3 4\n")
    with pytest.raises(InputError, match=r"c.obj:6: surface polygon face uses undefined modifier 'nowhere' "
                                         r"\(an OBJ's usemtl names a material defined in a .rad file"):
        load_scene(path)
    with caplog.at_level(logging.WARNING, logger="lpy_light"):
        chamber = load_scene(_obj_scene(tmp_path, square + "o strip\nusemtl grey\nf 1 2 2 1\nf 1 2 3\n"))
    assert len(chamber.triangles) == 1 and "1 face(s) of zero area left out (strip)" in caplog.text


def test_obj_materials_from_the_optical_tables(tmp_path, angers_dir):
    """usemtl names with tables: R (and T) from the tables, the specular fraction from specularities —
    the same events as the .rad's own definitions of these materials give."""
    obj = "v 0 0 0\nv 1 0 0\nv 1 1 0\nv 0 1 0\nusemtl MurBlanc\nf 1 2 3 4\nusemtl Makrolon\nf 4 3 2 1\n"
    extra = 'optical = "%s"\nspecularities = "%s"\nbands = [[655, 665]]\n' % (
        angers_dir / "optical", angers_dir / "optical" / "Specularities.xlsx")
    chamber = load_scene(_obj_scene(tmp_path, obj, extra=extra))
    rad = load_scene(angers_dir / "angers.toml")
    by_name = {m.name: m for m in rad.materials}
    for m in chamber.materials:
        if m.name in by_name:
            assert np.allclose(m.events, by_name[m.name].events), m.name
    assert {m.name: m.type for m in chamber.materials}["Makrolon"] == "trans"


def test_obj_reader_agrees_with_trimesh(angers_dir):
    trimesh = pytest.importorskip("trimesh")
    ours = read_obj(angers_dir / "obj" / "testChamber.obj")
    mesh = trimesh.load(angers_dir / "obj" / "testChamber.obj", process=False, force="mesh")
    from lpy_light.chamber.geometry import triangulate_polygon, triangle_areas
    area = sum(triangle_areas(triangulate_polygon(np.reshape(p.reals, (-1, 3)))).sum() for p in ours)
    assert area == pytest.approx(mesh.area, rel=1e-9)


# ------------------------------------------------------------------------------------------
# the Angers OBJ against the Angers .rad
def _per_identifier(prims):
    """identifier -> (materials, area, area-weighted normal, area-weighted centroid, lamps)."""
    from lpy_light.chamber.geometry import triangle_areas, triangulate_polygon
    out = {}
    for p in prims:
        if p.type not in ("polygon", "cylinder"):
            continue
        e = out.setdefault(p.identifier, [set(), 0.0, np.zeros(3), np.zeros(3), 0])
        e[0].add(p.modifier)
        if p.type == "cylinder":
            e[4] += 1
            continue
        t = triangulate_polygon(np.reshape(p.reals, (-1, 3)))
        a = triangle_areas(t)
        e[1] += a.sum()
        e[2] += np.cross(t[:, 1] - t[:, 0], t[:, 2] - t[:, 0]).sum(axis=0) / 2
        e[3] += (t.mean(axis=1) * a[:, None]).sum(axis=0)
    return out


def test_angers_obj_is_the_rad_but_three_differences(angers_dir):
    """Primitive by primitive (area, normal, centroid within 1e-3 mm, material): the OBJ is the .rad but for
    `anchor` (only in the OBJ), the lamps (zero-area strips, left out) and the x = 50 mm copies of the two
    names the .rad uses twice (the OBJ kept one shape per name)."""
    rad = _per_identifier(read_rad(angers_dir / "geometry" / "testChamber.rad"))
    obj = _per_identifier(read_obj(angers_dir / "obj" / "testChamber.obj"))
    assert set(obj) - set(rad) == {"anchor"}
    assert set(rad) - set(obj) == {"lamp20Str", "lamp21Str", "lamp22Str", "lamp23Str"}
    differ = set()
    for name in set(rad) & set(obj):
        r, o = rad[name], obj[name]
        same = (r[0] == o[0] and abs(r[1] - o[1]) <= 1e-6 * r[1] and np.allclose(r[2], o[2], rtol=1e-6, atol=1e-3)
                and np.allclose(r[3] / r[1], o[3] / o[1], atol=1e-3))
        if not same:
            differ.add(name)
            assert o[1] == pytest.approx(r[1] / 2) and o[3][0] / o[1] == pytest.approx(2350)
    assert differ == {"refcaissonY0a", "refcaissonY0n"}


def test_angers_obj_with_the_same_geometry_gives_the_same_sensors(tmp_path, angers_dir):
    """angers-obj with `anchor` removed and the two lost walls restored against angers, 8 independent batches
    each: every sensor within 4σ, and the sensors' total within 4σ (σ from the batches' spread: the sensors
    of a run are correlated; 7 degrees of freedom).  A face turned the wrong way, a table material of the
    wrong type (Makrolon opaque) or a lamp lost would move the total by > 10 %."""
    from obj_vs_rad import batches, compare, obj_scene
    n, k = 62_500, 8
    rad, rad_std = batches(angers_dir / "angers.toml", n, k, seed=1)
    obj, obj_std = batches(obj_scene(tmp_path, restore_walls=True, remove_anchor=True), n, k, seed=11)
    c = compare(obj, obj_std, rad, rad_std)
    assert c["n_over_4"] == 0, c["max_abs_z"]
    assert abs(c["total_rel"]) < 4 * c["total_rel_std"], (c["total_rel"], c["total_rel_std"])
    assert c["total_rel_std"] < 0.008           # 4σ: a 3 % change of the total fails
