"""The ``field`` estimator (:mod:`lpy_light.estimators.field`): the light entering the plant's region stored once, each
step's rays kept inside the region.

The scene (as ``test_reuse``'s): a room whose ceiling light comes through a diffusing sheet, one wall a perfect
mirror (its light reaches the region through the field), a bud in a pocket under a thin translucent leaf (most of
its light is what the leaf transmits and scatters: the passes between organs), and 24 more buds."""
import dataclasses
import math

import numpy as np
import pytest
import trimesh

from lpy_light.errors import InputError
from lpy_light.estimators.field import FieldSettings, clear_of_lamps, clip_polygon, face_grid, field_step, \
    inside_walls, lamp_bounds
from lpy_light.chamber.emitters import EmitterBuilder
from lpy_light.kernel.field import draw_direction, field_bin, guide_tables, sphere_bin, stratified_directions
from lpy_light.kernel.rng import seed_stream
from lpy_light.plant.light import LightModel
from scenes import write_scene
from test_reuse import GREEN, ROOM, THIN, _light, _plant

SMALL = FieldSettings(store_photons=400_000, batches=8, rays=512, shading_rays=64)


@pytest.fixture(scope="module")
def room(tmp_path_factory):
    return write_scene(tmp_path_factory.mktemp("field"), ROOM)


def _model(scene, estimator, photons=400_000, seed=1, field=SMALL):
    return LightModel(scene, organs={"Bud": GREEN, "Leaf": THIN}, lamp_flux=100.0, plant_unit="mm",
                      position=(500, 500, 0), photons=photons, estimator=estimator, seed=seed, threads=2,
                      field=field if estimator == "field" else None)


@pytest.fixture(scope="module")
def full(room):
    """The full kernel's light of the plant, 1.6e6 photons."""
    return _light(_model(room, "nee", 1_600_000, seed=3), _plant())


def test_the_field_agrees_with_the_full_kernel_organ_by_organ(room, full):
    """The same plant lit by the full kernel and from a field traced with it in place: every organ's light agrees
    (|z| < 4.5), the whole plant's too (|z| < 4), and the z-scores spread as σ says (standard deviation 0.5-1.6:
    the field's σ, its store's error included, is honest)."""
    model = _model(room, "field", seed=5)
    light, sigma = _light(model, _plant())
    assert model.keeper.built == 1
    z = (light - full[0]) / np.hypot(sigma, full[1])
    assert np.all(np.abs(z) < 4.5), z
    assert 0.5 < np.std(z) < 1.6, np.std(z)
    plant_z = (light.sum() - full[0].sum()) / math.hypot(np.sqrt(np.sum(sigma ** 2)), np.sqrt(np.sum(full[1] ** 2)))
    assert abs(plant_z) < 4, plant_z


def test_without_the_passes_between_organs_the_pocket_bud_loses_its_light(room, full):
    """The control: the same field read with no pass and no bounce (no light between organs) leaves the bud under the leaf far
    below the full kernel (z < -8): the passes are what light it."""
    model = _model(room, "field", seed=5)
    organs = model.organs_from_meshes(_plant())
    model.run(organs)                                    # the field, traced once
    result = field_step(model.kscene, model.keeper.field, dataclasses.replace(SMALL, bounces=0), seed=5,
                        threads=2, max_passes=0)
    from lpy_light.plant.organ_light import organ_lights
    lights = organ_lights(model.kscene, result, organs, model.flux, model.flux_std, model.chamber)
    pocket = lights[1]
    z = (pocket.ppfd[0] - full[0][0]) / math.hypot(pocket.ppfd_std[0], full[1][0])
    assert z < -8, z


