"""A scene's changes to its geometry (lpy_light.chamber.overrides): lamp outputs per band, shifts, materials,
lamp_flux, base."""
from __future__ import annotations

import numpy as np
import pytest

from lpy_light.run import simulate
from lpy_light.chamber import units
from lpy_light.errors import InputError
from lpy_light.chamber.scene import load_scene
from scenes import box

ROOM = ("void plastic grey\n0\n0\n5\n0.5 0.5 0.5 0 0\n\nvoid light lum\n0\n0\n3\n10 10 10\n\n"
        + box("grey", (0, 0, 0), (1000, 1000, 1000))
        + "lum cylinder lampA\n0\n0\n7\n300 500 900 400 500 900 1\n\n"
        + "lum cylinder lampB\n0\n0\n7\n600 500 900 700 500 900 1\n\n")


def scene(tmp_path, extra=""):
    tmp_path.mkdir(parents=True, exist_ok=True)
    (tmp_path / "room.rad").write_text(ROOM)
    (tmp_path / "sites.csv").write_text("X,Y,Z,rayon_capteur,Xnorm,Ynorm,Znorm\n" +
                                        "".join("%d,500,400,120,0,0,1\n" % x for x in (200, 500, 800)))
    (tmp_path / "scene.toml").write_text('geometry = "room.rad"\nsensors = "sites.csv"\n'
                                         'bands = [[400, 500], [600, 700]]\n' + extra)
    return tmp_path / "scene.toml"


def tallies(path, estimator="nee", photons=200_000):
    ch = load_scene(path)
    ks = simulate.KernelScene(ch, estimator=estimator)
    if estimator == "nee":
        ks.prune_next_events()
    r = simulate.run(ks, photons, seed=4, threads=1)
    return ch, r


@pytest.mark.parametrize("estimator", ["nee", "analog"])
def test_an_output_per_band_scales_that_band_alone(tmp_path, estimator):
    """Lamp A at [1, 0.5], lamp B at 0.5: each band is what the two lamps give there, exactly in expectation."""
    _, plain = tallies(scene(tmp_path / "plain"), estimator)
    _, onlyA = tallies(scene(tmp_path / "a", "[lamps.lampB]\noutput = 0.0\n"), estimator)
    ch, both = tallies(scene(tmp_path / "ab", "[lamps.lampA]\noutput = [1.0, 0.5]\n[lamps.lampB]\noutput = 0.5\n"),
                       estimator)
    share = ch.emitters.band_share()
    assert np.allclose(share, [0.75 / 0.625, 0.5 / 0.625])
    # photons per emitted photon of the whole scene: A alone has half its power, so per unit of power
    a = onlyA.tally[:3] / onlyA.photons                  # A's light per photon of A
    b = 2 * plain.tally[:3] / plain.photons - a          # B's, from the plain scene (A and B each half)
    expected = np.stack([(1.0 * a[:, 0] + 0.5 * b[:, 0]), (0.5 * a[:, 1] + 0.5 * b[:, 1])], axis=1) / 1.25
    got = both.tally[:3] / both.photons
    sigma = np.hypot(both.tally_std[:3] / both.photons, 2 * plain.tally_std[:3] / plain.photons)
    assert (np.abs(got - expected) < 4 * sigma + 1e-12).all(), (got, expected)
    # and a physics that would ignore the output fails: band 2 would then equal the plain scene
    assert np.abs(got[:, 1] - plain.tally[:3, 1] / plain.photons).max() > 5 * sigma[:, 1].max()


def test_outputs_of_one_give_the_same_numbers_bit_for_bit(tmp_path):
    _, plain = tallies(scene(tmp_path / "plain"))
    _, ones = tallies(scene(tmp_path / "ones", "[lamps.lampA]\noutput = 1.0\nshift = [0.0, 0.0, 0.0]\n"))
    assert np.array_equal(plain.tally, ones.tally)


def test_lamp_flux_gives_ppfd_without_the_spectrum(tmp_path):
    ch, r = tallies(scene(tmp_path, "lamp_flux = [100.0, 50.0]\n[lamps.lampA]\noutput = [1.0, 0.5]\n"))
    norm = units.scene_normalisation(ch, r)
    # the scene's flux in band b: lamp_flux_b, carried by N photons of expected weight share_b each
    assert np.allclose(norm.scale * r.photons * ch.emitters.band_share(), [100.0, 50.0])


def test_a_shift_moves_the_lamp(tmp_path):
    ch = load_scene(scene(tmp_path, "[lamps.lampA]\nshift = [10.0, -5.0, 2.0]\n"))
    a = [i for i, n in enumerate(ch.emitters.name) if n == "lampA"][0]
    assert np.allclose(ch.emitters.data[a, 0], [310, 495, 902]) and np.allclose(ch.emitters.data[a, 2], [1, 0, 0])


@pytest.mark.parametrize("extra, line, what", [
    ("[lamps.lampZ]\noutput = 1.0\n", 4, "no light source of that identifier"),
    ("[lamps.lampA]\noutput = [1.0, 2.0, 3.0]\n", 5, "list of 2 numbers"),
    ("[lamps.lampA]\ncolour = 1\n", 5, "unknown key 'colour'"),
    ("[materials.grey]\nreflectance = 2.5\n", 4, "not energy-conserving"),
    ("[materials.grey]\nspecular_transmission = 1.5\n", 5, "in 0..1"),
    ("lamp_flux = [1.0, -2.0]\n", 4, ">= 0"),
])
def test_bad_overrides_name_their_line(tmp_path, extra, line, what):
    path = scene(tmp_path, extra)
    with pytest.raises(InputError) as exc:
        load_scene(path)
    assert exc.value.line == line and what in str(exc.value), str(exc.value)


def test_a_scene_based_on_another_keeps_the_base_paths_and_adds_its_own(tmp_path):
    base = scene(tmp_path / "base")
    child = tmp_path / "elsewhere" / "fitted.toml"
    child.parent.mkdir()
    (child.parent / "mine.csv").write_text("X,Y,Z,rayon_capteur,Xnorm,Ynorm,Znorm\n500,500,600,30,0,0,1\n")
    child.write_text('base = "../base/scene.toml"\nsensors = "mine.csv"\n[lamps.lampB]\noutput = 0.0\n')
    ch = load_scene(child)
    assert len(ch.sensors) == 1 and ch.n_bands == 2
    assert ch.emitters.output[[n == "lampB" for n in ch.emitters.name]].max() == 0
    child.write_text('base = "fitted.toml"\n')
    with pytest.raises(InputError, match="leads back"):
        load_scene(child)
    assert load_scene(base).emitters.output is None


def test_a_light_model_on_a_fitted_chamber_takes_its_lamp_flux(tmp_path):
    """LightModel (grow, the .lpy files) reads a fitted scene as run does: the flux is the scene's, no run."""
    from lpy_light import LightModel
    fitted = tmp_path / "fitted.toml"
    fitted.write_text('base = "angers-12bands"\nlamp_flux = %s\n[lamps.lamp20Str]\noutput = 0.5\n'
                      % [float(10 * (i + 1)) for i in range(12)])
    model = LightModel(str(fitted), normalisation_photons=1000)
    share = model.chamber.emitters.band_share()
    assert np.allclose(model.flux * share, 10.0 * np.arange(1, 13)) and not model.flux_std.any()
    assert model.normalisation.assumption == units.LAMP_FLUX_ASSUMPTION
