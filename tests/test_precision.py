"""Precision on what the rules read (issue 45): ``precision={"par": 0.03, "rfr": 0.02}`` and
``--precision par=0.03,rfr=0.02``, parsed and checked, and a step that runs until the targets' asked
quantities reach it."""
import subprocess
import sys
from pathlib import Path

import numpy as np
import pytest
import trimesh

from lpy_light.plant import precision
from lpy_light.errors import InputError
from lpy_light.plant.light import LightModel
from lpy_light.run.simulate import CHUNK
from scenes import write_scene
from test_ratios import GREY_ROOM, LEAF, OPTICAL

BANDS = [(400.0, 655.0), (655.0, 665.0), (665.0, 700.0), (725.0, 735.0)]     # PAR tiled, red, far red
LABELS = ["400-655", "655-665", "665-700", "725-735"]
ROSE = Path(__file__).resolve().parents[1] / "lsystems" / "rose.lpy"


def test_a_number_asks_par_and_rfr_relative():
    goal = precision.parse_goal(0.04, BANDS, LABELS)
    assert dict(goal) == {"par": (0.04, True), "rfr": (0.04, True)} and goal.given == 0.04
    assert precision.parse_goal("0.04").given == 0.04 and precision.parse_goal(None) is None


@pytest.mark.parametrize("given", [{"par": 0.03, "rfr": 0.02}, "par=0.03,rfr=0.02", " PAR = 0.03 , rfr=0.02 ",
                                   {"par": "0.03", "rfr": 0.02}])
def test_a_mapping_asks_par_relative_and_rfr_absolute(given):
    goal = precision.parse_goal(given, BANDS, LABELS)
    assert dict(goal) == {"par": (0.03, True), "rfr": (0.02, False)}
    assert goal.given == {"par": 0.03, "rfr": 0.02}
    assert precision.parse_goal(goal, BANDS, LABELS) == goal          # parsed twice: the same


def test_a_band_of_the_scene_and_an_absolute_rfr_above_one():
    goal = precision.parse_goal({"725-735": 0.05, "rfr": 1.5}, BANDS, LABELS)
    assert dict(goal) == {"725-735": (0.05, True), "rfr": (1.5, False)}
    assert dict(precision.parse_goal("725-735=0.05")) == {"725-735": (0.05, True)}   # checked later, with the scene


@pytest.mark.parametrize("given, named", [
    ({"pars": 0.03}, "'pars'"), ("par=0.03,fr=0.1", "'fr'"), ({"700-800": 0.05}, "'700-800'"),
    ({"par": 0}, "par"), ({"par": 1.0}, "par"), ({"rfr": -0.1}, "rfr"), ({"rfr": "x"}, "rfr"),
    ({"par": float("nan")}, "par"), ({"rfr": True}, "rfr"), ("par=0.03,rfr", "rfr"), ("=0.1", "=0.1"),
    ({}, "empty"), (1.5, "1.5"), (0, "0"), ("abc", "abc"), (True, "True")])
def test_bad_keys_and_values_are_refused_by_name(given, named):
    with pytest.raises(InputError, match="precision") as info:
        precision.parse_goal(given, BANDS, LABELS)
    assert named in str(info.value)


def test_par_or_rfr_asked_of_bands_that_have_none_are_refused():
    with pytest.raises(InputError, match="no PAR"):
        precision.parse_goal({"par": 0.03}, [(655.0, 665.0), (725.0, 735.0)], ["655-665", "725-735"])
    with pytest.raises(InputError, match="no R:FR"):
        precision.parse_goal({"rfr": 0.02}, [(400.0, 700.0)], ["400-700"])


def test_sigma_over_goal_reads_each_quantity_and_waits_for_a_missing_rfr():
    """σ / goal per organ: PAR relative, R:FR absolute; an organ whose far red is too uncertain for an R:FR
    (CV 1.5 > 1) counts as 1.5 / 1, not as reached; organs without light are not waited for."""
    x = np.array([[100.0, 10.0, 20.0, 10.0], [100.0, 10.0, 20.0, 10.0], [0.0, 0.0, 0.0, 0.0]])
    cov = np.zeros((3, 4, 4))
    cov[0] = np.diag([4.0, 0.25, 1.0, 0.25])              # PAR σ 2.1 %; R:FR 1 ± 0.0707
    cov[1] = np.diag([1.0, 0.01, 0.01, 15.0 ** 2])         # far red's CV 1.5: no R:FR
    flux = np.ones(4)
    par_only = precision.parse_goal({"par": 0.03}, BANDS, LABELS)
    assert precision.sigma_over_goal(par_only, x[:1], cov[:1], flux, BANDS, LABELS) == pytest.approx(
        np.sqrt(4 + 0.25 + 1) / 130 / 0.03)
    rfr_only = precision.parse_goal({"rfr": 0.1}, BANDS, LABELS)
    assert precision.sigma_over_goal(rfr_only, x[:1], cov[:1], flux, BANDS, LABELS) == pytest.approx(
        np.sqrt(0.25 / 100 + 0.25 / 100) * (1 - 0.0025) / 0.1)
    assert precision.sigma_over_goal(rfr_only, x, cov, flux, BANDS, LABELS) == pytest.approx(1.5 / 1.0)
    assert precision.sigma_over_goal(rfr_only, x[2:], cov[2:], flux, BANDS, LABELS) == np.inf


