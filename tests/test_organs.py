"""Organs as meshes (no L-Py needed): the light model's whole path, scene → organs → results → parameters."""
import math

import numpy as np
import pytest
import trimesh

from lpy_light.plant import lpy
from lpy_light.errors import InputError
from lpy_light.plant.light import LightModel
from scenes import box, lamp_rectangle, rectangle_to_disc_fraction, write_scene

BLACK_ROOM = ("void plastic black\n0\n0\n5 0 0 0 0 0\n\nvoid light lamp\n0\n0\n3 10 10 10\n\n"
              + box("black", (0, 0, 0), (1000, 1000, 1100)) + lamp_rectangle("lamp", (500, 500), 100, 1000))
BLACK = {"reflectance": 0.0}
WHITE = {"reflectance": 0.5}
FLUX = 100.0          # µmol s⁻¹ emitted by the lamp (given, instead of a measured spectrum)


def disc_mesh(radius, z=0.0, up=True, sides=96):
    """A flat regular polygon (a leaf blade) centred on the z axis; its front faces up or down."""
    a = np.linspace(0, 2 * np.pi, sides, endpoint=False)
    v = np.c_[radius * np.cos(a), radius * np.sin(a), np.full(sides, z)]
    v = np.vstack([[0, 0, z], v])
    f = np.array([[0, 1 + i, 1 + (i + 1) % sides] for i in range(sides)])
    return trimesh.Trimesh(v, f if up else f[:, ::-1], process=False)


def square_mesh(side, z=0.0):
    h = side / 2
    return trimesh.Trimesh([[-h, -h, z], [h, -h, z], [h, h, z], [-h, h, z]], [[0, 1, 2], [0, 2, 3]], process=False)


@pytest.fixture(scope="module")
def black_room(tmp_path_factory):
    return write_scene(tmp_path_factory.mktemp("black"), BLACK_ROOM)


def _model(scene, **kw):
    kw.setdefault("lamp_flux", FLUX)
    kw.setdefault("plant_unit", "mm")
    kw.setdefault("position", (500, 500, 0))
    return LightModel(scene, organs={"Leaf": (BLACK, WHITE)}, **kw)


def _expected_fraction(area, z):
    """Fraction of the panel's photons reaching a horizontal disc of this area at height z under it."""
    r = math.sqrt(area / math.pi)
    return rectangle_to_disc_fraction((500, 500), 100, 1000, (0, 0, -1), (500, 500, z), (0, 0, 1), r)


def test_leaf_sides_and_units(black_room):
    """A leaf facing up absorbs all it gets (black upper side); flipped, its white side absorbs half."""
    model = _model(black_room, photons=20_000)
    up, down = disc_mesh(30, z=500), disc_mesh(30, z=500, up=False)
    lights = model.intercept({1: up})
    leaf = lights[1]
    area = up.area
    n = 20_000
    expected = n * _expected_fraction(area, 500)
    assert abs(leaf.photons[0] - expected) < 4 * leaf.photons_std[0]
    assert leaf.photons_std[0] < 0.02 * expected
    # units: ppfd = photons/N · flux / area (m²); absorbed = all of it (black side)
    assert leaf.area_m2 == pytest.approx(area * 1e-6)
    assert leaf.ppfd[0] == pytest.approx(leaf.photons[0] / n * FLUX / leaf.area_m2)
    assert leaf.absorbed[0] == pytest.approx(leaf.photons[0] / n * FLUX, rel=1e-9)
    flipped = model.intercept({1: down})[1]
    assert abs(flipped.absorbed[0] - 0.5 * flipped.photons[0] / n * FLUX) < 4 * flipped.absorbed_std[0]
    assert abs(flipped.absorbed[0] - leaf.absorbed[0]) > 10 * np.hypot(flipped.absorbed_std[0], leaf.absorbed_std[0])


def test_one_square_millimetre_bud_has_an_honest_sigma(black_room):
    """Across seeds, the spread of a 1 mm² bud's value matches the σ each run reports, and the mean is right."""
    values, sigmas = [], []
    for seed in range(12):
        model = _model(black_room, photons=5_000, seed=seed)
        bud = model.intercept({7: square_mesh(1.0, z=500)})[7]
        values.append(bud.photons[0])
        sigmas.append(bud.photons_std[0])
    values, sigmas = np.array(values), np.array(sigmas)
    expected = 5_000 * _expected_fraction(1.0, 500)
    assert np.all(sigmas > 0) and np.all(sigmas < 0.2 * expected)
    spread = values.std(ddof=1)
    assert 0.5 < spread / sigmas.mean() < 1.6, (spread, sigmas.mean())
    assert abs(values.mean() - expected) < 4 * sigmas.mean() / math.sqrt(len(values))


