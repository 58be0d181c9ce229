"""The command-line contract: lpy-light run SCENE --photons --seed --threads --out."""
import csv
import json
import subprocess
import sys

import pytest

from scenes import box, lamp_rectangle, write_scene

RAD = ("void plastic wall\n0\n0\n5 0.5 0.5 0.5 0 0\n\nvoid light lamp\n0\n0\n3 10 10 10\n\n"
       + box("wall", (0, 0, 0), (1000, 1000, 1100)) + lamp_rectangle("lamp", (500, 500), 100, 1000))
SENSORS = [(300, 300, 400, 60, 0, 0, 1), (700, 650, 200, 60, 0, 0, -1)]


def _run(*args):
    return subprocess.run([sys.executable, "-m", "lpy_light", *map(str, args)], capture_output=True, text=True)


def test_run_writes_sensors_and_summary(tmp_path):
    scene = write_scene(tmp_path / "s", RAD, SENSORS)
    out = tmp_path / "out"
    p = _run("run", scene, "--photons", "5e4", "--seed", 3, "--threads", 2, "--out", out, "--quiet")
    assert p.returncode == 0, p.stderr
    rows = list(csv.DictReader(open(out / "sensors.csv")))
    assert [r["sensor"] for r in rows] == ["0", "1"] and {r["band"] for r in rows} == {"rad"}
    assert float(rows[0]["photons"]) > 0 and float(rows[0]["photons_std"]) > 0
    summary = json.load(open(out / "summary.json"))
    assert summary["photons"] == 50000 and summary["seconds"] > 0
    closure = summary["energy_closure"]["rad"]
    assert 0 < closure["residual_std"] < 0.01 * closure["emitted"]
    assert abs(closure["residual"]) < 4 * closure["residual_std"]
    assert closure["absorbed"]["wall"] > 0 and closure["escaped"] == 0
    # same seed, other thread count: identical file
    p2 = _run("run", scene, "--photons", "5e4", "--seed", 3, "--threads", 1, "--out", tmp_path / "o2", "--quiet")
    assert p2.returncode == 0
    assert (tmp_path / "o2" / "sensors.csv").read_text() == (out / "sensors.csv").read_text()
    # SEC2's analog counting closes exactly
    p3 = _run("run", scene, "--photons", "5e4", "--estimator", "analog", "--out", tmp_path / "o3", "--quiet")
    assert p3.returncode == 0, p3.stderr
    closure = json.load(open(tmp_path / "o3" / "summary.json"))["energy_closure"]["rad"]
    assert closure["residual"] == pytest.approx(0, abs=1e-6) and closure["residual_std"] < 1e-3


def test_precision_stops_when_every_sensor_is_there(tmp_path):
    """``--precision REL``: the run stops once every sensor's relative σ is ≤ REL, well before the cap,
    with the same files as a plain run of the photons it traced; the summary and the last line say which
    sensor was the slowest.  Too small a cap: the cap's photons, and "NOT reached"."""
    scene = write_scene(tmp_path / "s", RAD, SENSORS)
    out = tmp_path / "p"
    p = _run("run", scene, "--precision", "0.02", "--photons", "1e8", "--seed", 5, "--out", out, "--estimator", "weighted")
    assert p.returncode == 0, p.stderr
    summary = json.load(open(out / "summary.json"))
    rows = list(csv.DictReader(open(out / "sensors.csv")))
    rel = [float(r["photons_std"]) / float(r["photons"]) for r in rows]
    assert summary["precision_reached"] and 0 < summary["photons"] < 1e7
    assert max(rel) <= 0.02 and max(rel) > 0.015          # stopped at the first check past the goal
    assert summary["relative_sigma"]["max"] == pytest.approx(max(rel))
    assert summary["relative_sigma"]["max_at"]["sensor"] == rel.index(max(rel))
    assert "goal 2 % reached" in p.stderr
    plain = tmp_path / "plain"
    p2 = _run("run", scene, "--photons", summary["photons"], "--seed", 5, "--out", plain, "--quiet",
              "--estimator", "weighted")
    assert p2.returncode == 0, p2.stderr
    assert (plain / "sensors.csv").read_text() == (out / "sensors.csv").read_text()
    p3 = _run("run", scene, "--precision", "1e-4", "--photons", "5e4", "--out", tmp_path / "cap")
    assert p3.returncode == 0, p3.stderr
    capped = json.load(open(tmp_path / "cap" / "summary.json"))
    assert capped["photons"] == 50000 and not capped["precision_reached"]
    assert "NOT reached" in p3.stderr


