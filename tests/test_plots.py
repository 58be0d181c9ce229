"""--plot: one PNG per sensor plane; --reference: comparison line and difference maps; units on Angers."""
import csv
import json
import subprocess
import sys

import numpy as np
import pytest

from lpy_light.report import plots
from lpy_light.errors import LpyLightError
from scenes import box, lamp_rectangle, write_scene

RAD = ("void plastic wall\n0\n0\n5 0.5 0.5 0.5 0 0\n\nvoid light lamp\n0\n0\n3 10 10 10\n\n"
       + box("wall", (0, 0, 0), (1000, 1000, 1100)) + lamp_rectangle("lamp", (500, 500), 100, 1000))
# two horizontal planes (z = 300 and z = 600) and one sideways sensor
SENSORS = ([(x, y, 300.0, 60, 0, 0, 1) for y in (300, 700) for x in (300, 500, 700)]
           + [(x, 500, 600.0, 60, 0, 0, 1) for x in (300, 700)] + [(200, 500, 500, 60, 1, 0, 0)])


def _run(*args):
    return subprocess.run([sys.executable, "-m", "lpy_light", *map(str, args)], capture_output=True, text=True)


def _valid_png(path):
    import matplotlib.image as mpimg
    assert path.read_bytes()[:8] == b"\x89PNG\r\n\x1a\n"
    img = mpimg.imread(path)
    assert img.ndim == 3 and img.shape[0] > 100 and img.shape[1] > 100
    assert img[..., :3].std() > 0.01          # not a blank picture


def test_plane_groups():
    centers = np.array([[0, 0, 1000], [100, 0, 1000], [0, 0, 1400], [5, 5, 5], [0, 0, 0]], float)
    normals = np.array([[0, 0, 1], [0, 0, 1], [0, 0, 1], [0, 1, 1], [0, 0, -1]], float)
    groups = plots.plane_groups(centers, normals, unit="mm")
    names = [g["name"] for g in groups]
    assert names[0] == "z1000" and set(names) == {"z1000", "z1400", "plane", "z0"}
    assert list(groups[0]["index"]) == [0, 1] and groups[0]["axes"] == ("x", "y")
    assert "facing -z" in [g for g in groups if g["name"] == "z0"][0]["title"]


def test_run_plot_writes_one_png_per_plane(tmp_path):
    scene = write_scene(tmp_path / "s", RAD, SENSORS)
    out = tmp_path / "out"
    p = _run("run", scene, "--photons", 20000, "--out", out, "--quiet", "--plot")
    assert p.returncode == 0, p.stderr
    pngs = sorted(x.name for x in out.glob("*.png"))
    assert pngs == ["map_x200.png", "map_z300.png", "map_z600.png"], pngs
    for name in pngs:
        _valid_png(out / name)
    # the run itself as a reference: comparison line, difference maps, summary entry
    out2 = tmp_path / "out2"
    p = _run("run", scene, "--photons", 20000, "--seed", 2, "--out", out2, "--quiet", "--plot",
             "--reference", out / "sensors.csv")
    assert p.returncode == 0, p.stderr
    assert "within 4σ" in p.stdout and "band rad" in p.stdout
    assert sorted(x.name for x in out2.glob("diff_*.png")) == ["diff_x200.png", "diff_z300.png", "diff_z600.png"]
    _valid_png(out2 / "diff_z300.png")
    ref = json.load(open(out2 / "summary.json"))["reference"]
    assert ref["band"] == "rad" and 0 <= ref["within_4sigma"] <= 1
    # the ratio per row of each plane: printed, in summary.json, drawn (rows along y, columns along x)
    assert "z = 300 mm, facing +z: ratio to the reference along y (mean 1)" in p.stdout
    assert [line for line in p.stdout.splitlines() if "  y = " in line][0].split()[1:4] == ["y", "=", "300"]
    rows = {r["plane"]: r for r in ref["rows"]}
    assert rows["z300"]["position"] == [300, 700] and rows["z300"]["sensors"] == [3, 3]
    assert sorted(x.name for x in out2.glob("profile_*.png")) == ["profile_x200.png", "profile_z300.png",
                                                                   "profile_z600.png"]
    _valid_png(out2 / "profile_z300.png")
    # two references: their average (here a run and itself: the same ratios)
    out3 = tmp_path / "out3"
    p = _run("run", scene, "--photons", 20000, "--seed", 2, "--out", out3, "--quiet",
             "--reference", out / "sensors.csv", "--reference", out / "sensors.csv")
    assert p.returncode == 0, p.stderr
    ref3 = json.load(open(out3 / "summary.json"))["reference"]
    assert " + " in ref3["file"] and ref3["rows"][0]["ratio"] == pytest.approx(rows["z300"]["ratio"], rel=1e-12)


def test_reference_with_wrong_sensor_count_is_a_clean_error(tmp_path, angers_dir):
    scene = write_scene(tmp_path / "s", RAD, SENSORS)
    out = tmp_path / "out"
    p = _run("run", scene, "--photons", 1000, "--out", out, "--quiet", "--plot",
             "--reference", angers_dir / "reference-sec2" / "mesures.txt")
    lines = [line for line in p.stderr.splitlines() if "warning" not in line]
    assert p.returncode == 2 and len(lines) == 1 and "Traceback" not in p.stderr, p.stderr
    assert "mesures.txt: reference has 240 sensors, the scene 9" in lines[0]
    assert not out.exists()


def test_missing_matplotlib_is_a_clear_error(monkeypatch):
    monkeypatch.setitem(sys.modules, "matplotlib", None)
    with pytest.raises(LpyLightError, match=r"lpy-light\[plot\]"):
        plots.require_matplotlib()


def test_angers_ppfd_units_and_derived(tmp_path):
    """angers and angers-12bands: ppfd beside photons; the sensors' mean ppfd is the measured band flux;
    PAR (the nine bands in 400-700) and R:FR (655-665 / 725-735) per sensor; the assumption stated."""
    from lpy_light.chamber import units
    from lpy_light.chamber.scene import resolve_scene
    from lpy_light.chamber.scene import load_scene

    for name in ("angers", "angers-12bands"):
        out = tmp_path / name
        p = _run("run", name, "--photons", 2e5, "--estimator", "nee", "--out", out, "--quiet")
        assert p.returncode == 0, p.stderr
        rows = list(csv.DictReader(open(out / "sensors.csv")))
        assert {"photons", "photons_std", "ppfd", "ppfd_std"} <= set(rows[0])
        chamber = load_scene(resolve_scene(name))
        flux = units.band_photon_flux(chamber.spectrum, chamber.bands)
        for b, label in enumerate(chamber.band_labels):
            mean = np.mean([float(r["ppfd"]) for r in rows if r["band"] == label])
            assert mean == pytest.approx(flux[b], rel=1e-9)
        summary = json.load(open(out / "summary.json"))
        assert "measured at the sensor sites" in summary["normalisation"]["assumption"]
        if name == "angers-12bands":
            derived = list(csv.DictReader(open(out / "sensors_derived.csv")))
            assert len(derived) == 240 and {"par", "par_std", "r_fr", "r_fr_std"} <= set(derived[0])
            assert np.mean([float(r["par"]) for r in derived]) == pytest.approx(flux[:9].sum(), rel=1e-9)
            assert summary["derived"]["par"]["bands"][0] == "400-445" and len(summary["derived"]["par"]["bands"]) == 9
            assert summary["derived"]["r_fr"] == {"red": "655-665", "far_red": "725-735", "how": units.RFR_HOW}
