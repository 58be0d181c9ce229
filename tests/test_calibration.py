"""Calibration against measured sensors: one scale per band, least squares through the origin."""
import csv
import json
import subprocess
import sys

import numpy as np
import pytest

from lpy_light.run import simulate
from lpy_light.chamber import units
from lpy_light.errors import InputError
from lpy_light.chamber.scene import load_scene
from scenes import box, lamp_rectangle, rectangle_to_disc_fraction, write_scene

BLACK = "void plastic black\n0\n0\n5 0 0 0 0 0\n\nvoid light lamp\n0\n0\n3 10 10 10\n\n"
RAD = BLACK + box("black", (0, 0, 0), (1000, 1000, 1100)) + lamp_rectangle("lamp", (500, 500), 100, 1000)
RADIUS = 50.0
SENSORS = [(x, y, 400.0, RADIUS, 0, 0, 1) for y in (300, 500, 700) for x in (300, 500, 700)]
K_TRUE = 2.0e5      # µmol m-2 s-1 per (fraction of the photons / m²): the "real" lamps
PHOTONS = 100_000


def _expected_density(s):
    """Fraction of the emitted photons crossing sensor s, per m² (quadrature)."""
    x, y, z, r, *n = SENSORS[s]
    f = rectangle_to_disc_fraction((500, 500), 100, 1000, (0, 0, -1), (x, y, z), n, r)
    return f / (np.pi * (r * 1e-3) ** 2)


def _measured_csv(path, offset=5.0, header="x,y,z,rad", extra_rows=()):
    """Measured = K_TRUE · expected density, at points a few mm off the sensor centres, plus a repeat reading."""
    lines = [header]
    for s, (x, y, z, *_rest) in enumerate(SENSORS):
        lines.append("%g,%g,%g,%r" % (x + offset, y - offset, z, K_TRUE * _expected_density(s)))
    lines.append("%g,%g,%g,%r" % (SENSORS[4][0], SENSORS[4][1], SENSORS[4][2], 1.02 * K_TRUE * _expected_density(4)))
    lines.extend(extra_rows)
    path.write_text("\n".join(lines) + "\n")
    return path


@pytest.fixture(scope="module")
def scene(tmp_path_factory):
    d = tmp_path_factory.mktemp("cal")
    path = write_scene(d, RAD, SENSORS)
    _measured_csv(d / "measured.csv")
    return path


def _run(*args):
    return subprocess.run([sys.executable, "-m", "lpy_light", *map(str, args)], capture_output=True, text=True)


def test_calibration_recovers_a_known_scale(scene):
    chamber = load_scene(scene)
    measured = units.read_measured(scene.parent / "measured.csv", chamber)
    assert list(measured.sensor) == list(range(9)) + [4]
    assert measured.distance[0] == pytest.approx(np.sqrt(50))
    result = simulate.run(simulate.KernelScene(chamber, "weighted"), PHOTONS, seed=5, threads=2)
    photons, std = result.sensors()
    cal = units.calibrate(measured, photons, std, chamber.sensors.area * 1e-6, chamber.band_labels)
    k, k_std = cal.norm.scale[0] * PHOTONS, cal.norm.scale_std[0] * PHOTONS   # per fraction of the photons
    assert 0 < k_std < 0.03 * K_TRUE                 # the test has power
    # recovered within σ: σ comes from 10 residuals (a t with 9 degrees of freedom), so a 4σ bound
    assert abs(k - K_TRUE) < 4 * k_std, (k, k_std)
    band = cal.summary["bands"]["rad"]
    assert band["points"] == 10 and band["r2"] > 0.9 and band["rms_relative"] < 0.1
    assert len(cal.rows) == 10 and {"line", "sensor", "measured", "simulated", "residual"} <= set(cal.rows[0])
    assert cal.rows[-1]["line"] == 11 and cal.rows[-1]["sensor"] == 4


def test_cli_calibrate_writes_residuals_and_ppfd(scene, tmp_path):
    out = tmp_path / "out"
    p = _run("run", scene, "--photons", PHOTONS, "--seed", 5, "--threads", 2, "--out", out, "--quiet",
             "--calibrate", scene.parent / "measured.csv")
    assert p.returncode == 0, p.stderr
    summary = json.load(open(out / "summary.json"))
    cal = summary["calibration"]["bands"]["rad"]
    assert {"scale", "scale_std", "rms", "rms_relative", "r2", "points"} <= set(cal)
    assert "least squares" in summary["normalisation"]["assumption"]
    rows = list(csv.DictReader(open(out / "calibration.csv")))
    assert len(rows) == 10 and rows[0]["line"] == "2"
    sensors = list(csv.DictReader(open(out / "sensors.csv")))
    ppfd = np.array([float(r["ppfd"]) for r in sensors])
    truth = np.array([K_TRUE * _expected_density(s) for s in range(9)])
    assert np.all(np.abs(ppfd / truth - 1) < 0.15)


