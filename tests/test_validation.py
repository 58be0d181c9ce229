"""The Angers chamber against SEC2 (docs/validation.md).

Fast: the reference readers, the scene -> SEC2 file mapping, and a 1e6-photon run of the full
chamber with power checks (a 3 % lamp error, two-sided surfaces or Lambertian lamps would fail the
same comparison).  Slow (``pytest -m slow``): the 1e8-photon criterion per scene.
"""
import numpy as np
import pytest

from lpy_light import reference, simulate, validation
from lpy_light.radiance import read_rad
from lpy_light.scene import load_scene

N_SEC2 = 999_999_936


SEC2_OFFSET = 0.005     # the 1e8 criterion's bound on |bias|: the full chamber sits -0.44 % ± 0.05 % from SEC2
SEC2_SPREAD = 0.005     # rms per-sensor difference beyond both noises and the mean offset, at 1e8 photons:
                        # √(1.03² − 0.80² − 0.44²) ≈ 0.48 % (docs/validation.md, full chamber)


def _ok(c, min_within=0.97, max_bias_sigmas=4.0):
    """The fast criterion: most sensors within 4σ and no mean bias beyond 4 of its σ plus the 0.5 % that the
    1e8 criterion allows (with next events' control variate, 1e6 photons resolve the full chamber's
    -0.44 % offset from SEC2, measured at 1e8 photons: docs/validation.md)."""
    return c.within_4sigma >= min_within and abs(c.bias) < max_bias_sigmas * c.bias_std + SEC2_OFFSET


# ---------------------------------------------------------------------------------------------
def test_read_sec2(angers_dir):
    ref = reference.read_sec2(angers_dir / "reference-sec2" / "mesures.txt")
    assert len(ref.photons) == 240 and ref.n_photons == N_SEC2
    assert ref.photons.min() == 12018 and ref.photons.max() == 31415 and ref.photons.sum() == 4846010
    np.testing.assert_allclose(ref.photons_std, np.sqrt(ref.photons))
    assert ref.centers.shape == (240, 3) and tuple(ref.centers[0]) == (110, 930, 1000)


def test_photon_mapping_against_sec2(angers_dir):
    """DATA.md: the photon-mapping run is -0.68 % (rms 1.21 %, noise alone ~1.0 %) from SEC2."""
    pm = reference.read_photon_mapping(validation.PHOTON_MAPPING)
    assert len(pm.photons) == 240 and pm.n_photons == 1e9
    c = reference.compare(pm.photons, pm.photons_std, pm.n_photons,
                          reference.read_sec2(angers_dir / "reference-sec2" / "mesures.txt"))
    assert c.bias == pytest.approx(-0.0068, abs=5e-5)
    assert c.rms == pytest.approx(0.0121, abs=5e-5)
    assert c.rms_noise == pytest.approx(0.0102, abs=5e-5)
    assert c.within_4sigma == 1.0
    # a 1 % scale error would show: the bias moves by 1 %, far beyond its σ (0.07 %)
    assert c.bias_std < 0.001


def test_compare_z_scores_by_hand():
    ref = reference.Reference(np.array([100.0, 400.0]), np.array([10.0, 20.0]), 1000, "hand")
    c = reference.compare([10.0, 60.0], [1.0, 1.0], 100, ref)      # scaled x10: 100 ± 10, 600 ± 10
    np.testing.assert_allclose(c.z, [0.0, 200 / np.hypot(10, 20)])
    np.testing.assert_allclose(c.relative, [0.0, 0.5])
    assert c.within_4sigma == 0.5 and c.bias == pytest.approx(0.25)
    assert c.rms == pytest.approx(np.sqrt(0.125))


