"""Next-event tallies (estimator "nee"): unbiased against quadrature and against analog counting."""
import numpy as np
import pytest

from lpy_light import simulate
from lpy_light.scene import load_scene
from scenes import box, lamp_rectangle, rad_polygon, rectangle_to_disc_fraction, write_scene

BLACK = "void plastic black\n0\n0\n5 0 0 0 0 0\n\nvoid light lamp\n0\n0\n3 10 10 10\n\n"
DISCS = [((500, 500, 500), (0, 0, 1), 40.0), ((800, 600, 400), (0, 0, 1), 40.0),
         ((700, 500, 600), (-1, 0, 0), 40.0), ((500, 300, 700), (0, 1, 1), 40.0)]


def _rows(discs):
    return [c + (r,) + n for c, n, r in discs]


def _run(chamber, estimator, photons, seed, picks=0):
    ks = simulate.KernelScene(chamber, estimator)
    ks.nee_picks = picks
    return simulate.run(ks, photons, seed=seed, threads=2)


def test_direct_light_matches_quadrature_with_far_fewer_photons(tmp_path):
    rad = BLACK + box("black", (0, 0, 0), (1000, 1000, 1100)) + lamp_rectangle("lamp", (500, 500), 100, 1000)
    chamber = load_scene(write_scene(tmp_path, rad, _rows(DISCS)))
    n = 20_000
    nee = _run(chamber, "nee", n, seed=4)
    counted = _run(chamber, "weighted", n, seed=4)
    p, s = nee.sensors()
    _, s_counted = counted.sensors()
    for i, (c, nrm, r) in enumerate(DISCS):
        expected = n * rectangle_to_disc_fraction((500, 500), 100, 1000, (0, 0, -1), c, nrm, r)
        assert abs(p[i, 0] - expected) < 4 * s[i, 0], (i, p[i, 0], expected, s[i, 0])
        assert s[i, 0] < 0.01 * expected                 # power: σ well below 1%
        assert s[i, 0] < s_counted[i, 0] / 10            # and ≥ 10x below counting at equal photons


# A room that exercises every path type: grey walls with a specular part, a mirror, a diffusing
# sheet (diffuse + straight transmission) under a line lamp, sensors near walls (no next events there)
ROOM = ("void plastic grey\n0\n0\n5 0.5 0.5 0.5 0.3 0\n\n"
        "void mirror silver\n0\n0\n3 0.9 0.9 0.9\n\n"
        "void trans diffuser\n0\n0\n7 0.1 0.1 0.1 0 0 0.7 0.4\n\n"
        "void light lamp\n0\n0\n3 10 10 10\n\n"
        + box("grey", (0, 0, 0), (1000, 1000, 1100))
        + rad_polygon("silver", "mirror", [(990, 100, 100), (990, 100, 900), (990, 900, 900), (990, 900, 100)])
        + rad_polygon("diffuser", "sheet", [(200, 200, 950), (800, 200, 950), (800, 800, 950), (200, 800, 950)])
        + "lamp cylinder tube\n0\n0\n7 300 500 1020 700 500 1020 5\n\n")
ROOM_SENSORS = [(500, 500, 500, 40, 0, 0, 1), (200, 800, 300, 40, 0, 0, 1), (50, 500, 600, 40, 1, 0, 0),
                (500, 500, 900, 40, 0, 0, 1), (500, 500, 200, 40, 0, 0, -1), (900, 500, 500, 40, 1, 0, 0)]


@pytest.fixture(scope="module")
def room(tmp_path_factory):
    chamber = load_scene(write_scene(tmp_path_factory.mktemp("room"), ROOM, ROOM_SENSORS))
    return chamber, _run(chamber, "analog", 600_000, seed=21)


@pytest.mark.parametrize("picks, photons", [(0, 40_000), (1, 300_000)])
def test_room_matches_analog_counting(room, picks, photons):
    chamber, analog = room
    nee = _run(chamber, "nee", photons, seed=22, picks=picks)
    a, sa = analog.sensors()
    b, sb = nee.sensors()
    scale = analog.photons / nee.photons
    z = (a[:, 0] - scale * b[:, 0]) / np.hypot(sa[:, 0], scale * sb[:, 0])
    assert np.all(np.abs(z) < 4), z
    closure, closure_std = nee.closure
    assert abs(closure[0] - nee.photons) < 4 * closure_std[0]


def test_a_biased_next_event_would_fail(room):
    """Dropping the straight transmission through the sheet from the counted segments (a classic
    next-event bug) moves the sensor under the sheet by far more than 4σ."""
    chamber, analog = room
    a, sa = analog.sensors()
    nee = _run(chamber, "nee", 40_000, seed=23)
    b, sb = nee.sensors()
    scale = analog.photons / nee.photons
    # the light reaching sensor 0 after a straight pass through the sheet is ~ T·tspec of the direct light
    straight = 0.7 * 0.4
    wrong = scale * b[0, 0] * (1 - straight)
    assert abs(a[0, 0] - wrong) > 4 * np.hypot(sa[0, 0], scale * sb[0, 0])


def test_pruning_blind_sources_changes_nothing(room):
    chamber, _ = room
    ks = simulate.KernelScene(chamber, "nee")
    ks.nee_picks = 0
    full = simulate.run(ks, 30_000, seed=31, threads=2)
    report = ks.prune_next_events(photons=4096, max_share=0.05)
    pruned = simulate.run(ks, 30_000, seed=32, threads=2)
    a, sa = full.sensors()
    b, sb = pruned.sensors()
    assert report["off"]                                  # something was switched off
    assert np.all(np.abs(a - b) < 4 * np.hypot(sa, sb))
