"""The L-Py layer: against the real L-Py when importable (conda), its plain parts always."""
import csv
import importlib.util
import subprocess
import sys
from pathlib import Path

import pytest

from lpy_light.light import organ_rows
from lpy_light.plant_view import plant_picture
from lpy_light.results import csv_text
from test_organs import FLUX, disc_mesh, square_mesh, _model, black_room  # noqa: F401  (fixture)

ROSE = Path(__file__).parent.parent / "lsystems" / "rose.lpy"
HAVE_LPY = importlib.util.find_spec("openalea") is not None and importlib.util.find_spec("openalea.lpy") is not None


def test_grow_without_lpy_says_how_to_get_it(tmp_path):
    if HAVE_LPY:
        pytest.skip("L-Py is installed")
    p = subprocess.run([sys.executable, "-m", "lpy_light", "grow", str(ROSE), "--steps", "1", "--out",
                        str(tmp_path / "out")], capture_output=True, text=True)
    assert p.returncode == 2 and "Traceback" not in p.stderr
    assert "conda" in p.stderr and len(p.stderr.strip().splitlines()) == 1
    assert not (tmp_path / "out").exists()


def test_organs_csv_and_picture_from_meshes(black_room, tmp_path):  # noqa: F811
    model = _model(black_room, photons=5_000)
    step = model.run(model.organs_from_meshes({1: disc_mesh(30, z=500), 2: square_mesh(5.0, z=450)},
                                              module="Leaf"))
    rows = organ_rows(step)
    (tmp_path / "organs.csv").write_text(csv_text(rows))
    got = list(csv.DictReader(open(tmp_path / "organs.csv")))
    assert {"step", "organ", "module", "band", "ppfd", "ppfd_std", "absorbed"} <= set(got[0])
    assert [r["organ"] for r in got] == ["1", "2"] and got[0]["module"] == "Leaf"
    plant_picture(tmp_path / "plant.png", model.kscene.organs, step.organs, title="test")
    assert (tmp_path / "plant.png").read_bytes()[:4] == b"\x89PNG"


@pytest.mark.lpy
@pytest.mark.skipif(not HAVE_LPY, reason="L-Py/PlantGL are conda-only; not importable here")
def test_rose_grows_with_light_in_its_parameters(tmp_path):
    """The real thing: the rose for a few steps, light written into modules, organs.csv and plant.png."""
    p = subprocess.run([sys.executable, "-m", "lpy_light", "grow", str(ROSE), "--steps", "6", "--photons", "20000",
                        "--out", str(tmp_path)], capture_output=True, text=True)
    assert p.returncode == 0, p.stderr
    rows = list(csv.DictReader(open(tmp_path / "organs.csv")))
    assert {r["module"] for r in rows} >= {"Leaf", "Internode", "Bud"}
    assert all(float(r["ppfd"]) >= 0 for r in rows)
    assert (tmp_path / "plant.png").exists()


@pytest.mark.lpy
@pytest.mark.skipif(not HAVE_LPY, reason="L-Py/PlantGL are conda-only; not importable here")
def test_endeach_writes_parameters_the_next_step_reads():
    from openalea.lpy import Lsystem
    lsys = Lsystem(str(ROSE), {"PHOTONS": 20000, "STEPS": 4})
    lstring = lsys.axiom
    for i in range(4):
        lstring = lsys.derive(lstring, i, 1)
    lights = [lstring[i].light for i in range(len(lstring)) if lstring[i].name == "Leaf"]
    assert lights and all(light is not None and light.par > 0 for light in lights)
