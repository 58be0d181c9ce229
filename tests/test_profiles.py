"""Row profiles against a reference (reference.row_profiles, reference.average): the ratio per row of each
sensor plane, mean 1, with its σ and its change across the rows -- the structure a per-sensor test misses."""
import numpy as np
import pytest

from lpy_light.report import reference
from lpy_light.errors import InputError

# two horizontal planes (z = 1000, 1400) of 4 columns (x) x 3 rows (y), facing up, and one sideways sensor
GRID = [(x, y, z) for z in (1000.0, 1400.0) for y in (100.0, 200.0, 300.0) for x in (0.0, 10.0, 20.0, 30.0)]
CENTERS = np.array(GRID + [(0.0, 0.0, 500.0)])
NORMALS = np.array([(0, 0, 1.0)] * len(GRID) + [(1.0, 0, 0)])


def _ref(counts, std=None, n=1e9):
    counts = np.asarray(counts, float)
    return reference.Reference(counts, np.sqrt(counts) if std is None else np.asarray(std, float), n, "ref")


def test_rows_by_hand():
    """ours = reference x (1 + 0.01 (y - 200)/200) x (any level): each row's ratio is its factor over the mean
    factor, the change across the rows is 1 %, the sideways sensor is a plane of its own."""
    ref = _ref(np.linspace(1e4, 3e4, len(CENTERS)))
    factor = np.where(NORMALS[:, 2] > 0, 1 + 0.01 * (CENTERS[:, 1] - 200) / 200, 1.0)
    ours = 0.37 * ref.photons * factor
    profiles = reference.row_profiles(ours, 1e-9 * ours, ref, CENTERS, NORMALS, unit="mm")
    assert [p.plane for p in profiles] == ["z1000", "z1400", "x0"]
    z1000 = profiles[0]
    mean = factor.mean()
    assert z1000.axis == "y" and list(z1000.position) == [100, 200, 300] and list(z1000.count) == [4, 4, 4]
    np.testing.assert_allclose(z1000.ratio, np.array([0.995, 1.0, 1.005]) / mean, rtol=1e-12)
    assert z1000.slope == pytest.approx(0.01 / mean, rel=1e-9)
    # columns: no change along x
    cols = reference.row_profiles(ours, 1e-9 * ours, ref, CENTERS, NORMALS, across=0)
    assert cols[0].axis == "x" and len(cols[0].position) == 4 and abs(cols[0].slope) < 1e-12
    assert profiles[2].slope == 0.0 and len(profiles[2].position) == 1
    assert "change across the rows +1.00%" in z1000.lines()[0] and len(z1000.lines()) == 4


def test_row_sigma_combines_both_and_averages_the_row():
    """σ of a row = √(Σ σ_s²) / n with σ_s² = r²((σ_ours/ours)² + (σ_ref/ref)²)."""
    ref = _ref(np.full(len(CENTERS), 1e4), std=np.full(len(CENTERS), 100.0))      # 1 % per sensor
    ours = np.full(len(CENTERS), 5.0)
    profiles = reference.row_profiles(ours, 0.02 * ours, ref, CENTERS, NORMALS)          # 2 % per sensor
    np.testing.assert_allclose(profiles[0].ratio_std, np.hypot(0.01, 0.02) / np.sqrt(4), rtol=1e-12)
    # the slope's σ: weighted least squares over the rows (three rows at t = -1/2, 0, 1/2)
    assert profiles[0].slope_std == pytest.approx(np.hypot(0.01, 0.02) / 2 / np.sqrt(0.5), rel=1e-9)


def test_a_tilt_hidden_in_the_per_sensor_noise_shows_in_the_rows():
    """A 1.5 % tilt along y under a reference with 0.8 % Poisson noise per sensor: every sensor is within 4σ
    (the per-sensor comparison passes), the rows resolve the tilt (what breaks: averaging rows would not)."""
    rng = np.random.default_rng(3)
    y = np.tile(np.repeat(np.linspace(930, 1830, 10), 12), 2)
    centers = np.c_[np.tile(np.linspace(110, 1210, 12), 20), y, np.repeat([1000.0, 1400.0], 120)]
    normals = np.tile([0, 0, 1.0], (240, 1))
    truth = np.full(240, 15000.0)
    ref = _ref(rng.poisson(truth).astype(float))
    ours = truth * (1 + 0.015 * (y - 1380) / 900) / 10          # a run of 1e8 photons, noise 0.1 %
    ours_std = 0.001 * ours
    ours = ours + rng.normal(0, 1, 240) * ours_std
    c = reference.compare(ours, ours_std, 1e8, ref)
    assert c.within_4sigma == 1.0
    for p in reference.row_profiles(ours, ours_std, ref, centers, normals):
        assert abs(p.slope - 0.015) < 4 * p.slope_std and p.slope_std < 0.003, (p.slope, p.slope_std)


def test_average_of_two_references_per_emitted_photon():
    a = _ref([100.0, 300.0], n=1e6)
    b = _ref([400.0, 1000.0], n=2e6)           # 200, 500 per 1e6 photons
    avg = reference.average([a, b])
    assert avg.n_photons == 1e6 and avg.source == "ref + ref"
    np.testing.assert_allclose(avg.photons, [150.0, 400.0])
    np.testing.assert_allclose(avg.photons_std, np.sqrt([100 + 400 / 4, 300 + 1000 / 4]) / 2)
    assert reference.average([a]) is a
    with pytest.raises(InputError, match="2 and 3 sensors"):
        reference.average([a, _ref([1.0, 2.0, 3.0])])


def test_the_two_angers_references_agree_row_by_row(angers_dir):
    """The two Angers references (SEC2, photon mapping) have no tilt along y against each other: the premise of
    testing our rows against their average (docs/validation.md, section 8)."""
    from lpy_light.report import validation
    sec2 = reference.read_sec2(angers_dir / "reference-sec2" / "mesures.txt")
    pm = reference.read_photon_mapping(validation.PHOTON_MAPPING)
    chamber = validation.load("angers")
    for p in reference.row_profiles(pm.photons, pm.photons_std, sec2, chamber.sensors.center, chamber.sensors.normal):
        assert abs(p.slope) < 4 * p.slope_std + 0.005, (p.plane, p.slope, p.slope_std)
        assert np.all(np.abs(p.ratio - 1) < 0.01), p.ratio