@pytest.mark.parametrize("name", list(validation.SEC2_SCENES))
def test_scene_names_its_geometry_and_removals(name):
    vs = validation.SEC2_SCENES[name]
    assert vs.sec2_path.exists()
    text = vs.path.read_text()
    assert vs.sec2 in text, "the scene's comment names its SEC2 file"
    chamber = load_scene(vs.path)
    assert len(chamber.sensors) == 240
    prims = read_rad(validation.ANGERS / "geometry" / vs.geometry)
    assert "geometry/%s" % vs.geometry in text
    ids = {p.identifier for p in prims}
    assert set(vs.removed) <= ids
    kept = {s[0] for s in chamber.surfaces}
    assert not kept & set(vs.removed)
    assert kept == {p.identifier for p in prims if p.type == "polygon"} - set(vs.removed)
    names = [s[0] for s in chamber.surfaces]
    assert len(names) == len(set(names)), "SEC2's reading of repeated names: one surface per identifier"


# ---------------------------------------------------------------------------------------------
@pytest.fixture(scope="module")
def full_1e6():
    return validation.validate("angers", 1_000_000, estimator="nee", seed=1, threads=2)


def test_full_chamber_1e6_agrees_with_sec2(full_1e6):
    c = full_1e6["sec2"]
    assert c.within_4sigma >= 0.97, c.line()
    assert abs(c.bias) < 4 * c.bias_std + SEC2_OFFSET, c.line()
    # the spread is the noise, the mean offset and the per-sensor spread measured at 1e8 (which 1e6 photons
    # resolve since zone events: without them, a 1.2x noise bound alone)
    assert c.rms ** 2 < (1.2 * c.rms_noise) ** 2 + c.bias ** 2 + SEC2_SPREAD ** 2, c.line()
    assert full_1e6["photon_mapping"] is not None


def test_power_lamp_error_of_3_percent_would_fail(full_1e6):
    """The same run with the lamps 3 % too bright fails the fast criterion."""
    res = full_1e6["result"]
    p, s = res.sensors()
    ref = reference.read_sec2(validation.SEC2_SCENES["angers"].sec2_path)
    for factor in (1.03, 0.97):
        c = reference.compare(factor * p[:, 0], factor * s[:, 0], res.photons, ref)
        assert not _ok(c), (factor, c.line())


def test_power_two_sided_surfaces_would_fail():
    chamber = load_scene(validation.SEC2_SCENES["angers"].path, physics={"one_sided": False})
    run = validation.validate("angers", 1_000_000, estimator="nee", seed=1, threads=2,
                              kscene=validation.kernel_scene(chamber, "nee", threads=2))
    assert not _ok(run["sec2"]), run["sec2"].line()
    assert run["sec2"].bias < -0.015                  # ~ -3 % on this chamber (docs/validation.md)


def test_power_lamp_pattern_onlylamps():
    """Direct light only: isotropic line lamps pass, Lambertian cylinders (Radiance) fail."""
    line = validation.validate("angers-onlylamps", 1_000_000, estimator="nee", seed=1, threads=2)
    assert _ok(line["sec2"]), line["sec2"].line()
    lamb = validation.validate("angers-onlylamps", 1_000_000, estimator="nee", seed=1, threads=2,
                               variant="lamps=lambertian")
    assert not _ok(lamb["sec2"]), lamb["sec2"].line()


# ---------------------------------------------------------------------------------------------
# the requirement at 1e8 photons (each run 1-3 min on 2 threads); see docs/validation.md for why
# the variants without the table or without the Makrolon do not reach it
KNOWN_OFF = {
    "angers-sansmakrolon": "ours is 1.8 % below SEC2 (unexplained; docs/validation.md)",
    "angers-sanstable": "ours is 0.8 % above SEC2: which table primitives SEC2 left out is not known",
}


@pytest.mark.slow
@pytest.mark.parametrize("name", [pytest.param(n, marks=pytest.mark.xfail(reason=KNOWN_OFF[n], strict=True))
                                  if n in KNOWN_OFF else n for n in validation.SEC2_SCENES])
def test_sec2_criterion_1e8(name):
    run = validation.validate(name, 100_000_000, estimator="nee", seed=1, threads=2)
    c = run["sec2"]
    assert c.within_4sigma >= 0.99, c.line()
    assert abs(c.bias) < 0.005, c.line()
