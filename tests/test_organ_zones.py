"""Next events near organs: picks by importance (:func:`kernel.nee.importance_cdf`), and two-step events
through the organ surface beside an organ (:mod:`kernel.organ_zones`), against counting and each other.

The scene is a bud in a pocket: an icosphere 6 mm under a thin leaf (R 0.4, T 0.5) that shades it from
the lamp, so that most of its light is what the leaf transmits from right above it — the far red a rose's
axillary bud gets under its leaf — and 49 more buds far away (targets enough for random picks)."""
import math

import numpy as np
import pytest
import trimesh

from lpy_light.kernel.importance import cluster_cdf, draw
from lpy_light.kernel.organ_zones import solid_angles
from lpy_light.kernel.records import T_MESH2
from lpy_light.kernel.sampling import triangle_solid_angle
from lpy_light.plant.light import LightModel
from scenes import box, rad_polygon, write_scene

ROOM = ("void plastic grey\n0\n0\n5 0.5 0.5 0.5 0 0\n\n"
        "void trans diffuser\n0\n0\n7 0.1 0.1 0.1 0 0 0.7 0\n\n"
        "void light lamp\n0\n0\n3 10 10 10\n\n"
        + box("grey", (0, 0, 0), (1000, 1000, 1100))
        + rad_polygon("diffuser", "sheet", [(200, 200, 950), (800, 200, 950), (800, 800, 950), (200, 800, 950)])
        + "lamp cylinder tube\n0\n0\n7 300 500 1020 700 500 1020 5\n\n")
THIN, GREEN = {"reflectance": 0.4, "transmittance": 0.5}, {"reflectance": 0.3}