def test_scene_calibration_key(scene, tmp_path):
    toml = scene.parent / "with_cal.toml"
    toml.write_text(scene.read_text() + 'calibration = {file = "measured.csv", tolerance = 10}\n')
    assert load_scene(toml).calibration[1] == 10.0
    out = tmp_path / "out"
    p = _run("run", toml, "--photons", 20000, "--out", out, "--quiet")
    assert p.returncode == 0, p.stderr
    assert (out / "calibration.csv").exists() and "calibration" in json.load(open(out / "summary.json"))
    # a tolerance smaller than the 7 mm offsets: the first measured row is too far
    bad = scene.parent / "tight.toml"
    bad.write_text(scene.read_text() + 'calibration = {file = "measured.csv", tolerance = 1}\n')
    p = _run("run", bad, "--photons", 20000, "--out", tmp_path / "o2", "--quiet")
    assert p.returncode == 2 and "measured.csv:2:" in p.stderr and "tolerance" in p.stderr, p.stderr
    assert not (tmp_path / "o2").exists()


@pytest.mark.parametrize("content, where, what", [
    ("x,y,z,rad\n300,300,400,12.5\n500,300,400,oops\n", "measured.csv:3", "expected a number"),
    ("x,y,z,rad\n300,300,400,12.5\n300,300,\n", "measured.csv:3", "expected 4 values"),
    ("x,y,z,rad\n300,300,400,12.5\n900,900,400,3\n", "measured.csv:3", "nearest scene sensor"),
    ("x,y,z,500-600\n300,300,400,12.5\n", "measured.csv:1", "not a band of the scene"),
    ("a,b,rad\n1,2,3\n", "measured.csv:1", "x,y,z"),
    ("sensor,rad\n9,1.0\n", "measured.csv:2", "not a row of the scene's 9 sensors"),
    ("x,y,z,rad\n300,300,400,-1\n", "measured.csv:2", "non-negative"),
])
def test_malformed_measured_csv_names_file_and_line(scene, tmp_path, content, where, what):
    bad = tmp_path / "measured.csv"
    bad.write_text(content)
    with pytest.raises(InputError) as exc:
        units.read_measured(bad, load_scene(scene))
    assert where in str(exc.value) and what in str(exc.value), str(exc.value)


def test_malformed_measured_csv_on_the_command_line(scene, tmp_path):
    """Checked before tracing: one line naming file:line, status 2, no results."""
    bad = tmp_path / "measured.csv"
    bad.write_text("x,y,z,rad\n300,300,400,12.5\n500,300,400,oops\n")
    out = tmp_path / "out"
    p = _run("run", scene, "--photons", 1000, "--out", out, "--quiet", "--calibrate", bad)
    lines = [line for line in p.stderr.splitlines() if "warning" not in line]
    assert p.returncode == 2 and len(lines) == 1 and "measured.csv:3:" in lines[0], p.stderr
    assert not out.exists()


def test_sensor_index_and_semicolons(scene, tmp_path):
    """``sensor`` row indices instead of positions; a ';' csv with decimal commas."""
    path = tmp_path / "m.csv"
    path.write_text("sensor;rad;note\n0;12,5;a\n4;;b\n4;30,0;c\n")
    m = units.read_measured(path, load_scene(scene))
    assert list(m.sensor) == [0, 4, 4] and m.values[0, 0] == 12.5 and np.isnan(m.values[1, 0])


def test_missing_band_column_without_spectrum_is_an_error(scene, tmp_path):
    folder = tmp_path / "two"
    path = write_scene(folder, RAD, SENSORS, 'bands = [[600, 650], [650, 700]]\n')
    (folder / "m.csv").write_text("x,y,z,600-650\n300,300,400,1\n")
    chamber = load_scene(path)
    m = units.read_measured(folder / "m.csv", chamber)
    photons = np.ones((9, 2))
    with pytest.raises(InputError, match="no column for band 650-700"):
        units.calibrate(m, photons, photons, chamber.sensors.area * 1e-6, chamber.band_labels)