def test_a_field_is_never_used_stale(room):
    """A new field when a lamp's output or a material changes, when the plant leaves the region, and after
    ``renew`` steps; the same one otherwise (``StepResult.extra['store']`` names it)."""
    settings = FieldSettings(store_photons=20_000, batches=4, rays=8, shading_rays=4, piece_rays=4, renew=3)
    organs = _plant()
    model = _model(room, "field", field=settings)

    def steps(n, plant=organs):
        return [model.run(model.organs_from_meshes(plant)).extra["store"] for _ in range(n)]

    first = steps(2)
    assert first[0]["field"] == first[1]["field"] and model.keeper.built == 1 and first[0]["why"] == "first step"
    model.flux = model.flux * 2.0
    moved = steps(1)[0]
    assert moved["field"] != first[0]["field"] and "lamps" in moved["why"], moved
    grey = next(m for m in model.kscene.materials if m.name == "grey")
    grey.events[0] *= 0.9
    grey.events[4] = 1.0 - grey.events[:4].sum(axis=0)
    changed = steps(1)[0]
    assert changed["field"] != moved["field"] and model.keeper.built == 3, changed
    after = steps(3)
    assert [s["field"] for s in after[:2]] == [changed["field"]] * 2 and after[2]["why"] == "renewed after 3 steps"
    far = steps(1, _plant(lift=400.0))[0]
    assert far["why"] == "the plant left the field's region", far


def test_a_field_step_is_the_same_on_any_number_of_threads(room):
    settings = FieldSettings(store_photons=40_000, batches=4, rays=16, shading_rays=8, piece_rays=8)
    out = []
    for threads in (1, 3):
        model = _model(room, "field", field=settings)
        model.threads = threads
        out.append(_light(model, _plant()))
    assert np.array_equal(out[0][0], out[1][0]) and np.array_equal(out[0][1], out[1][1])


def test_field_settings_refuse_what_they_cannot_do(room):
    with pytest.raises(InputError, match="batches"):
        FieldSettings(batches=2)
    with pytest.raises(InputError, match="unknown field setting"):
        _model(room, "field", field={"photons": 10})


def test_the_bins_are_of_equal_projected_solid_angle_and_tile_the_faces():
    """Directions drawn cosine-weighted through a face fill its direction bins equally (χ²), and points drawn over
    the faces fill their cells in proportion to area; a point and direction fall in one bin only."""
    box = np.array([0.0, 0.0, 0.0, 2.0, 1.0, 0.5])
    grid, face0 = face_grid(box, 4)
    rings, sectors = 4, 8
    rng = np.random.default_rng(1)
    n = 40_000
    counts = np.zeros(rings * sectors)
    for _ in range(n):
        u1, u2 = rng.random(2)
        d = np.array([math.sqrt(1 - u1), math.sqrt(u1) * math.cos(2 * math.pi * u2), math.sqrt(u1) * math.sin(2 * math.pi * u2)])
        k = field_bin(box, grid, face0, rings, sectors, 0, 0.0, 0.3, 0.2, d[0], d[1], d[2])
        assert k // (rings * sectors) == face0[0] + 0 * grid[0, 1] + 0         # y 0.3 of 1 in 2, z 0.2 of 0.5 in 1
        counts[k % (rings * sectors)] += 1
    expected = n / len(counts)
    chi2 = np.sum((counts - expected) ** 2 / expected)
    assert chi2 < len(counts) + 4 * math.sqrt(2 * len(counts)), chi2
    assert grid.tolist() == [[2, 1], [2, 1], [1, 4], [1, 4], [4, 2], [4, 2]]
    assert face0.tolist() == [0, 2, 4, 8, 12, 20]
    # a point in the upper half of face 0's y-range falls in its second cell
    k = field_bin(box, grid, face0, rings, sectors, 0, 0.0, 0.7, 0.2, 1.0, 0.0, 0.0)
    assert k // (rings * sectors) == 1


def test_a_triangle_clipped_to_a_box_keeps_the_part_inside():
    tri = np.array([[-1.0, -1.0, 0.5], [3.0, -1.0, 0.5], [-1.0, 3.0, 0.5]])
    poly = clip_polygon(tri, np.zeros(3), np.ones(3))
    assert np.allclose(poly.min(axis=0), [0, 0, 0.5]) and np.allclose(poly.max(axis=0), [1, 1, 0.5])
    area = 0.5 * abs(sum(np.cross(poly[i], poly[(i + 1) % len(poly)])[2] for i in range(len(poly))))
    assert area == pytest.approx(1.0)