def _bud_and_leaf(folder, **kw):
    """The bud behind a leaf of tests/test_ratios.py, with bands that tile PAR (PAR and R:FR both defined)."""
    bands = "bands = [%s]\n" % ", ".join("[%g, %g]" % b for b in BANDS)
    scene = write_scene(folder, GREY_ROOM, toml_extra=bands + 'optical = "%s"\n' % OPTICAL.as_posix())
    a = np.linspace(0, 2 * np.pi, 24, endpoint=False)
    v = np.vstack([[0, 0, 500], np.c_[60 * np.cos(a), 60 * np.sin(a), np.full(24, 500.0)]])
    leaf = trimesh.Trimesh(v, [[0, 1 + i, 1 + (i + 1) % 24] for i in range(24)], process=False)
    bud = trimesh.creation.icosphere(subdivisions=1, radius=1.0)
    bud.apply_translation((0, 0, 400))
    model = LightModel(scene, organs={"Leaf": LEAF, "Bud": LEAF[0]}, lamp_flux=[245.0, 10.0, 35.0, 10.0],
                       plant_unit="mm", position=(500, 500, 0), threads=1, targets=["Bud", "Leaf"], **kw)
    return model, model.organs_from_meshes({0: (leaf, LEAF, "Leaf"), 1: (bud, LEAF[0], "Bud")})


def test_a_bad_precision_is_refused_where_the_model_is_made(tmp_path):
    with pytest.raises(InputError, match="'fr'"):
        _bud_and_leaf(tmp_path, precision={"par": 0.03, "fr": 0.02})
    model, _ = _bud_and_leaf(tmp_path / "b", precision=0.04)
    with pytest.raises(InputError, match="'655-666'"):
        model.precision = "655-666=0.1"              # as ``lpy-light grow --precision`` sets it
    assert model.precision == 0.04


def test_grow_refuses_a_bad_precision_before_it_needs_lpy(tmp_path):
    p = subprocess.run([sys.executable, "-m", "lpy_light", "grow", str(ROSE), "--out", str(tmp_path / "out"),
                        "--precision", "par=0.03,rfr=x"], capture_output=True, text=True)
    assert p.returncode == 2 and "--precision rfr" in p.stderr and "'x'" in p.stderr, p.stderr


def _sigmas(step):
    bud, leaf = step.organs[1], step.organs[0]
    return (max(bud.par_std / bud.par, leaf.par_std / leaf.par), max(bud.rfr_std, leaf.rfr_std),
            max(bud.rfr_std / bud.rfr, leaf.rfr_std / leaf.rfr))


def test_a_step_runs_until_the_asked_quantities_reach_the_goal(tmp_path):
    """{"par": 0.0015, "rfr": 0.004}: the step stops at the first chunk where every target's PAR is within
    0.15 % and its R:FR within ±0.004 (absolute); the same seed one chunk shorter is not there yet.  Asking
    R:FR alone stops earlier (PAR is what holds it here), the number 0.004 (relative on both: ±0.0026 on the
    bud's R:FR ≈ 0.65) later."""
    goal = {"par": 0.0015, "rfr": 0.004}
    model, organs = _bud_and_leaf(tmp_path, photons=4_000_000, precision=goal)
    step = model.run(organs)
    par_rel, rfr_abs, _ = _sigmas(step)
    assert step.extra["precision_reached"] and step.extra["precision"] == goal
    assert step.photons < 4_000_000 and step.photons % CHUNK == 0
    assert par_rel <= 0.0015 and rfr_abs <= 0.004
    model.step, model.precision = 0, None           # the same seed, one chunk fewer, no goal
    shorter = _sigmas(model.run(organs, photons=step.photons - CHUNK))
    assert shorter[0] > 0.0015 or shorter[1] > 0.004, shorter
    model.step, model.precision = 0, {"rfr": 0.004}
    rfr_only = model.run(organs)
    assert rfr_only.extra["precision_reached"] and _sigmas(rfr_only)[1] <= 0.004
    model.step, model.precision = 0, 0.004
    number = model.run(organs)
    assert number.extra["precision_reached"] and max(_sigmas(number)[::2]) <= 0.004
    assert rfr_only.photons < step.photons < number.photons, (rfr_only.photons, step.photons, number.photons)


def test_a_step_short_of_its_precision_at_the_cap_says_so_once(tmp_path, caplog):
    """A cap that stops a step before the precision asked: a warning naming the cap, the goal, how many target
    organs are short of it and by how much (a rule comparing their numbers with a threshold reads noise), once per
    run however many steps; none where the goal is reached.  Per organ σ / goal as the stop reads it."""
    model, organs = _bud_and_leaf(tmp_path, photons=CHUNK, precision={"par": 0.0002, "rfr": 0.0005})
    with caplog.at_level("WARNING", logger="lpy_light"):
        for _ in range(3):
            step = model.run(organs)
    short = [r.getMessage() for r in caplog.records if "before the precision asked" in r.getMessage()]
    assert not step.extra["precision_reached"] and len(short) == 1, short
    assert "cap of %d photons" % CHUNK in short[0] and "par 0.0002, rfr 0.0005" in short[0]
    assert "2 of 2 target organs" in short[0] and "(Bud, Leaf)" in short[0]
    caplog.clear()
    model.photons, model.precision = 4_000_000, {"par": 0.03}
    with caplog.at_level("WARNING", logger="lpy_light"):
        assert model.run(organs).extra["precision_reached"]
    assert not [r for r in caplog.records if "before the precision asked" in r.getMessage()]
    x = np.array([[100.0, 10.0, 20.0, 10.0], [0.0, 0.0, 0.0, 0.0]])
    cov = np.array([np.diag([4.0, 0.25, 1.0, 0.25]), np.zeros((4, 4))])
    per_organ = precision.organs_sigma_over_goal(precision.parse_goal({"par": 0.03}, BANDS, LABELS), x, cov,
                                                 np.ones(4), BANDS, LABELS)
    assert per_organ[0] == pytest.approx(np.sqrt(4 + 0.25 + 1) / 130 / 0.03) and np.isnan(per_organ[1])
