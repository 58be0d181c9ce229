"""The Angers chamber against SEC2 (docs/validation.md).

Fast: the reference readers, the scene -> SEC2 file mapping, and a 1e6-photon run of the full
chamber with power checks (a 3 % lamp error, two-sided surfaces or Lambertian lamps would fail the
same comparison).  Slow (``pytest -m slow``): the 1e8-photon criterion per scene.
"""
import numpy as np
import pytest

from lpy_light.report import reference, validation
from lpy_light.run import simulate
from lpy_light.chamber.radiance import read_rad
from lpy_light.chamber.scene import load_scene

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
    "angers-sansmakrolon": "ours is 1.2 % below SEC2 (unexplained; docs/validation.md)",
    "angers-sanstable": "ours is 1.7 % above SEC2: which table primitives SEC2 left out is not known",
}


@pytest.mark.slow
@pytest.mark.parametrize("name", [pytest.param(n, marks=pytest.mark.xfail(reason=KNOWN_OFF[n], strict=True))
                                  if n in KNOWN_OFF else n for n in validation.SEC2_SCENES])
def test_sec2_criterion_1e8(name):
    run = validation.validate(name, 100_000_000, estimator="nee", seed=1, threads=2)
    c = run["sec2"]
    assert c.within_4sigma >= 0.99, c.line()
    assert abs(c.bias) < 0.005, c.line()


# ---------------------------------------------------------------------------------------------
# the shape of the full chamber's light field, row by row (issue 21; docs/validation.md, section 8)
ROW_BOUND = 0.006        # every row and column within 0.6 % of the references' average (both at mean 1)
CHANGE_BOUND = 0.005     # the least-squares change across the rows of a plane within 0.5 %


@pytest.fixture(scope="module")
def profiles_2e7():
    """Rows (along y) and columns (along x) of both planes against the average of SEC2 and the photon-mapping
    run, at 2e7 photons: our rows to ~0.05 %, the references' to ~0.15 % (1e9 photons each)."""
    run = validation.validate("angers", 20_000_000, estimator="nee", seed=1, threads=2)
    p, s = run["result"].sensors()
    chamber = validation.load("angers")
    avg = reference.average([reference.read_sec2(validation.SEC2_SCENES["angers"].sec2_path),
                             reference.read_photon_mapping(validation.PHOTON_MAPPING)])
    return {(prof.plane, prof.axis): prof for across in (1, 0)
            for prof in reference.row_profiles(p[:, 0], s[:, 0], avg, chamber.sensors.center, chamber.sensors.normal,
                                               across=across)}


@pytest.mark.slow
@pytest.mark.parametrize("plane, axis", [("z1000", "x"), ("z1400", "x"), ("z1000", "y"),
                                         pytest.param("z1400", "y", marks=pytest.mark.xfail(strict=True, reason=(
                                             "+0.7 % across the rows, +0.8 % in the last (y = 1830, under the strip "
                                             "along the wall where the Makrolon and a cornice top coincide): the "
                                             "references resolve that tie by their arithmetic, the photon-mapping "
                                             "engine for the cornice 72 % of the time (emulated from its source), "
                                             "lpy-light by a fair choice (docs/validation.md, section 8)")))])
def test_full_chamber_rows_match_the_references(profiles_2e7, plane, axis):
    """Every row (constant y) and column (constant x) of each plane within 0.6 % of the references' average (or 4σ
    of the row, when the references' own noise, ~0.16 % per row, makes that larger: they differ from each other by
    1.0 % in the column x = 210 at z = 1400) and no change across them beyond 0.5 %.  What breaks it: the lamp-box mirror at x = 50, which both references' readers
    lose (physics.repeated_names = "all": +1.5 % along x at z = 1400, +1.4 % along y), or the cornices winning the
    coplanar tie in every strip (-0.5 % along y, +2.2 % along x at z = 1400)."""
    prof = profiles_2e7[(plane, axis)]
    assert abs(prof.slope) < CHANGE_BOUND, prof.lines()
    assert np.all(np.abs(prof.ratio - 1) < np.maximum(ROW_BOUND, 4 * prof.ratio_std)), prof.lines()
