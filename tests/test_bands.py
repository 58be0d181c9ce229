"""All bands in one pass: unbiased for each band against separate analog runs."""
import numpy as np
import pytest

from lpy_light.run import simulate
from lpy_light.chamber.scene import load_scene
from scenes import box, lamp_rectangle, write_scene

RAD = ("void plastic wall\n0\n0\n5 0.5 0.5 0.5 0 0\n\nvoid light lamp\n0\n0\n3 10 10 10\n\n"
       + box("wall", (0, 0, 0), (1000, 1000, 1100)) + lamp_rectangle("lamp", (500, 500), 100, 1000))
SENSORS = [(300, 300, 400, 60, 0, 0, 1), (700, 650, 200, 60, 0, 0, -1), (500, 500, 900, 60, 1, 0, 0)]
BANDS = [[400, 500], [500, 600], [600, 700]]
REFLECTANCE = {450: 0.2, 550: 0.8, 650: 0.5}


def _optical(folder):
    d = folder / "optical" / "Env" / "ReflectancesMean"
    d.mkdir(parents=True)
    rows = "".join("%d;%s\n" % (nm, str(REFLECTANCE[100 * (nm // 100) + 50]).replace(".", ","))
                   for nm in range(400, 700))
    (d / "wall.csv").write_text('"lambda";"moy"\n' + rows)


def _scene(folder, bands):
    _optical(folder)
    extra = 'optical = "optical"\nbands = %s\n' % bands
    return load_scene(write_scene(folder, RAD, SENSORS, extra))


@pytest.fixture(scope="module")
def runs(tmp_path_factory):
    n = 150_000
    one_pass = simulate.run(simulate.KernelScene(_scene(tmp_path_factory.mktemp("all"), BANDS), "weighted"), n, seed=1)
    separate = [simulate.run(simulate.KernelScene(_scene(tmp_path_factory.mktemp("b%d" % i), [b]), estimator="analog"),
                             n, seed=100 + i)
                for i, b in enumerate(BANDS)]
    return one_pass, separate


def test_one_pass_matches_separate_analog_runs(runs):
    one_pass, separate = runs
    p, s = one_pass.sensors()
    for b, run in enumerate(separate):
        q, t = run.sensors()
        z = (p[:, b] - q[:, 0]) / np.hypot(s[:, b], t[:, 0])
        assert np.all(np.abs(z) < 4), (b, z)


def test_bands_differ_where_the_walls_do(runs):
    """The weights carry the band physics: R = 0.2 and 0.8 walls give very different indirect light."""
    p, s = runs[0].sensors()
    down = 1   # the downward-facing sensor sees only reflected light
    assert (p[down, 1] - p[down, 0]) / np.hypot(s[down, 0], s[down, 1]) > 10


def test_one_pass_is_as_precise_as_separate_runs(runs):
    """No band's weight grows, so the brightest band keeps its analog precision (within 20%)."""
    one_pass, separate = runs
    p, s = one_pass.sensors()
    for b, run in enumerate(separate):
        q, t = run.sensors()
        assert np.all(s[:, b] < 1.2 * t[:, 0] + 1e-9), (b, s[:, b], t[:, 0])


def test_energy_closure_holds_per_band(runs):
    one_pass, separate = runs
    n = one_pass.photons
    closure, sigma = one_pass.closure
    assert np.all(sigma > 0)
    assert np.all(np.abs(closure - n) < 4 * sigma)
    np.testing.assert_allclose(one_pass.fate.sum(axis=0), closure, rtol=1e-9)
    for run in separate:   # analog, one band: every photon deposits exactly 1
        assert run.closure[1][0] < 1e-6 * n
        assert run.fate.sum() == pytest.approx(n, rel=1e-9)


def test_analog_traces_each_band_on_its_own_path(runs, tmp_path):
    """``analog`` with several bands is SEC2's counting band by band: every photon is traced once per band,
    each path with that band's own event probabilities, so each band's tally is a raw count (a whole number),
    each path deposits exactly 1 in its band (closure without spread), and the bands agree with separate
    one-band analog runs at their σ.  A shared event probability (the bands' mean, as before) gives weights
    P_e,b / q_e ≠ 1: no whole numbers, no exact closure, and a σ that misses the weights' growth."""
    _, separate = runs
    n = 150_000
    together = simulate.run(simulate.KernelScene(_scene(tmp_path, BANDS), estimator="analog"), n, seed=7)
    p, s = together.sensors()
    assert np.all(p > 0)
    np.testing.assert_array_equal(p, np.round(p))
    assert together.fate.sum(axis=0) == pytest.approx(np.full(3, n), rel=1e-9)
    assert np.all(together.closure[1] < 1e-6 * n)
    for b, run in enumerate(separate):
        q, t = run.sensors()
        z = (p[:, b] - q[:, 0]) / np.hypot(s[:, b], t[:, 0])
        assert np.all(np.abs(z) < 4), (b, z)
        assert np.all(np.abs(s[:, b] / t[:, 0] - 1) < 0.2), (b, s[:, b], t[:, 0])   # the same precision


# a dichroic film across the room: R = 0.95 in blue, T = 0.95 in red (and white walls R = 0.95): the
# bands' largest event probabilities sum to 1.9 on the film, so no single q serves both bands
DICHROIC_RAD = ("void plastic wall 0 0 5 0.5 0.5 0.5 0 0\nvoid trans film 0 0 7 0.5 0.5 0.5 0 0 0.5 0\n"
                "void light lamp 0 0 3 10 10 10\n"
                + box("wall", (0, 0, 0), (1000, 1000, 1100)) + lamp_rectangle("lamp", (500, 500), 100, 1000)
                + "film polygon f1 0 0 12 0 0 600 1000 0 600 1000 1000 600 0 1000 600\n"
                + "film polygon f2 0 0 12 0 0 600 0 1000 600 1000 1000 600 1000 0 600\n")
DICHROIC_BANDS = [[400, 500], [500, 600], [600, 700]]


def _dichroic(folder):
    tables = {("ReflectancesMean", "wall"): (0.95, 0.95, 0.95), ("ReflectancesMean", "film"): (0.95, 0.04, 0.0),
              ("TransmittancesMean", "film"): (0.0, 0.05, 0.95)}
    for (kind, name), values in tables.items():
        d = folder / "optical" / "Env" / kind
        d.mkdir(parents=True, exist_ok=True)
        rows = "".join("%d;%s\n" % (nm, str(values[(nm - 400) // 100]).replace(".", ",")) for nm in range(400, 700))
        (d / ("%s.csv" % name)).write_text('"lambda";"moy"\n' + rows)
    extra = 'optical = "optical"\nbands = %s\n' % DICHROIC_BANDS
    return load_scene(write_scene(folder, DICHROIC_RAD, SENSORS, extra))


def test_bands_that_cannot_share_a_path_travel_on_their_own(tmp_path):
    """Where the bands' largest event probabilities sum above 1 on a material (a dichroic film), no shared
    q keeps every weight factor P_e,b / q_e <= 1 (scaling q down made the blue band's weight grow ×1.9 at
    each reflection on the film: a σ that cannot be trusted).  Those bands go on paths of their own (the
    green band, which fits with either, shares the first): every weight factor stays <= 1, and the bands
    agree with analog counting."""
    from lpy_light.chamber.materials import band_passes, sampling_tables
    chamber = _dichroic(tmp_path / "d")
    ks = simulate.KernelScene(chamber, "weighted")
    np.testing.assert_array_equal(ks.band_pass, [0, 0, 1])
    prob, cum, passes, _ = sampling_tables(ks.materials)
    q = np.diff(np.concatenate([np.zeros((len(prob), 1, cum.shape[2])), cum], axis=1), axis=1)[:, :4]
    for b in range(prob.shape[2]):
        factor = prob[:, :4, b] / np.where(q[:, :, passes[b]] > 0, q[:, :, passes[b]], np.inf)
        assert factor.max() <= 1 + 1e-12, (b, factor.max())
    np.testing.assert_array_equal(band_passes(np.stack([m.events for m in load_scene(
        write_scene(tmp_path / "w", RAD, SENSORS)).materials])), [0])       # white walls: one path
    n = 100_000
    weighted = simulate.run(ks, n, seed=3)
    analog = simulate.run(simulate.KernelScene(chamber, estimator="analog"), n, seed=4)
    p, s = weighted.sensors()
    q_, t = analog.sensors()
    dark = (t == 0) & (s == 0)                      # blue under the film: none, in both
    np.testing.assert_array_equal(p[dark], 0)
    np.testing.assert_array_equal(q_[dark], 0)
    z = (p - q_)[~dark] / np.hypot(s, t)[~dark]
    assert np.all(np.abs(z) < 4), z
    assert np.all(s <= 1.2 * t + 1e-9), (s, t)      # no weight grows: at least analog's precision
    closure, sigma = weighted.closure
    assert np.all(np.abs(closure - n) < 4 * sigma + 1e-6 * n)
