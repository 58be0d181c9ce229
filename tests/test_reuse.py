"""The ``reuse`` estimator (:mod:`lpy_light.estimators.reuse`): the chamber's light stored once, gathered at each organ.

The scene: a room whose ceiling light comes through a diffusing sheet, one wall a perfect mirror (the light it
sends the organs comes by the gather's image draws), a bud in a pocket under a thin translucent leaf (most of
its light is what the leaf transmits and scatters: the paths and the zone events), and 24 more buds."""
import math

import numpy as np
import pytest
import trimesh

from lpy_light.errors import InputError
from lpy_light.plant.light import LightModel
from lpy_light.estimators.reuse import ReuseSettings, StoreKeeper, chamber_key, gather_step
from scenes import box, rad_polygon, write_scene

ROOM = ("void plastic grey\n0\n0\n5 0.5 0.5 0.5 0 0\n\n"
        "void metal mirror\n0\n0\n5 0.8 0.8 0.8 1 0\n\n"
        "void trans diffuser\n0\n0\n7 0.1 0.1 0.1 0 0 0.7 0\n\n"
        "void light lamp\n0\n0\n3 10 10 10\n\n"
        + box("grey", (0, 0, 0), (1000, 1000, 1100))
        + rad_polygon("mirror", "glass", [(999, 100, 50), (999, 100, 900), (999, 900, 900), (999, 900, 50)])
        + rad_polygon("diffuser", "sheet", [(200, 200, 950), (800, 200, 950), (800, 800, 950), (200, 800, 950)])
        + "lamp cylinder tube\n0\n0\n7 300 500 1020 700 500 1020 5\n\n")
THIN, GREEN = {"reflectance": 0.4, "transmittance": 0.5}, {"reflectance": 0.3, "transmittance": 0.3}
SMALL = ReuseSettings(store_photons=200_000, batches=16, samples=32, image_draws=80, paths=20)