ROOM = ("void plastic grey\n0\n0\n5 0.6 0.6 0.6 0.2 0\n\nvoid light lamp\n0\n0\n3 10 10 10\n\n"
        + box("grey", (0, 0, 0), (1000, 1000, 1100)) + lamp_rectangle("lamp", (500, 500), 100, 1000))


def test_next_events_on_organs_match_counting(tmp_path):
    """Two leaves, one shading the other, in a reflecting room: nee agrees with the weighted estimator."""
    scene = write_scene(tmp_path, ROOM)
    organs = {1: (disc_mesh(60, z=400), ({"reflectance": 0.1, "transmittance": 0.2}, {"reflectance": 0.3})),
              2: (disc_mesh(60, z=300, up=False), (BLACK, WHITE))}
    nee = LightModel(scene, organs={"Leaf": BLACK}, lamp_flux=FLUX, plant_unit="mm", position=(500, 500, 0),
                     photons=60_000, estimator="nee", nee_picks=1).intercept(organs)
    counted = LightModel(scene, organs={"Leaf": BLACK}, lamp_flux=FLUX, plant_unit="mm", position=(500, 500, 0),
                         photons=600_000, estimator="weighted").intercept(organs)
    for k in (1, 2):
        for name in ("ppfd", "absorbed"):
            a, sa = getattr(nee[k], name)[0], getattr(nee[k], name + "_std")[0]
            b, sb = getattr(counted[k], name)[0], getattr(counted[k], name + "_std")[0]
            assert abs(a - b) < 4 * math.hypot(sa, sb), (k, name, a, b, sa, sb)
    assert nee[2].ppfd[0] < nee[1].ppfd[0]       # the lower leaf is shaded


def test_targets_aim_shadow_rays_at_the_organs_that_matter(tmp_path):
    """``targets``: next events go to the named modules only — unbiased, and the targeted organ gets all the
    shadow rays (a smaller σ than when it shares them); the others only shade: their numbers are not
    reported (NaN, empty cells), never a few-photon count passed off as their light."""
    scene = write_scene(tmp_path, ROOM)
    grey = {"reflectance": 0.3, "transmittance": 0.1}
    far = disc_mesh(60, z=700).apply_translation((250, 0, 0))
    organs = {1: (disc_mesh(60, z=400), grey, "Leaf"), 2: (disc_mesh(60, z=300, up=False), grey, "Stem"),
              3: (far, grey, "Leaf")}
    kw = dict(organs={"Leaf": grey, "Stem": grey}, lamp_flux=FLUX, plant_unit="mm", position=(500, 500, 0))
    aimed = LightModel(scene, photons=60_000, estimator="nee", nee_picks=1, targets=["Leaf"], **kw).intercept(organs)
    every = LightModel(scene, photons=60_000, estimator="nee", nee_picks=1, **kw).intercept(organs)
    counted = LightModel(scene, photons=600_000, estimator="weighted", **kw).intercept(organs)
    a, sa = aimed[1].ppfd[0], aimed[1].ppfd_std[0]
    b, sb = counted[1].ppfd[0], counted[1].ppfd_std[0]
    assert abs(a - b) < 4 * math.hypot(sa, sb), (a, b, sa, sb)
    rel = lambda r, k: r[k].ppfd_std[0] / r[k].ppfd[0]
    assert rel(every, 1) > 1.05 * rel(aimed, 1)      # the Leaf shares its shadow rays with the Stem there (1.08x)
    assert aimed[2].role == "shading only" and every[2].role == "target" and aimed[1].role == "target"
    assert all(math.isnan(x) for x in (aimed[2].ppfd[0], aimed[2].ppfd_std[0], aimed[2].absorbed[0], aimed[2].par))
    assert every[2].ppfd[0] > 0
    with pytest.raises(InputError, match="Root"):
        LightModel(scene, targets=["Root"], **kw)
    with pytest.raises(InputError, match="mirror_events"):
        LightModel(scene, mirror_events=-1, **kw)


