"""Direct light from a Lambertian panel in a black room, against quadrature (4σ)."""
import numpy as np
import pytest

from lpy_light.run import simulate
from lpy_light.chamber.scene import load_scene
from scenes import box, lamp_rectangle, rectangle_to_disc_fraction, write_scene

BLACK = "void plastic black\n0\n0\n5 0 0 0 0 0\n\nvoid light lamp\n0\n0\n3 10 10 10\n\n"
MIRROR = "void mirror silver\n0\n0\n3 0.8 0.8 0.8\n\n"
PHOTONS = 400_000

# disc: centre, normal, radius (mm); the panel is 200 x 200 mm at z = 1000, facing down
DISCS = [((500, 500, 500), (0, 0, 1), 40.0),      # under the panel
         ((800, 600, 400), (0, 0, 1), 40.0),      # off axis
         ((700, 500, 600), (-1, 0, 0), 40.0),     # sideways, facing the panel's side
         ((500, 300, 700), (0, 1, 1), 40.0)]      # 45°, normal not unit


def _rows(discs):
    return [c + (r,) + n for c, n, r in discs]


@pytest.fixture(scope="module")
def direct(tmp_path_factory):
    rad = BLACK + box("black", (0, 0, 0), (1000, 1000, 1100)) + lamp_rectangle("lamp", (500, 500), 100, 1000)
    path = write_scene(tmp_path_factory.mktemp("direct"), rad, _rows(DISCS))
    chamber = load_scene(path)
    return chamber, simulate.run(simulate.KernelScene(chamber, "weighted"), PHOTONS, seed=11, threads=2)


def test_direct_light_matches_quadrature(direct):
    chamber, result = direct
    photons, std = result.sensors()
    for s, (c, n, r) in enumerate(DISCS):
        expected = PHOTONS * rectangle_to_disc_fraction((500, 500), 100, 1000, (0, 0, -1), c, n, r)
        z = (photons[s, 0] - expected) / std[s, 0]
        assert abs(z) < 4, "disc %d: %g vs %g expected (z = %.2f)" % (s, photons[s, 0], expected, z)
        assert std[s, 0] < 0.05 * expected   # the test has power: σ is a few % of the answer


def test_isotropic_panel_would_fail(direct):
    """The same bound rejects a wrong emission law (isotropic instead of Lambertian)."""
    chamber, result = direct
    photons, std = result.sensors()
    c, n, r = DISCS[0]
    lambert = rectangle_to_disc_fraction((500, 500), 100, 1000, (0, 0, -1), c, n, r)
    # isotropic over the lower hemisphere: intensity per sr is 1/(2π) instead of cosθ/π; on axis cosθ ≈ 1
    isotropic = lambert / 2
    assert abs(photons[0, 0] - PHOTONS * isotropic) / std[0, 0] > 10


def test_energy_closure_is_exact_for_one_band(direct):
    chamber, result = direct
    assert result.fate.sum() == pytest.approx(PHOTONS, rel=1e-9)
    assert result.closure[0][0] == pytest.approx(PHOTONS, rel=1e-9)
    # black room: everything is absorbed on the first hit, by the walls or the lamp itself
    assert result.fate[-3:].sum() == 0


def test_mirror_floor_matches_image_source(tmp_path):
    """A mirror floor (R = 0.8): a downward-facing disc sees only the panel's mirror image."""
    rad = (BLACK + MIRROR + box("black", (0, 0, 0), (1000, 1000, 1100)).replace(
        "black polygon floor", "silver polygon floor") + lamp_rectangle("lamp", (500, 500), 100, 1000))
    disc = ((450, 520, 300), (0, 0, -1), 100.0)
    path = write_scene(tmp_path, rad, _rows([disc]))
    chamber = load_scene(path)
    result = simulate.run(simulate.KernelScene(chamber, "weighted"), PHOTONS, seed=5, threads=2)
    photons, std = result.sensors()
    # image panel at z = -1000 facing up
    expected = 0.8 * PHOTONS * rectangle_to_disc_fraction((500, 500), 100, -1000, (0, 0, 1), *disc)
    assert abs(photons[0, 0] - expected) / std[0, 0] < 4
    # the test has power: a mirror of reflectance 0.6 instead of 0.8 would fail it
    assert abs(photons[0, 0] - expected * 0.6 / 0.8) / std[0, 0] > 6


def test_transparent_sensor_changes_no_other_count(tmp_path):
    rad = (BLACK.replace("5 0 0 0 0 0", "5 0.5 0.5 0.5 0 0") + box("black", (0, 0, 0), (1000, 1000, 1100))
           + lamp_rectangle("lamp", (500, 500), 100, 1000))
    base = [DISCS[0], DISCS[1]]
    up = ((500, 500, 800), (0, 0, 1), 90.0)     # right in the beam, facing up: counts photons from above
    down = ((500, 500, 750), (0, 0, -1), 90.0)  # facing down: counts only light coming back up
    runs = []
    for discs in (base, base + [up, down]):
        path = write_scene(tmp_path / str(len(discs)), rad, _rows(discs))
        chamber = load_scene(path)
        runs.append(simulate.run(simulate.KernelScene(chamber, "weighted"), 100_000, seed=3, threads=2))
    a, b = runs[0].sensors()[0], runs[1].sensors()[0]
    np.testing.assert_array_equal(a, b[:2])
    assert b[2, 0] > 5 * b[3, 0] > 0   # each counts only crossings from its front side


def test_results_do_not_depend_on_threads(direct):
    chamber, _ = direct
    ks = simulate.KernelScene(chamber, "weighted")
    r1 = simulate.run(ks, 3 * simulate.CHUNK + 17, seed=7, threads=1)
    r2 = simulate.run(ks, 3 * simulate.CHUNK + 17, seed=7, threads=2)
    r3 = simulate.run(ks, 3 * simulate.CHUNK + 17, seed=8, threads=2)
    np.testing.assert_array_equal(r1.tally, r2.tally)
    np.testing.assert_array_equal(r1.tally_sq, r2.tally_sq)
    np.testing.assert_array_equal(r1.fate, r2.fate)
    assert not np.array_equal(r1.tally, r3.tally)
