"""Points on closed and one-sided organs drawn among the triangles facing the vertex
(:func:`kernel.nee.facing_triangle`, :func:`kernel.targets.closed_meshes`).

From beyond NEAR radii a closed mesh's far side is hidden by its near side: drawn by area over the whole bud, half
the next events' points were on its hidden side and found it (V = 0), and the other half deposited twice the
light.  Drawn among the triangles facing v, every point can be seen; the estimate has the same mean."""
import numpy as np
import pytest
import trimesh

from lpy_light.kernel.targets import closed_meshes
from lpy_light.plant.light import LightModel
from scenes import write_scene

from test_organ_zones import GREEN, ROOM, THIN


def _tris(mesh):
    return np.asarray(mesh.triangles, dtype=float)


def test_closed_meshes():
    """A sphere and a cube are closed; the same turned inside out (wound inward), with a face missing, with a
    face doubled, or an open leaf, are not; groups are told apart."""
    sphere, cube = _tris(trimesh.creation.icosphere(subdivisions=1)), _tris(trimesh.creation.box())
    leaf = np.array([[[0, 0, 0], [1, 0, 0], [1, 1, 0]], [[0, 0, 0], [1, 1, 0], [0, 1, 0]]], float)
    cases = [sphere, cube, sphere[:, ::-1], sphere[1:], np.concatenate([cube, cube[:1]]), leaf, cube + 5.0]
    tris = np.concatenate(cases)
    group = np.repeat(np.arange(len(cases)), [len(c) for c in cases])
    assert closed_meshes(tris, group).tolist() == [True, True, False, False, False, False, True]
    assert closed_meshes(np.zeros((0, 3, 3)), np.zeros(0, np.int64)).tolist() == []


def _organs():
    """Three buds (closed spheres, 80 triangles each) and a cube under a diffuser, a leaf (open) beside them."""
    organs = {}
    for i, (x, y) in enumerate(((-150, 0), (0, 120), (160, -60))):
        bud = trimesh.creation.icosphere(subdivisions=1, radius=6.0 + 2 * i).apply_translation((x, y, 300))
        organs[i] = (bud, GREEN, "Bud")
    organs[3] = (trimesh.creation.box((20, 20, 20)).apply_translation((0, -150, 250)), GREEN, "Bud")
    leaf = trimesh.Trimesh([[-60, -60, 200], [60, -60, 200], [60, 60, 200], [-60, 60, 200]], [[0, 1, 2], [0, 2, 3]])
    organs[4] = (leaf, THIN, "Leaf")
    return organs


def _light(scene, estimator, photons, seed, facing=True):
    model = LightModel(scene, organs={"Bud": GREEN, "Leaf": THIN}, lamp_flux=100.0, plant_unit="mm",
                       position=(500, 500, 0), photons=photons, estimator=estimator, seed=seed,
                       targets=["Leaf", "Bud"], threads=2)
    converted = model.organs_from_meshes(_organs())
    if not facing:                       # points by area on the whole mesh, as before
        model.kscene.configure(facing=False)
    step = model.run(converted)
    keys = sorted(step.organs)
    return (np.array([step.organs[k].ppfd[0] for k in keys]), np.array([step.organs[k].ppfd_std[0] for k in keys]),
            model.kscene.targets)


@pytest.fixture(scope="module")
def scene(tmp_path_factory):
    return write_scene(tmp_path_factory.mktemp("facing"), ROOM)


def test_facing_points_keep_the_light_and_lower_the_buds_variance(scene):
    """The buds' and the cube's light with points among the facing triangles agrees with counting (weighted,
    10x the photons) and with points over the whole mesh (|z| < 4 each); their relative variance is below 0.7
    of the whole mesh's at the same photons (about half of the points were hidden).  Drawing among the facing
    triangles but depositing the whole mesh's area (A instead of A_facing) reads about twice the light: z = +11
    to +25 (tried)."""
    facing, facing_sd, tgt = _light(scene, "nee", 150_000, 21)
    assert tgt.facing.tolist()[-5:] == [1, 1, 1, 1, 0]       # the three spheres and the cube; not the open leaf
    whole, whole_sd, _ = _light(scene, "nee", 150_000, 22, facing=False)
    counted, counted_sd, _ = _light(scene, "weighted", 1_500_000, 23)
    for other, other_sd in ((counted, counted_sd), (whole, whole_sd)):
        z = (facing - other) / np.hypot(facing_sd, other_sd)
        assert np.all(np.abs(z) < 4), z
    buds = slice(0, 4)
    ratio = (facing_sd / facing)[buds] ** 2 / (whole_sd / whole)[buds] ** 2
    assert np.all(ratio < 0.7), ratio