@pytest.mark.parametrize("mutate, where", [
    (lambda d: (d / "scene.rad").write_text(RAD.replace("5 0.5 0.5 0.5 0 0", "5 0.5 0.5 oops 0 0")), "scene.rad:4"),
    (lambda d: (d / "sensors.csv").write_text("X,Y,Z,rayon_capteur,Xnorm,Ynorm,Znorm\n1,2,3,4,0,0\n"), "sensors.csv:2"),
    (lambda d: (d / "scene.toml").write_text('geometry = "scene.rad"\nbands = [[700, 600]]\n'), "scene.toml:2"),
    (lambda d: (d / "scene.toml").write_text('geometry = "missing.rad"\n'), "scene.toml:1"),
])
def test_bad_input_one_line_no_traceback_no_results(tmp_path, mutate, where):
    d = tmp_path / "s"
    write_scene(d, RAD, SENSORS)
    mutate(d)
    out = tmp_path / "out"
    p = _run("run", d / "scene.toml", "--photons", 1000, "--out", out, "--quiet")
    assert p.returncode == 2
    lines = [line for line in p.stderr.splitlines() if "warning" not in line]
    assert len(lines) == 1 and "Traceback" not in p.stderr, p.stderr
    assert where in lines[0] and lines[0].startswith("lpy-light: error:")
    assert not out.exists() or not any(out.iterdir())


def test_default_run_is_nee_to_one_percent_and_says_what_it_wrote(tmp_path):
    """Without --photons or --precision, ``run`` gives the best answer: next events, every sensor's σ ≤ 1 %
    (checked from the files), and its last lines say how precise it is and where the results are.
    ``--photons`` alone keeps its meaning (exactly that many photons, no precision goal)."""
    scene = write_scene(tmp_path / "s", RAD, SENSORS)
    out = tmp_path / "d"
    p = _run("run", scene, "--seed", 2, "--out", out)
    assert p.returncode == 0, p.stderr
    summary = json.load(open(out / "summary.json"))
    assert summary["estimator"] == "nee" and summary["precision"] == 0.01 and summary["precision_reached"]
    rows = list(csv.DictReader(open(out / "sensors.csv")))
    assert max(float(r["photons_std"]) / float(r["photons"]) for r in rows) <= 0.01
    assert "goal 1 % reached" in p.stderr and ("results in %s: sensors.csv" % out) in p.stderr
    fixed = tmp_path / "f"
    p2 = _run("run", scene, "--photons", 40000, "--out", fixed, "--quiet")
    assert p2.returncode == 0, p2.stderr
    summary = json.load(open(fixed / "summary.json"))
    assert summary["photons"] == 40000 and "precision" not in summary and summary["estimator"] == "nee"


def test_every_command_prints_its_help():
    """``lpy-light CMD --help`` for every command: argparse expands ``%`` in help texts, so a help
    mentioning '1 %' must write it '%%' after any Python formatting ('run --help' crashed with a
    ValueError before)."""
    import argparse
    from lpy_light import cli
    parser = cli._parser()
    parser.format_help()
    subs = [a for a in parser._actions if isinstance(a, argparse._SubParsersAction)]
    assert subs and subs[0].choices
    for name, sub in subs[0].choices.items():
        text = sub.format_help()
        assert name in text
    assert "stops at 1%" in subs[0].choices["run"].format_help()


def test_a_folder_stands_for_its_scene_and_a_results_folder_is_not_a_scene(tmp_path, monkeypatch):
    """``run angers --out angers`` run twice: the second must not take the first's results folder for the
    scene.  A folder holding one scene (``scene.toml``, or a single ``.toml``) stands for it; any other folder
    is refused with its name."""
    from lpy_light.errors import InputError
    from lpy_light.chamber.scene import builtin_scenes, resolve_scene
    monkeypatch.chdir(tmp_path)
    (tmp_path / "angers").mkdir()
    (tmp_path / "angers" / "summary.json").write_text("{}")
    assert resolve_scene("angers") == builtin_scenes()["angers"]
    (tmp_path / "mine").mkdir()
    (tmp_path / "mine" / "chamber.toml").write_text("")
    assert resolve_scene("mine").resolve() == tmp_path / "mine" / "chamber.toml"
    (tmp_path / "mine" / "other.toml").write_text("")
    with pytest.raises(InputError, match="it has 2: chamber.toml, other.toml"):
        resolve_scene("mine")
    (tmp_path / "mine" / "scene.toml").write_text("")
    assert resolve_scene("mine").resolve() == tmp_path / "mine" / "scene.toml"
    (tmp_path / "empty").mkdir()
    with pytest.raises(InputError, match="a folder, not a scene file.*it has none"):
        resolve_scene("empty")