def _guided(guide, normal, share, n, seed=3, groups=8):
    """n directions drawn as a step draws a side's first rays, from ``guide`` (1, bins) mixed with ``share`` of
    the cosine; their (n, 3) directions and weights."""
    state = np.zeros(1, np.uint64)
    seed_stream(state, seed, 0)
    lattice, cosine = np.empty((n, 2)), np.empty(n, bool)
    stratified_directions(state, n, groups, share, lattice, cosine)
    rng = np.random.default_rng(seed)
    out = [draw_direction(guide, 0, share, 32, *normal, cosine[j], lattice[j, 0], lattice[j, 1], rng.random())
           for j in range(n)]
    return np.array([o[:3] for o in out]), np.array([o[3] for o in out])


def test_guided_directions_weigh_back_to_the_cosine():
    """Directions drawn from a peaked guide mixed with the cosine, each weighed by (cos θ / π) / its density:
    over any set of directions the weights' mean is that set's cosine-weighted share (the guide changes where
    the rays go, not what they estimate): the whole hemisphere (1), a cone about the normal (sin² of its half
    angle), and single sphere bins (their integral of cos θ / π), within 4σ; a density that left out the bins'
    solid angle fails."""
    rng = np.random.default_rng(2)
    weights = rng.random(512) ** 8                           # a few bright bins hold most of the guide
    guide = (np.cumsum(weights) / weights.sum())[None]
    normal = np.array([0.3, -0.5, 0.8]) / np.linalg.norm([0.3, -0.5, 0.8])
    d, w = _guided(guide, normal, 0.25, 16384)
    n = len(w)

    def check(inside, expected):
        f = w * inside
        assert abs(f.mean() - expected) < 4 * f.std() / math.sqrt(n) + 1e-12, (f.mean(), expected)

    check(np.ones(n), 1.0)
    cos = d @ normal
    check(cos > math.cos(0.6), math.sin(0.6) ** 2)
    bins = np.array([sphere_bin(*x, 16, 32) for x in d])
    for b in [int(np.argmax(weights)), *np.argsort(weights)[-4:-1], 300]:
        iz, ip = divmod(int(b), 32)
        z = -1 + 2 * (iz + (np.arange(200) + 0.5) / 200) / 16
        phi = 2 * math.pi * (ip + (np.arange(200) + 0.5) / 200) / 32
        r = np.sqrt(1 - z[:, None] ** 2)
        c = r * np.cos(phi) * normal[0] + r * np.sin(phi) * normal[1] + z[:, None] * normal[2]
        exact = np.maximum(c, 0).mean() / math.pi * 4 * math.pi / 512
        check(bins == b, exact)


def test_a_guide_points_where_the_field_brings_light():
    """Light that enters the region only through its top face, downwards: a guide from the box's centre puts all
    its weight on directions that leave by the top; none below the side it is drawn for."""
    box = np.array([0.0, 0.0, 0.0, 1.0, 1.0, 1.0])
    grid, face0 = face_grid(box, 2)
    rings, sectors = 4, 8
    light = np.zeros(int((grid[:, 0] * grid[:, 1]).sum()) * rings * sectors)
    top = slice(face0[5] * rings * sectors, (face0[5] + grid[5, 0] * grid[5, 1]) * rings * sectors)
    light[top] = 1.0
    normals = np.array([[[0.0, 0.0, 1.0]] * 2, [[1.0, 0.0, 0.0]] * 2])
    cdf = guide_tables(box, grid, face0, rings, sectors, light, np.array([[0.5, 0.5, 0.5]] * 2), normals, 16, 32, 1)
    share = np.diff(np.concatenate([[0.0], cdf[0]]))
    z_band = np.arange(512) // 32
    assert share.sum() == pytest.approx(1.0)
    assert share[z_band < 8].sum() == 0.0                       # below the horizon of the side
    assert share[z_band >= 12].sum() > 0.9                      # steep enough to leave by the top
    # a side facing +x sees the top only through directions that also point up
    share_x = np.diff(np.concatenate([[0.0], cdf[1]]))
    assert share_x[z_band < 8].sum() == 0.0 and share_x.sum() == pytest.approx(1.0)