def test_unchanged_organs_are_not_converted_again(black_room):
    model = _model(black_room, photons=2_000)
    plant = {1: disc_mesh(30, z=500), 2: disc_mesh(20, z=400)}
    model.intercept(plant)
    misses = model.cache.misses
    model.intercept(plant)
    assert model.cache.misses == misses and model.cache.hits >= 2
    plant[2] = disc_mesh(25, z=400)       # it grew
    model.intercept(plant)
    assert model.cache.misses == misses + 1


def test_bad_organ_meshes_name_the_organ(black_room):
    model = _model(black_room, photons=1_000)
    v = np.array([[0, 0, 0], [1, 0, 0], [0, 1, 0]], float)
    with pytest.raises(InputError, match="organ 3.*outside"):
        model.intercept({3: (v, np.array([[0, 1, 5]]))})
    with pytest.raises(InputError, match="organ 4.*degenerate"):
        model.intercept({4: (v * np.nan, np.array([[0, 1, 2]]))})
    with pytest.raises(InputError, match="no optical table"):
        LightModel(black_room, organs={"Leaf": "NoSuchLeaf"}, lamp_flux=FLUX)


def test_degenerate_triangles_dropped_with_one_warning(black_room, caplog):
    model = _model(black_room, photons=1_000)
    m = disc_mesh(30, z=500)
    v = np.vstack([m.vertices, [[0, 0, 500]]])
    f = np.vstack([m.faces, [[0, 0, 1], [0, 1, len(v) - 1]]])       # repeated vertex, zero area
    with caplog.at_level("WARNING", logger="lpy_light"):
        lights = model.intercept({9: (v, f)})
    warnings = [r for r in caplog.records if "organ 9" in r.getMessage()]
    assert len(warnings) == 1 and "dropped 2 degenerate" in warnings[0].getMessage()
    assert lights[9].area_m2 == pytest.approx(m.area * 1e-6)


class FakeModule:
    """What L-Py's ParamModule offers that write_parameters uses (name, hasParameter, setParameter)."""

    def __init__(self, name, params):
        self.name, self.params = name, dict(params)

    def hasParameter(self, p):
        return p in self.params

    def setParameter(self, p, v):
        self.params[p] = v


def test_results_land_in_module_parameters(black_room, caplog):
    model = _model(black_room, photons=5_000)
    lstring = [FakeModule("Stem", {}), FakeModule("Leaf", {"length": 3, "light": None}), FakeModule("Bud", {})]
    meshes = {1: [(disc_mesh(30, z=500).vertices, disc_mesh(30, z=500).faces)], 2: [(square_mesh(2.0, 450).vertices,
                                                                                    square_mesh(2.0, 450).faces)]}
    model.organ_materials["Bud"] = BLACK
    organs = lpy.organs_from_meshes_by_id(meshes, {1: "Leaf", 2: "Bud"},
                                          lambda name: model._materials_of(model.organ_materials[name]),
                                          model.scale, model.position)
    step = model.run(organs)
    with caplog.at_level("WARNING", logger="lpy_light"):
        written = lpy.write_parameters(lstring, step.organs, "light")
    assert written == 1
    light = lstring[1].params["light"]
    assert light.ppfd[0] > 0 and light["ppfd_std"][0] > 0 and light.module == "Leaf"
    assert any("module Bud has no parameter 'light'" in r.getMessage() for r in caplog.records)


def test_geometry_key_follows_content():
    """The PlantGL cache key: equal for equal turtle geometry, different when a parameter changes, None if unknown."""
    class V:
        def __init__(self, x, y, z):
            self.x, self.y, self.z = x, y, z

    class Cylinder:
        def __init__(self, r, h):
            self.radius, self.height, self.slices, self.solid = r, h, 8, True

    class Translated:
        def __init__(self, t, g):
            self.translation, self.geometry = t, g

    class Mystery:
        pass

    a = Translated(V(0, 0, 1), Cylinder(0.1, 2.0))
    b = Translated(V(0, 0, 1), Cylinder(0.1, 2.0))
    c = Translated(V(0, 0, 1), Cylinder(0.1, 2.5))
    assert lpy.geometry_key(a) == lpy.geometry_key(b) is not None
    assert lpy.geometry_key(a) != lpy.geometry_key(c)
    assert lpy.geometry_key(Translated(V(0, 0, 1), Mystery())) is None