def _pocket():
    leaf = trimesh.Trimesh([[-100, -100, 260], [100, -100, 260], [100, 100, 260], [-100, 100, 260]],
                           [[0, 1, 2], [0, 2, 3]])
    organs = {1: (trimesh.creation.icosphere(subdivisions=1, radius=4.0).apply_translation((0, 0, 250)), GREEN, "Bud"),
              2: (leaf, THIN, "Leaf")}
    for i in range(49):
        bud = trimesh.creation.icosphere(subdivisions=1, radius=4.0)
        organs[10 + i] = (bud.apply_translation((-300 + 20 * (i // 7), 250 + 20 * (i % 7), 100)), GREEN, "Bud")
    return organs


@pytest.fixture(scope="module")
def pocket(tmp_path_factory):
    return write_scene(tmp_path_factory.mktemp("pocket"), ROOM), _pocket()


def _bud(scene, organs, estimator, photons, seed, zones=0.5, importance=True):
    model = LightModel(scene, organs={"Bud": GREEN, "Leaf": THIN}, lamp_flux=100.0, plant_unit="mm",
                       position=(500, 500, 0), photons=photons, estimator=estimator, seed=seed, targets=["Bud"],
                       threads=2)
    model.kscene.configure(organ_zones=zones, importance=importance)
    light = model.intercept(organs)[1]
    return light.ppfd[0], light.ppfd_std[0]


def test_organ_zone_events_are_unbiased_and_lower_the_variance(pocket):
    """The bud's light with zone events agrees with the bud's own events alone and with counting (|z| < 4),
    at a quarter of their relative variance or less (measured 0.22-0.25).  Forgetting to skip the own events
    of a photon that lands in a zone counts that light twice: 20.1 ± 0.7 for 12.9 (z ≈ +10 here)."""
    scene, organs = pocket
    zones, zones_std = _bud(scene, organs, "nee", 400_000, 61)
    own, own_std = _bud(scene, organs, "nee", 400_000, 62, zones=0.0)
    counted, counted_std = _bud(scene, organs, "weighted", 10_000_000, 63)
    assert abs(zones - own) < 4 * math.hypot(zones_std, own_std), (zones, zones_std, own, own_std)
    assert abs(zones - counted) < 4 * math.hypot(zones_std, counted_std), (zones, zones_std, counted, counted_std)
    assert (zones_std / zones) ** 2 < 0.4 * (own_std / own) ** 2, (zones_std / zones, own_std / own)


def test_zone_events_serve_the_buds_only(pocket):
    """Organ zone events go to the small targets (buds) only: a leaf's near light comes from its own events, and
    the zone events' noise was some leaves' largest term (issue 28).  With the leaf a target too, and a white
    board 40 mm under it (not a target) that lights its underside, the leaf's and the bud's light agree with
    counting (|z| < 4).  Skipping the leaf's own events at the board's vertices as if zone events served them
    loses that light (fails, tried: 44.2 ± 0.4 for 49.8 ± 0.2 on the leaf, z = -14)."""
    scene, organs = pocket
    organs = dict(organs)
    board = trimesh.Trimesh([[-150, -150, 220], [150, -150, 220], [150, 150, 220], [-150, 150, 220]],
                            [[0, 1, 2], [0, 2, 3]])
    organs[100] = (board, {"reflectance": 0.8}, "Board")
    out = {}
    for estimator, photons, seed in (("nee", 300_000, 91), ("weighted", 6_000_000, 92)):
        model = LightModel(scene, organs={"Bud": GREEN, "Leaf": THIN, "Board": {"reflectance": 0.8}},
                           lamp_flux=100.0, plant_unit="mm", position=(500, 500, 0), photons=photons,
                           estimator=estimator, seed=seed, targets=["Leaf", "Bud"], threads=2)
        lights = model.intercept(organs)
        out[estimator] = {k: (lights[k].ppfd[0], lights[k].ppfd_std[0]) for k in (1, 2)}
        if estimator == "nee":
            zw = model.kscene.records()[1].organs.zones.weight
            tgt = model.kscene.targets
            kinds = {organ.module for organ, t in zip(model.kscene.organs, tgt.receiver_target[model.kscene.n_chamber_receivers:])
                     if t >= 0 and zw[t] > 0}
            assert kinds == {"Bud"}, kinds
    for k in (1, 2):
        (a, sa), (b, sb) = out["nee"][k], out["weighted"][k]
        assert abs(a - b) < 4 * math.hypot(sa, sb), (k, a, sa, b, sb)


def test_importance_picks_are_unbiased(pocket):
    """Uniform and importance picks give the same light on the bud under the leaf and on a far bud."""
    scene, organs = pocket
    a, sa = _bud(scene, organs, "nee", 300_000, 71, importance=True)
    b, sb = _bud(scene, organs, "nee", 300_000, 72, importance=False)
    assert abs(a - b) < 4 * math.hypot(sa, sb), (a, sa, b, sb)


def test_picks_follow_what_a_vertex_can_bring(pocket):
    """Picks drawn as many as a vertex's pick share asks (:func:`kernel.nee.pick_share`: its photon's weight, its
    material's diffuse reflectance or transmittance, the targets' importances summed; here a mean of 1 over a
    pilot's vertices, so that many draw fewer than one on average) give each of the 50 buds the same light as one
    pick at every vertex (|z| < 4; measured from -2.3 to 3.0, mean -0.08).  Dividing each deposit by the picks
    drawn instead of their mean fails it (a vertex that draws one pick for a mean of 0.3 then deposits 0.3 of its
    due over its draws: tried, z from -6.9 to -1.2, mean -4.7)."""
    scene, organs = pocket
    out = []
    for share, seed in ((True, 81), (False, 82)):
        model = LightModel(scene, organs={"Bud": GREEN, "Leaf": THIN}, lamp_flux=100.0, plant_unit="mm",
                           position=(500, 500, 0), photons=300_000, seed=seed, targets=["Bud"], threads=2)
        model.kscene.configure(pick_share=share, picks=1)
        lights = model.intercept(organs)
        buds = sorted(k for k in lights if lights[k].module == "Bud")
        out.append((np.array([lights[k].ppfd[0] for k in buds]), np.array([lights[k].ppfd_std[0] for k in buds])))
        organ_events = model.kscene.records()[1].organs
        assert (organ_events.pick_mean > 0) == share, organ_events.pick_mean
    (a, sa), (b, sb) = out
    z = (a - b) / np.hypot(sa, sb)
    assert len(z) == 50 and np.all(np.abs(z) < 4), z


def test_importance_picks_favour_the_targets_beside_a_vertex(pocket):
    """Seen from a point of the leaf 30 mm from the bud (outside its near radius), the bud is drawn ~30x as
    often as a far bud; the leaf itself (a vertex on it is within its near radius) is never drawn; the
    probabilities the draws report are their frequencies (χ²)."""
    scene, organs = pocket
    model = LightModel(scene, organs={"Bud": GREEN, "Leaf": THIN}, lamp_flux=100.0, plant_unit="mm",
                       position=(500, 500, 0), photons=1, targets=None)
    ks = model.kscene
    ks.configure(sensors=False)
    ks.set_organs(model.organs_from_meshes(organs), model.materials)
    (_, nee) = ks.records()
    tgt, organs = nee.targets, nee.organs
    n, k = len(tgt.kind), len(organs.clusters.radius)
    assert organs.weight.shape == (n,) and 1 < k < n        # organs only: picks by importance, over clusters
    bud, leaf = tgt.receiver_target[0], tgt.receiver_target[1]
    cdf, exact = np.zeros(n + k), np.zeros(k, np.uint8)
    v = (530.0, 500.0, 260.0)
    how = (organs.weight, organs.cluster_weight, tgt.img_near2, 9.0, True, organs.far_weight)
    total = cluster_cdf(v, how, organs.clusters, tgt, cdf, exact)
    rng = np.random.default_rng(3)
    counts, prob = np.zeros(n), np.full(n, np.nan)
    for u1, u2 in rng.random((20000, 2)):
        t, p = draw(u1, u2, total, v, how, organs.clusters, tgt, cdf, exact)
        counts[t] += 1
        assert np.isnan(prob[t]) or prob[t] == pytest.approx(p, rel=1e-12)
        prob[t] = p
    assert counts[leaf] == 0
    far = [t for t in range(n) if t not in (bud, leaf)]
    assert counts[bud] > 10 * counts[far].max(), (counts[bud], counts[far].max())
    drawn = counts > 0
    assert prob[drawn].sum() == pytest.approx(1.0, abs=1e-9)
    expected = 20000 * prob[drawn]
    chi2 = ((counts[drawn] - expected) ** 2 / expected).sum()
    assert chi2 < drawn.sum() + 5 * math.sqrt(2 * drawn.sum()), chi2


def _bud_scene(scene, organs):
    """The pocket's KernelScene with its organs set, the bud the only kind of target (no sensors)."""
    model = LightModel(scene, organs={"Bud": GREEN, "Leaf": THIN}, lamp_flux=100.0, plant_unit="mm",
                       position=(500, 500, 0), photons=1, targets=["Bud"])
    ks = model.kscene
    ks.configure(sensors=False)
    ks.set_organs(model.organs_from_meshes(organs), model.materials)
    return ks


def test_zones_are_the_other_organs_surface_within_the_near_radius(pocket):
    """The bud's zone is the leaf's triangles within its near radius (none of its own, none of the chamber);
    each zone's cumulative areas and solid angles end at 1 and its totals are their sums."""
    scene, organs = pocket
    ks = _bud_scene(scene, organs)
    oz, tgt = ks.organ_events.zones, ks.targets
    bud = tgt.receiver_target[0]
    z = int(np.flatnonzero(oz.target == bud)[0])
    tris = oz.tri[oz.start[z]:oz.start[z + 1]]
    assert set(ks.tri_receiver[tris].tolist()) == {ks.n_chamber_receivers + 1}     # the leaf's, nothing else
    assert np.all(tris >= ks.n_chamber_triangles)
    for z in range(len(oz.target)):
        sl = slice(oz.start[z], oz.start[z + 1])
        assert oz.cdf_area[sl][-1] == pytest.approx(1.0) and oz.cdf_angle[sl][-1] == pytest.approx(1.0)
        assert np.all(np.diff(oz.cdf_area[sl]) >= 0) and np.all(np.diff(oz.cdf_angle[sl]) >= 0)
        t = oz.target[z]
        v = ks.tri_verts[oz.tri[sl]]
        area = 0.5 * np.linalg.norm(np.cross(v[:, 1] - v[:, 0], v[:, 2] - v[:, 0]), axis=1).sum()
        assert oz.total[z, 0] == pytest.approx(area)
        angle = sum(triangle_solid_angle(*tgt.center[t], *tri) for tri in v)
        assert oz.total[z, 1] == pytest.approx(angle)
        assert tgt.kind[t] >= T_MESH2


def test_solid_angles_of_triangles():
    """The vectorised solid angles equal the kernel's, and a large square right under a point subtends ~2π."""
    rng = np.random.default_rng(5)
    tris = rng.normal(size=(50, 3, 3))
    expected = [triangle_solid_angle(0.0, 0.0, 0.0, t[0], t[1], t[2]) for t in tris]
    assert np.allclose(solid_angles(tris), expected, rtol=1e-12, atol=1e-15)
    big = np.array([[[-1e4, -1e4, -1.0], [1e4, -1e4, -1.0], [1e4, 1e4, -1.0]],
                    [[-1e4, -1e4, -1.0], [1e4, 1e4, -1.0], [-1e4, 1e4, -1.0]]])
    assert solid_angles(big).sum() == pytest.approx(2 * math.pi, rel=1e-3)


def _open_bud(center, radius=3.0):
    """A bud as ``F() Sphere()`` under ``SectionResolution(4)`` draws part of it in rose-simple4.lpy: a
    four-sided tube, open at both ends (here 4 radii long, upright, without the sphere)."""
    tube = trimesh.creation.cylinder(radius=radius, height=4 * radius, sections=4)
    walls = np.abs(tube.face_normals[:, 2]) < 0.5
    return trimesh.Trimesh(tube.vertices, tube.faces[walls], process=False).apply_translation(center)


def test_an_open_bud_lights_its_own_inside(tmp_path):
    """An open bud (a tube, white inside) gets much of its light from its own inside: a photon that enters bounces
    there, each landing making a large own event -- rare photons carrying a large share, the heavy tail of
    rose-simple4's buds' far red.  Its own surface is in its zone (zone events land inside it) and the zone events
    walk on the short legs after (:func:`kernel.organ_zones.zone_walk`).  Against counting and against the
    estimator without either (|z| < 4), at less than 0.04 of the latter's relative variance (measured 0.011).
    Not skipping a photon's own events inside the tube where zone events served them counts that light twice,
    and its noise with it: 0.12 (first landings) and 0.38 (the walk's legs) -- both fail."""
    scene = write_scene(tmp_path, ROOM)
    white = {"reflectance": 0.8}
    organs = {k: (mesh, white, "Bud") for k, (mesh, _, kind) in _pocket().items() if kind == "Bud"}
    organs[1] = (_open_bud((0, 0, 250)), white, "Bud")

    def bud(estimator, photons, seed, new=True):
        model = LightModel(scene, organs={"Bud": white}, lamp_flux=100.0, plant_unit="mm", position=(500, 500, 0),
                           photons=photons, estimator=estimator, seed=seed, targets=["Bud"], threads=2)
        model.kscene.configure(open_zones=new, zone_walk=model.kscene.settings.zone_walk if new else 0)
        light = model.intercept(organs)[1]
        return light.ppfd[0], light.ppfd_std[0]

    (a, sa), (b, sb), (c, sc) = bud("nee", 1_000_000, 51), bud("nee", 1_000_000, 52, False), bud("weighted", 16_000_000, 53)
    assert abs(a - c) < 4 * math.hypot(sa, sc), (a, sa, c, sc)
    assert abs(a - b) < 4 * math.hypot(sa, sb), (a, sa, b, sb)
    assert (sa / a) ** 2 < 0.04 * (sb / b) ** 2, (sa / a, sb / b)


def test_a_translucent_closed_bud_lights_its_own_inside(tmp_path):
    """A closed bud of translucent tissue (a leaf's far red: R 0.4, T 0.45) under the leaf: light that enters it
    bounces inside, each bounce incident on the bud again -- in a rose's buds a quarter of their far red and, while
    only the photons that landed on a bud found it, ~85 % of its variance (buds' far-red σ at 10⁶ photons 0.25, so
    their R:FR read high: issue 45).  With its own surface in its zone (``closed_zones``) the zone events from every
    vertex estimate that light.  Against counting and against the estimator without it (|z| < 4), at less than half
    its relative variance (measured 0.17: 22.9 ± 1.0 against 22.9 ± 2.4, counting 23.2 ± 1.4); an opaque closed bud's zone is not given its own surface."""
    scene = write_scene(tmp_path, ROOM)
    far_red = {"reflectance": 0.4, "transmittance": 0.45}
    organs = {k: (mesh, far_red if kind == "Bud" else mat, kind) for k, (mesh, mat, kind) in _pocket().items()}

    def bud(estimator, photons, seed, closed=True):
        model = LightModel(scene, organs={"Bud": far_red, "Leaf": THIN}, lamp_flux=100.0, plant_unit="mm",
                           position=(500, 500, 0), photons=photons, estimator=estimator, seed=seed,
                           targets=["Bud"], threads=2)
        model.kscene.configure(closed_zones=closed)
        light = model.intercept(organs)[1]
        return light.ppfd[0], light.ppfd_std[0], model.kscene.organ_events

    (a, sa, ev), (b, sb, _), (c, sc, _) = (bud("nee", 1_000_000, 61), bud("nee", 1_000_000, 62, False),
                                           bud("weighted", 16_000_000, 63))
    assert ev.zones.own.any()
    assert abs(a - c) < 4 * math.hypot(sa, sc), (a, sa, c, sc)
    assert abs(a - b) < 4 * math.hypot(sa, sb), (a, sa, b, sb)
    assert (sa / a) ** 2 < 0.5 * (sb / b) ** 2, (sa / a, sb / b)
    print("closed zones %.4g ± %.3g, without %.4g ± %.3g, counting %.4g ± %.3g; relative variance ratio %.3f"
          % (a, sa, b, sb, c, sc, (sa / a) ** 2 / (sb / b) ** 2))
    opaque = LightModel(scene, organs={"Bud": GREEN, "Leaf": THIN}, lamp_flux=100.0, plant_unit="mm",
                        position=(500, 500, 0), targets=["Bud"], photons=1000)
    opaque.intercept(_pocket())
    assert not opaque.kscene.organ_events.zones.own.any()


def test_which_landings_the_zone_events_served(pocket):
    """:func:`kernel.nee.zone_served` against the chains of organ vertices it is given: a landing on the bud's zone
    is served by a long leg into it (at least the near radius), or by up to ``walk`` short legs on the zone after
    such a one; not by short legs alone, nor after a start outside the zone or, for a closed bud, on the bud
    itself (its own events there are never skipped), unless its own surface is in its zone."""
    from lpy_light.kernel.nee import zone_served

    scene, organs = pocket
    ks = _bud_scene(scene, organs)
    (scene_rec, nee) = ks.records()
    tgt, geo, ev = nee.targets, scene_rec.geometry, nee.organs
    bud = tgt.receiver_target[0]
    r2 = tgt.near_r2[bud]
    leaf_tri = int(np.flatnonzero(ks.tri_receiver == ks.n_chamber_receivers + 1)[0])
    bud_tri = int(np.flatnonzero(ks.tri_receiver == ks.n_chamber_receivers)[0])
    long, short = 4 * r2, 0.01 * r2
    near_leaf = lambda leg2: (500.0, 505.0, 260.0, leaf_tri, leg2)          # noqa: E731  (10 mm from the bud)
    far_leaf = (500.0, 500.0 + 2 * math.sqrt(r2), 260.0, leaf_tri, long)    # outside its near radius
    on_bud = (500.0, 500.0, 254.0, bud_tri, long)

    def served(*chain, own=0):
        organs_ = ev._replace(zones=ev.zones._replace(own=np.full_like(ev.zones.own, own)))
        return zone_served(bud, len(chain), np.array(chain, float), geo, tgt, organs_)

    walk = int(ev.zones.walk)
    assert walk > 0
    assert served(near_leaf(long))
    assert not served(near_leaf(short))
    assert served(near_leaf(long), near_leaf(short))
    assert served(near_leaf(long), *[near_leaf(short)] * walk)
    assert not served(near_leaf(long), *[near_leaf(short)] * (walk + 1))
    assert not served(near_leaf(short), near_leaf(short))
    assert not served(far_leaf, near_leaf(short))
    assert not served(on_bud, near_leaf(short))
    assert served(on_bud, near_leaf(short), own=1)