def _plant(lift=0.0):
    leaf = trimesh.Trimesh([[-100, -100, 260], [100, -100, 260], [100, 100, 260], [-100, 100, 260]],
                           [[0, 1, 2], [0, 2, 3]])
    organs = {1: (trimesh.creation.icosphere(subdivisions=1, radius=4.0).apply_translation((0, 0, 250)), GREEN, "Bud"),
              2: (leaf, THIN, "Leaf")}
    for i in range(24):
        bud = trimesh.creation.icosphere(subdivisions=1, radius=6.0)
        organs[10 + i] = (bud.apply_translation((-150 + 40 * (i // 5), 150 + 30 * (i % 5), 100)), GREEN, "Bud")
    for mesh, _, _ in organs.values():
        mesh.apply_translation((0, 0, lift))
    return organs


@pytest.fixture(scope="module")
def room(tmp_path_factory):
    return write_scene(tmp_path_factory.mktemp("reuse"), ROOM)


def _model(scene, estimator, photons=400_000, seed=1, reuse=SMALL):
    return LightModel(scene, organs={"Bud": GREEN, "Leaf": THIN}, lamp_flux=100.0, plant_unit="mm",
                      position=(500, 500, 0), photons=photons, estimator=estimator, seed=seed, threads=2,
                      reuse=reuse if estimator == "reuse" else None)


def _light(model, organs):
    """Each organ's ppfd in the first band and its σ, (n,) each, in the organs' order."""
    lights = model.intercept(organs)
    keys = sorted(lights)
    return np.array([lights[k].ppfd[0] for k in keys]), np.array([lights[k].ppfd_std[0] for k in keys])


def test_reuse_agrees_with_the_full_kernel_organ_by_organ(room):
    """The same plant lit by the full kernel (1.6e6 photons) and from a store built with it in place: every
    organ's light agrees (|z| < 4.5), the whole plant's too (|z| < 4), and the z-scores spread as σ says (their
    standard deviation 0.6-1.5: the reuse's σ, its store's error included, is honest).  Without the paths traced
    on from the organs (the light between organs) the pocket bud loses most of its light (tried: z = -25)."""
    organs = _plant()
    full, full_std = _light(_model(room, "nee", 1_600_000, seed=3), organs)
    model = _model(room, "reuse", seed=5)
    reuse, reuse_std = _light(model, organs)
    assert model.keeper.built == 1
    z = (reuse - full) / np.hypot(reuse_std, full_std)
    assert np.all(np.abs(z) < 4.5), z
    assert 0.6 < np.std(z) < 1.5, np.std(z)
    plant_z = (reuse.sum() - full.sum()) / math.hypot(np.sqrt(np.sum(reuse_std ** 2)), np.sqrt(np.sum(full_std ** 2)))
    assert abs(plant_z) < 4, plant_z


def test_a_store_is_never_used_stale(room, tmp_path):
    """A new store when a lamp's output, a material, the chamber file or the plant's position changes, and after
    ``renew`` steps; the same one otherwise.  Each change is made as a user would make it (a new flux, an edited
    material table, an edited .rad file, the plant moved), and ``StepResult.extra['store']`` names the store."""
    settings = ReuseSettings(store_photons=20_000, batches=8, samples=2, image_draws=2, paths=1, renew=3)
    organs = _plant()

    def steps(model, n, plant=organs):
        out = []
        for _ in range(n):
            out.append(model.run(model.organs_from_meshes(plant)).extra["store"])
        return out

    model = _model(room, "reuse", reuse=settings)
    first = steps(model, 2)
    assert first[0]["store"] == first[1]["store"] and model.keeper.built == 1, first
    assert first[0]["why"] == "first step"
    model.flux = model.flux * 2.0                                 # a lamp's output
    moved = steps(model, 1)[0]
    assert moved["store"] != first[0]["store"] and "lamps" in moved["why"], moved
    grey = next(m for m in model.kscene.materials if m.name == "grey")
    grey.events[0] *= 0.9                                         # a material's optical properties:
    grey.events[4] = 1.0 - grey.events[:4].sum(axis=0)            # less diffuse reflection, more absorption
    changed = steps(model, 1)[0]
    assert changed["store"] != moved["store"] and model.keeper.built == 3, changed
    after = steps(model, 3)
    assert [s["store"] for s in after[:2]] == [changed["store"]] * 2 and after[2]["store"] != changed["store"]
    assert after[2]["why"].startswith("renewed after 3 steps"), after
    far = steps(model, 1, _plant(lift=400.0))[0]                  # the plant moved out of the store's region
    assert far["why"] == "the plant left the store's region", far
    edited = write_scene(tmp_path, ROOM.replace("5 0.5 0.5 0.5 0 0", "5 0.45 0.45 0.45 0 0"))   # the chamber file
    other = _model(edited, "reuse", reuse=settings)
    assert chamber_key(other.kscene, model.keeper.store.box, 20_000, 8, 1) != \
        chamber_key(_model(room, "reuse", reuse=settings).kscene, model.keeper.store.box, 20_000, 8, 1)


def test_a_reuse_step_is_the_same_on_any_number_of_threads(room):
    """Store and gather per batch, each batch's draws from its own random streams, summed in batch order: the
    same numbers bit for bit on 1 and 3 threads."""
    settings = ReuseSettings(store_photons=40_000, batches=8, samples=4, image_draws=4, paths=2)
    out = []
    for threads in (1, 3):
        model = _model(room, "reuse", reuse=settings)
        model.threads = threads
        out.append(_light(model, _plant()))
    assert np.array_equal(out[0][0], out[1][0]) and np.array_equal(out[0][1], out[1][1])


def test_reuse_settings_and_the_run_command_refuse_what_they_cannot_do(room, tmp_path):
    with pytest.raises(InputError, match="batches"):
        ReuseSettings(batches=2)
    with pytest.raises(InputError, match="unknown reuse setting"):
        _model(room, "reuse", reuse={"photons": 10})
    from lpy_light.cli import main
    assert main(["run", str(room), "--estimator", "reuse", "--out", str(tmp_path / "r")]) == 2


def test_a_store_too_small_to_light_every_cell_gives_a_step_not_an_error(room):
    """A store of a few photons leaves most clusters without light in most batches: their draws are empty, the
    step has numbers (zeros where nothing was drawn), no division by zero."""
    model = _model(room, "reuse", reuse=ReuseSettings(store_photons=16, batches=8, samples=2, image_draws=1, paths=1))
    light, sigma = _light(model, _plant())
    assert np.all(np.isfinite(light)) and np.all(light >= 0)


def test_a_sweep_of_growth_runs_passes_the_estimator_to_each():
    """``lpy-light sweep MODEL.lpy --set SEED=1..2 --estimator reuse``: every run is ``grow ... --estimator
    reuse``, which ``grow`` accepts (and ``run`` refuses, test above)."""
    from pathlib import Path

    from lpy_light.run import sweep
    from lpy_light.cli import _parser
    rose = Path(__file__).resolve().parent.parent / "lsystems" / "rose.lpy"
    tasks = sweep.tasks_for([str(rose)], ["SEED=1..2"], ["--estimator", "reuse"])
    assert len(tasks) == 2 and all(t.argv[t.argv.index("--estimator") + 1] == "reuse" for t in tasks)
    assert _parser().parse_args(tasks[0].argv + ["--out", "x"]).estimator == "reuse"