def test_angers_leaf_gets_par_and_red_far_red():
    """The real chamber, 12 bands, leaf tables: PAR in µmol m⁻² s⁻¹ and R:FR, each with σ."""
    model = LightModel("angers-12bands", photons=40_000, plant_unit="cm")
    leaf = model.intercept({0: (disc_mesh(5, z=30), ("FeuilleVieille_Sup", "FeuilleVieille_Inf"))})[0]
    assert 20 < leaf.par < 2000 and 0 < leaf.par_std < 0.1 * leaf.par
    assert 0.3 < leaf.rfr < 5 and 0 < leaf.rfr_std < 0.2 * leaf.rfr
    assert np.all(leaf.absorbed > 0) and np.all(leaf.absorbed < leaf.ppfd * leaf.area_m2)


@pytest.mark.parametrize("with_sensors", [False, True])
def test_par_sigma_includes_the_bands_covariance(tmp_path, with_sensors):
    """All bands ride on the same photons: PAR's σ must add the bands' σ linearly when they move together.
    Across seeds, the spread of PAR matches the reported σ, which is √3 above the naive independent sum.
    With sensors in the scene the organs' tally rows come after them (a row offset once picked a sensor's σ)."""
    sensors = [(500, 500, 100 + 10 * i, 20, 0, 0, 1) for i in range(5)] if with_sensors else None
    scene = write_scene(tmp_path, BLACK_ROOM, sensors=sensors,
                        toml_extra="bands = [[400, 500], [500, 600], [600, 700]]\n")
    values, sigmas, naive = [], [], []
    for seed in range(16):
        model = LightModel(scene, organs={"Leaf": BLACK}, lamp_flux=[FLUX, FLUX, FLUX], plant_unit="mm",
                           position=(500, 500, 0), photons=3_000, seed=seed, estimator="weighted")
        leaf = model.intercept({1: disc_mesh(30, z=500)})[1]
        values.append(leaf.par)
        sigmas.append(leaf.par_std)
        naive.append(math.sqrt((leaf.ppfd_std ** 2).sum()))
    spread, sigma = np.std(values, ddof=1), np.mean(sigmas)
    assert np.mean(sigmas) == pytest.approx(math.sqrt(3) * np.mean(naive), rel=1e-6)
    assert 0.6 < spread / sigma < 1.5, (spread, sigma)


def test_a_plant_where_it_cannot_be_is_named_once(black_room, caplog):
    """An organ 100 m above the chamber (a plant drawn in mm and declared in m, say) gets no light: it is named,
    with its bounding box and the chamber's in the plant's unit, once per run, and flagged in the step."""
    model = _model(black_room, photons=2_000)
    far = {1: disc_mesh(30, z=500), 2: disc_mesh(30, z=100_000)}
    with caplog.at_level("WARNING", logger="lpy_light"):
        first = model.run(model.organs_from_meshes(far, module="Leaf"))
        second = model.run(model.organs_from_meshes(far, module="Leaf"))
    lines = [r.getMessage() for r in caplog.records if "outside the chamber" in r.getMessage()]
    assert len(lines) == 1 and "keys 2" in lines[0] and "1e+05" in lines[0] and "1100" in lines[0], lines
    assert first.extra["outside_chamber"] == [2] == second.extra["outside_chamber"]
    assert model.messages.counts[next(k for k in model.messages.counts if "outside the chamber" in k)] == 2
    assert first.organs[2].role == "not reached" and first.organs[1].ppfd[0] > 0
    inside = model.run(model.organs_from_meshes({1: disc_mesh(30, z=500)}, module="Leaf"))
    assert "outside_chamber" not in inside.extra


def test_a_plant_above_what_a_calibration_surveyed_is_warned_about_once(black_room, caplog):
    """A fitted chamber carries where its survey constrains the light ([surveyed], lpy-light calibrate): a plant
    that grows above it is told, once, with the fitted light's σ at its height."""
    from lpy_light.chamber.scene import load_scene
    from lpy_light.chamber.overrides import read_surveyed

    chamber = load_scene(black_room)
    chamber.surveyed = read_surveyed({"lower": [400, 400, 300], "upper": [600, 600, 300], "margin": 50.0,
                                      "sigma": [[300.0, 0.01], [700.0, 0.09]]}, ValueError)
    model = _model(chamber, photons=2_000)
    with caplog.at_level("WARNING", logger="lpy_light"):
        model.run(model.organs_from_meshes({1: disc_mesh(30, z=320)}, module="Leaf"))
        assert not [r for r in caplog.records if "survey" in r.getMessage()]
        for _ in range(2):
            model.run(model.organs_from_meshes({1: disc_mesh(30, z=320), 2: disc_mesh(30, z=700)}, module="Leaf"))
    lines = [r.getMessage() for r in caplog.records if "survey constrains" in r.getMessage()]
    assert len(lines) == 1 and "9.0 %" in lines[0], lines