def test_the_region_is_cut_clear_of_every_lamp():
    """Light emitted inside the region never crosses its faces, so the field would miss it (a lamp hung low beside
    the plant, or under the bench it stands on, inside the grown box).  A lamp under the organs moves the bottom
    face halfway up to them; one beside them, the side face that keeps the most of the region; one outside the box
    changes nothing; one among the organs is refused."""
    lo, hi = np.array([20.0, 20.0, 0.0]), np.array([80.0, 80.0, 100.0])
    box = np.array([0.0, 0.0, -20.0, 100.0, 100.0, 120.0])
    under = np.array([[[50.0, 50.0, -6.0], [50.0, 50.0, -4.0]]])
    cut = clear_of_lamps(box, lo, hi, under)
    assert np.allclose(cut, [0, 0, -2, 100, 100, 120])
    beside = np.array([[[90.0, 10.0, 40.0], [92.0, 12.0, 42.0]]])     # below lo[1] and above hi[0]: keeps more
    cut = clear_of_lamps(box, lo, hi, beside)
    assert np.allclose(cut, [0, 0, -20, 85, 100, 120])
    assert np.all(cut[:3] <= lo) and np.all(cut[3:] >= hi)
    assert np.array_equal(clear_of_lamps(box, lo, hi, np.array([[[0.0, 0.0, 200.0], [1.0, 1.0, 201.0]]])), box)
    with pytest.raises(InputError, match="among the plant's organs"):
        clear_of_lamps(box, lo, hi, np.array([[[50.0, 50.0, 50.0], [50.0, 50.0, 50.0]]]))


def test_lamp_bounds_hold_each_kind_of_lamp():
    b = EmitterBuilder(lamps="lambertian")
    b.point([1.0, 2.0, 3.0], 1.0, "point")
    b.sphere([0.0, 0.0, 10.0], 2.0, 1.0, "ball")
    bounds = lamp_bounds(b.build())
    assert np.allclose(bounds[0], [[1, 2, 3], [1, 2, 3]])
    assert np.allclose(bounds[1], [[-2, -2, 8], [2, 2, 12]])


def _square(a, c, lo, hi):
    """Two triangles of the plane x_a = c, from lo to hi (2,) on the other two axes (a + 1, a + 2 mod 3)."""
    a1, a2 = (a + 1) % 3, (a + 2) % 3
    quad = []
    for u, v in ((lo[0], lo[1]), (hi[0], lo[1]), (hi[0], hi[1]), (lo[0], hi[1])):
        p = np.zeros(3)
        p[a], p[a1], p[a2] = c, u, v
        quad.append(p)
    return np.array([[quad[0], quad[1], quad[2]], [quad[0], quad[2], quad[3]]])


def test_the_region_stops_at_a_wall_that_crosses_it_whole():
    """A plant against a wall: the grown box reaching behind it would read no light there, and the cells partly
    behind it the mean of lit and unlit parts (chambre2's rose against its wall: the field 6 % low, 4 % once cut).
    A wall crossing the whole box moves that face just inside the room; a wall with a gap, or the table the plant
    stands on, changes nothing."""
    lo, hi = np.array([20.0, 20.0, 0.0]), np.array([80.0, 80.0, 100.0])
    box = np.array([0.0, 0.0, -20.0, 100.0, 100.0, 120.0])
    wall = _square(1, 10.0, (-50.0, -50.0), (150.0, 150.0))             # y = 10, beyond the box in z and x
    cut = inside_walls(box, lo, hi, wall)
    assert 10.0 < cut[1] < 10.5 and np.array_equal(np.delete(cut, 1), np.delete(box, 1))
    half = _square(1, 10.0, (-50.0, -50.0), (50.0, 150.0))              # z from -50 to 50 only: a gap above
    assert np.array_equal(inside_walls(box, lo, hi, half), box)
    table = _square(2, 0.0, (-50.0, -50.0), (150.0, 150.0))             # z = 0, where the plant stands
    assert np.array_equal(inside_walls(box, lo, hi, table), box)