def test_an_organ_no_sample_reached_is_undefined_not_zero_plus_minus_zero(black_room, caplog, tmp_path):
    """A leaf in a closed box that no photon enters has no estimate: not PAR 0 ± 0 (a σ of 0 claims a certainty
    the run does not have) but None for the rules, empty cells in organs.csv, and a warning counted per organ.
    The leaf beside it keeps its numbers."""
    import csv
    from lpy_light.plant.light import organ_rows
    from lpy_light.run.results import csv_text
    model = _model(black_room, photons=3_000)
    lit = disc_mesh(30, z=500)
    hidden = trimesh.creation.box(extents=(20, 20, 20)).apply_translation((300, 300, 100))   # closed: a cave
    inside = disc_mesh(3, z=100).apply_translation((300, 300, 0))
    organs = {1: lit, 2: (hidden, BLACK), 3: inside}
    with caplog.at_level("WARNING", logger="lpy_light"):
        lights = model.intercept(organs)
    assert lights[3] is None and lights[1] is not None and lights[1].ppfd_std[0] > 0
    assert lights[2] is not None                        # the box's outside is lit
    warned = [r.getMessage() for r in caplog.records if "no sample of this step reached it" in r.getMessage()]
    assert len(warned) == 1 and "organ 3" in warned[0]
    assert model.messages.counts[next(k for k in model.messages.counts if "no sample" in k)] == 1
    step = model.run(model.organs_from_meshes(organs))
    assert step.organs[3].role == "not reached" and math.isnan(step.organs[3].ppfd[0])
    (tmp_path / "organs.csv").write_text(csv_text(organ_rows(step)))
    rows = [r for r in csv.DictReader(open(tmp_path / "organs.csv")) if r["organ"] == "3"]
    assert rows and all(r["ppfd"] == "" and r["ppfd_std"] == "" and r["role"] == "not reached" for r in rows)
    assert model.messages.counts[next(k for k in model.messages.counts if "no sample" in k)] == 2


@pytest.mark.parametrize("photons", [-5, 0, 2.5, "many", True])
def test_a_photon_count_that_is_not_one_is_refused_where_it_is_written(black_room, photons):
    with pytest.raises(InputError, match="photons must be a whole number"):
        _model(black_room, photons=photons)


def test_precision_on_the_targets_stops_when_their_par_is_there(black_room):
    """``precision``: a step traces until every target organ's σ is at most the goal (here one band: its ppfd);
    a goal out of reach stops at the photon cap and says so."""
    model = _model(black_room, photons=2_000_000, precision=0.02)
    step = model.run(model.organs_from_meshes({1: disc_mesh(40, z=500)}, module="Leaf"))
    light = step.organs[1]
    assert step.extra["precision_reached"] and step.photons < 2_000_000
    assert light.ppfd_std[0] / light.ppfd[0] <= 0.02
    capped = _model(black_room, photons=140_000, precision=1e-4)
    step = capped.run(capped.organs_from_meshes({1: disc_mesh(40, z=500)}, module="Leaf"))
    assert step.photons == 140_000 and not step.extra["precision_reached"]


def test_lamp_scale_multiplies_the_flux_per_band(tmp_path):
    """``lamp_scale``: a number dims every band; ``{"LO-HI": k}`` the bands within LO-HI nm only."""
    from lpy_light.plant.light import lamp_factors

    class Bands:
        n_bands, bands = 3, [(600, 655), (655, 665), (725, 735)]
        band_labels = ["600-655", "655-665", "725-735"]
    assert list(lamp_factors(0.5, Bands)) == [0.5, 0.5, 0.5]
    assert list(lamp_factors({"400-800": 0.5, "700-800": 2.0}, Bands)) == [0.5, 0.5, 1.0]
    for bad in ({"800-900": 2.0}, {"far": 2.0}, -1, "x"):
        with pytest.raises(InputError, match="lamp_scale"):
            lamp_factors(bad, Bands)
