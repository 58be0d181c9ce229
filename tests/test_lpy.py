"""The L-Py layer: against the real L-Py and PlantGL where importable (``scripts/test-lpy.sh`` installs the
bundle of ``../shared/lpy`` into ``.venv-lpy``; users get them from conda), its plain parts always."""
import csv
import importlib.util
import json
import subprocess
import sys
from pathlib import Path

import pytest

from lpy_light.plant.light import organ_rows
from lpy_light.plant.plant_view import plant_picture
from lpy_light.run.results import csv_text
from test_organs import FLUX, disc_mesh, square_mesh, _model, black_room  # noqa: F401  (fixture)

LSYSTEMS = Path(__file__).parent.parent / "lsystems"
ROSE = LSYSTEMS / "rose.lpy"
SEED_ROSE = LSYSTEMS / "rose-simple4.lpy"
SEED_ROSE_LIT = LSYSTEMS / "rose-simple4-light.lpy"
HAVE_LPY = importlib.util.find_spec("openalea") is not None and importlib.util.find_spec("openalea.lpy") is not None
lpy = pytest.mark.skipif(not HAVE_LPY, reason="L-Py/PlantGL are not importable here (conda, or scripts/test-lpy.sh)")
SEED_ORGANS = ["--organs", "Leaf=FeuilleVieille_Sup/FeuilleVieille_Inf", "--organs", "Internode=FeuilleVieille_Sup",
               "--organs", "Bud=FeuilleVieille_Sup", "--organs", "Flower=FeuilleVieille_Sup"]


def _grow(*args):
    return subprocess.run([sys.executable, "-m", "lpy_light", "grow", *map(str, args)], capture_output=True,
                          encoding="utf-8")


def _rows(path, band="655-665"):
    return [r for r in csv.DictReader(open(path)) if r["band"] == band]


def test_grow_without_lpy_says_how_to_get_it(tmp_path):
    if HAVE_LPY:
        pytest.skip("L-Py is installed")
    p = _grow(ROSE, "--steps", "1", "--out", tmp_path / "out")
    assert p.returncode == 2 and "Traceback" not in p.stderr
    assert "conda" in p.stderr and len(p.stderr.strip().splitlines()) == 1


def test_our_models_survive_a_save_in_the_lpy_ide():
    """The L-Py IDE takes the editor's text through Latin-1 (``lpycodeeditor.getCode``: other characters become
    '?' when a model is saved): the models we ship hold no character outside it."""
    for path in LSYSTEMS.glob("*.lpy"):
        text = path.read_text(encoding="utf-8")
        assert text.encode("latin-1", "replace").decode("latin-1") == text, path.name


def test_organs_csv_and_picture_from_meshes(black_room, tmp_path):  # noqa: F811
    model = _model(black_room, photons=5_000)
    step = model.run(model.organs_from_meshes({1: disc_mesh(30, z=500), 2: square_mesh(5.0, z=450)},
                                              module="Leaf"))
    rows = organ_rows(step)
    (tmp_path / "organs.csv").write_text(csv_text(rows))
    got = list(csv.DictReader(open(tmp_path / "organs.csv")))
    assert {"step", "organ", "module", "band", "ppfd", "ppfd_std", "absorbed", "par", "par_std", "role"} <= set(got[0])
    assert [r["organ"] for r in got] == ["1", "2"] and got[0]["module"] == "Leaf"
    plant_picture(tmp_path / "plant.png", model.kscene.organs, step.organs, title="test", top=100.0)
    assert (tmp_path / "plant.png").read_bytes()[:4] == b"\x89PNG"


# -- the real L-Py ------------------------------------------------------------------------------
def _derive(model, steps, **externs):
    """(lstring, lsystem) after ``steps`` steps of ``model`` with ``externs``."""
    from openalea.lpy import Lsystem
    lsys = Lsystem(str(model), {"STEPS": steps, **externs})
    return lsys.derive(), lsys


def _bursts(lstring) -> int:
    """Buds that grew out: each became the Apex of a new axis (order >= 1)."""
    return sum(1 for m in lstring if m.name == "Apex" and m[0] >= 1)


@pytest.mark.lpy
@lpy
def test_rose_grows_with_its_light_and_pictures(tmp_path):
    """``lpy-light grow``: organs.csv with σ on PAR, internodes reported as shading only (no PAR), the last step's
    picture and one every --plot-every steps, and each kind of warning printed at most once."""
    p = _grow(ROSE, "--steps", 8, "--photons", 100_000, "--precision", 0.5, "--plot-every", 4, "--out", tmp_path)
    assert p.returncode == 0, p.stderr
    rows = _rows(tmp_path / "organs.csv")
    assert {r["module"] for r in rows} == {"Leaf", "Internode", "Bud"}
    for r in rows:
        if r["module"] == "Internode":
            assert r["role"] == "shading only" and r["ppfd"] == r["par"] == r["par_std"] == ""
        else:
            assert r["role"] == "target" and float(r["par"]) > 0 and float(r["par_std"]) > 0
    assert sorted(f.name for f in tmp_path.glob("*.png")) == ["plant.png", "plant_003.png", "plant_007.png"]
    summary = json.loads((tmp_path / "summary.json").read_text())
    assert len(summary["steps"]) == 8 and all("convert_seconds" in s for s in summary["steps"][1:])
    assert summary["estimator"] == "nee" and summary["settings"]["closed_zones"] is True   # what ran, to rerun it
    assert summary["seed"] == 1 and summary["scene"].endswith(".toml")
    warnings = [line for line in p.stderr.splitlines() if ": warning: " in line]
    assert len(warnings) == len(set(w.split(":")[2][:40] for w in warnings))


@pytest.mark.lpy
@lpy
def test_lit_steps_leave_the_locale_and_utf8_files_as_they_were(utf8_locale, tmp_path):
    """Issue 47: PlantGL's ``Point3Array.to_str`` (how a tessellation's points are read) sets the C locale and
    never restores it; after a lit step the default encoding was ASCII and the L-Py IDE saved a model holding µ
    as an empty file.  After lit steps in the real L-Py, the locale is the one before, and a UTF-8 file is
    written and read back through ``open()`` with the default encoding."""
    import locale
    before = locale.setlocale(locale.LC_ALL)
    lstring, _ = _derive(ROSE, 3, PHOTONS=20_000, PRECISION=0)
    assert any(m.name == "Leaf" and m.light is not None for m in lstring)      # the steps were lit
    assert locale.setlocale(locale.LC_ALL) == before
    assert locale.getpreferredencoding(False) == "UTF-8"
    text = ROSE.read_text(encoding="utf-8")
    assert "µ" in text
    with open(tmp_path / "rose.lpy", "w") as fh:        # as the IDE saves: the locale's encoding
        fh.write(text)
    assert open(tmp_path / "rose.lpy").read() == text


@pytest.mark.lpy
@lpy
def test_plantgl_calls_that_set_the_locale_are_guarded(utf8_locale, tmp_path):
    """Every PlantGL call found to set the process's locale (``Point2/3/4Array.to_str``, the ``.geom``
    reader): each does (so the guard is needed), and inside :func:`preserved_locale` the locale comes back."""
    import locale
    import openalea.plantgl.all as pgl
    from lpy_light.process_state import preserved_locale
    (tmp_path / "s.geom").write_text("Sphere s { Radius 1.5 }\n")
    calls = {"Point2Array.to_str": lambda: pgl.Point2Array([(0, 1)]).to_str(),
             "Point3Array.to_str": lambda: pgl.Point3Array([(0, 1, 2)]).to_str(),
             "Point4Array.to_str": lambda: pgl.Point4Array([(0, 1, 2, 3)]).to_str(),
             "Scene(.geom)": lambda: pgl.Scene(str(tmp_path / "s.geom"))}
    for name, call in calls.items():
        call()
        assert locale.setlocale(locale.LC_ALL) == "C", name            # PlantGL's side effect, still there
        locale.setlocale(locale.LC_ALL, "C.UTF-8")
        with preserved_locale():
            call()
        assert locale.setlocale(locale.LC_ALL) == "C.UTF-8", name


@pytest.mark.lpy
@lpy
def test_meshes_read_fast_are_plantgls_own():
    """The triangles read from an ``Index3Array``'s text, and the faces reused between shapes of one topology
    (a growing internode), are those PlantGL's own iteration gives, for every primitive the turtle makes and
    for a leaf swept along a curve; a shape whose triangles differ from its topology's is not given them."""
    import numpy as np
    import openalea.plantgl.all as pgl
    from lpy_light.plant import lpy as adapter
    from lpy_light.plant.organs import TessellationCache
    V = pgl.Vector3
    path = pgl.Polyline([V(0, 0, 0), V(0, 0.5, 1), V(0, 2, 1.5), V(0, 3, 1)])
    profile = pgl.Polyline2D([pgl.Vector2(-0.5, 0), pgl.Vector2(0, 0.1), pgl.Vector2(0.5, 0)])
    shapes = [pgl.Translated(V(1, 2, 3), pgl.Oriented(V(1, 0, 0), V(0, 1, 0), pgl.Cylinder(r, h, False, 8)))
              for r, h in ((0.1, 1.0), (0.2, 3.5), (0.05, 0.01))]
    shapes += [pgl.Translated(V(0, 0, 1), pgl.Sphere(0.3, 8, 6)), pgl.Frustum(0.5, 2.0, 0.3, True, 12),
               pgl.Cone(0.4, 1.0, True, 10), pgl.Disc(1.0, 16), pgl.Box(V(1, 2, 3)),
               pgl.Cylinder(0.1, 1.0, True, 8), pgl.Extrusion(path, profile), pgl.Sphere(1.0, 200, 200)]
    cache = TessellationCache()
    for geometry in shapes:
        shape = pgl.Shape(geometry)
        t = pgl.Tesselator()
        shape.apply(t)
        own = np.array([tuple(f) for f in t.result.indexList], dtype=np.int64)
        assert np.array_equal(adapter._faces(t.result.indexList), own), type(geometry).__name__
        key = adapter.geometry_key(geometry)
        points, faces = adapter._tessellate(shape, pgl, adapter.topology_key(key), cache.faces)
        assert np.array_equal(faces, own), type(geometry).__name__
        assert len(points) == len(t.result.pointList)
    # the three internodes share one face list; the solid cylinder (caps) has its own
    thin = [adapter.topology_key(adapter.geometry_key(g)) for g in shapes[:3]]
    assert thin[0] == thin[1] == thin[2] != adapter.topology_key(adapter.geometry_key(shapes[-3]))
    # a cached topology whose counts differ is not reused (e.g. a tessellator that dropped a triangle)
    bogus = next(iter(cache.faces))
    cache.faces[bogus] = (np.zeros((3, 3), dtype=np.int64), 3)
    shape = pgl.Shape(shapes[0])
    points, faces = adapter._tessellate(shape, pgl, bogus, cache.faces)
    assert len(faces) > 3


@pytest.mark.lpy
@pytest.mark.slow
@lpy
def test_the_locale_after_30_lit_steps_of_each_model_is_the_one_before(utf8_locale, tmp_path):
    """Issue 47's criterion, on every model in ``lsystems/``: 30 lit steps in the real L-Py (the models that call
    us from their ``EndEach``, and rose-simple4 lit from outside at every step by ``lpy-light grow``)."""
    import locale
    from openalea.lpy import Lsystem
    from lpy_light.cli import main
    before = locale.setlocale(locale.LC_ALL)
    for model, externs in ((ROSE, {"STEPS": 30, "PHOTONS": 50_000, "PRECISION": 0}),
                           (SEED_ROSE_LIT, {"PHOTONS": 50_000})):
        lsys = Lsystem(str(model), externs)
        lstring = lsys.derive(lsys.axiom, 0, 30)
        assert any(m.name == "Leaf" and m.light is not None for m in lstring) if model == ROSE else True
        assert locale.setlocale(locale.LC_ALL) == before, model.name
    code = main(["grow", str(SEED_ROSE), "--steps", "30", "--photons", "20000", "--at", "1280,860,980",
                 "--targets", "Leaf,Bud", *SEED_ORGANS, "--quiet", "--out", str(tmp_path / "seed")])
    assert code == 0 and len(json.loads((tmp_path / "seed" / "summary.json").read_text())["steps"]) == 30
    assert locale.setlocale(locale.LC_ALL) == before and locale.getpreferredencoding(False) == "UTF-8"


@pytest.mark.lpy
@lpy
def test_ctrl_c_during_grow_says_so_in_its_last_line(tmp_path):
    """Issue 47: an interrupted ``grow`` exits 130 with consistent partial files, and its last line says it was
    stopped, after how many steps, and where the partial results are."""
    import signal
    import time
    out = tmp_path / "out"
    child = subprocess.Popen([sys.executable, "-m", "lpy_light", "grow", str(ROSE), "--steps", "30", "--photons",
                              "100000", "--precision", "0.5", "--out", str(out)], stderr=subprocess.PIPE,
                             encoding="utf-8")
    lines = []
    for line in child.stderr:
        lines.append(line)
        if line.lstrip().startswith("step 2:"):
            time.sleep(0.3)
            child.send_signal(signal.SIGINT)
            break
    lines += child.stderr.readlines()
    assert child.wait(timeout=120) == 130, "".join(lines)
    last = lines[-1]
    assert last.startswith("lpy-light: interrupted after ") and "of 30 derivation step(s)" in last, last
    assert str(out) in last and "partial" in last
    summary = json.loads((out / "summary.json").read_text())
    lit = len(summary["steps"])
    assert summary["partial"] is True and 3 <= lit < 30 and ("%d lit" % lit) in last
    assert (sorted({r["step"] for r in _rows(out / "organs.csv")}, key=int)
            == [str(s["step"]) for s in summary["steps"] if s["organs"]])       # the csv has every step lit


SWALLOWS_CTRL_C = """import os, signal

def swallow(n):
    if n == 2:                  # Ctrl-C at step 2, its KeyboardInterrupt lost as code out of our hands may lose it
        try:
            os.kill(os.getpid(), signal.SIGINT)
        except KeyboardInterrupt:
            pass

Axiom: A(0)
derivation length: 10
production:
A(n):
    swallow(n)
    produce F(1) Leaf A(n + 1)
interpretation:
Leaf --> @O(0.5)
endlsystem
"""


@pytest.mark.lpy
@lpy
def test_a_ctrl_c_whose_keyboardinterrupt_is_lost_still_stops_grow(tmp_path):
    """A Ctrl-C whose KeyboardInterrupt never reaches grow's loop (raised inside a rule that L-Py's C++ called,
    where it can be lost; here a rule swallows it) still ends the growth after the step it came in: exit 130 and
    the same last line as any Ctrl-C.  Before, such a grow ran to its end (a flaky failure of the Ctrl-C test
    on a fresh clone)."""
    model = tmp_path / "swallows.lpy"
    model.write_text(SWALLOWS_CTRL_C)
    p = _grow(model, "--organs", "Leaf=FeuilleVieille_Sup", "--at", "1280,860,980", "--photons", 2000,
              "--out", tmp_path / "out")
    last = p.stderr.strip().splitlines()[-1]
    assert p.returncode == 130, p.stderr
    assert last.startswith("lpy-light: interrupted after 3 of 10 derivation step(s)"), last


@pytest.mark.lpy
@lpy
def test_endeach_writes_parameters_the_next_step_reads():
    lstring, _ = _derive(ROSE, 5, PHOTONS=50_000, PRECISION=0)
    lights = [m.light for m in lstring if m.name in ("Leaf", "Bud")]
    assert lights and all(light is not None and light.par > 0 and light.par_std > 0 for light in lights)


@pytest.mark.lpy
@lpy
def test_buds_see_light_of_the_order_of_their_leaves():
    """The buds sit in the leaf axil on the stem's surface: their PAR (the mean over the bud's surface: a
    sphere gets 1/4 to 1/2 of a flat leaf facing the light) is a fair share of their neighbour leaves', not
    the 0.1-0.35 µmol m-2 s-1 of a bud drawn inside its internode (0.3 % of its leaf)."""
    lstring, _ = _derive(ROSE, 10, PHOTONS=300_000, PRECISION=0)
    leaves = [m.light.par for m in lstring if m.name == "Leaf"]
    buds = [m.light.par for m in lstring if m.name == "Bud"]
    assert len(buds) >= 3
    mean_leaf = sum(leaves) / len(leaves)
    assert all(0.08 * mean_leaf < par < 2 * mean_leaf for par in buds), (buds, mean_leaf)


@pytest.mark.lpy
@lpy
def test_light_drives_branching():
    """The coupling: under the chamber's lamps some buds burst; with PAR_MIN out of reach none does; dimmer lamps
    and a far-red supplement (lower R:FR, same lamps) give fewer bursts."""
    kw = dict(PHOTONS=100_000, PRECISION=0)
    lit, _ = _derive(ROSE, 16, **kw)
    assert _bursts(lit) >= 3
    assert _bursts(_derive(ROSE, 16, PAR_MIN=1e6, **kw)[0]) == 0
    assert _bursts(_derive(ROSE, 16, LAMP_SCALE=0.5, **kw)[0]) < _bursts(lit)
    assert _bursts(_derive(ROSE, 16, FAR_RED_SCALE=2.0, **kw)[0]) < _bursts(lit)


@pytest.mark.lpy
@lpy
def test_the_viewer_shows_each_organs_par():
    """The interpretation rules colour every leaf and bud by its PAR on a fixed scale (what Animate shows in the
    L-Py viewer), internodes grey-brown (their light is not estimated)."""
    from lpy_light.plant.plant_view import UNKNOWN, par_colour
    lstring, lsys = _derive(ROSE, 6, PHOTONS=50_000, PRECISION=0)
    scene = lsys.sceneInterpretation(lstring)
    seen = {}
    for shape in scene:
        module = lstring[shape.id]
        c = shape.appearance.ambient
        if module.name in ("Leaf", "Bud"):
            assert (c.red, c.green, c.blue) == par_colour(module.light, 120.0)
            seen[(c.red, c.green, c.blue)] = module.name
        elif module.name == "Internode":
            assert (c.red, c.green, c.blue) == UNKNOWN
    assert len(seen) >= 3                      # organs in different light, different colours


@pytest.mark.lpy
@lpy
@pytest.mark.parametrize("estimator, name", [("reuse", "store"), ("field", "field")])
def test_grow_with_the_chamber_stored_once_says_which_store_lit_each_step(tmp_path, estimator, name):
    """``grow --estimator reuse`` (a store of the chamber's light) and ``--estimator field`` (the light entering the
    plant's region) on the report's rose lit from outside (its Sweep leaves, internodes, flowers): every leaf read
    gets its light with a σ below its value, ``summary.json`` names the estimator, its settings and each step's
    store (and why it was built), and a store serves several steps.  Each field is checked against ``nee`` as it
    is traced (``field_checks``); where it fails (this rose's buds cut into their stems: their R:FR), its steps are
    lit by ``nee`` at ``--photons`` and say so (``lit_by``)."""
    p = _grow(SEED_ROSE, *SEED_ORGANS, "--at", "1280,860,980", "--targets", "Leaf,Bud", "--steps", 12,
              "--estimator", estimator, "--photons", 100_000, "--out", tmp_path)
    assert p.returncode == 0, p.stderr
    rows = _rows(tmp_path / "organs.csv")
    leaves = [r for r in rows if r["module"] == "Leaf" and r["step"] == "11"]
    assert leaves and all(float(r["par"]) > 0 and 0 < float(r["par_std"]) < float(r["par"]) for r in leaves)
    summary = json.loads((tmp_path / "summary.json").read_text())
    assert summary["estimator"] == estimator and summary[estimator]["renew"] == 10
    stores = [s["store"][name] for s in summary["steps"] if "store" in s]
    assert len(stores) == 12 and 1 <= summary["stores_built"] == len(set(stores)) < 12
    assert summary["steps"][0]["store"]["why"] == "first step"
    if estimator == "field":
        checks = summary["field_checks"]
        assert len(checks) == summary["stores_built"] and "passed" in checks[0]
        assert summary["steps"][0]["field_check"] == checks[0]
        lit = [s["lit_by"].split()[0] for s in summary["steps"]]
        assert lit[0] == ("field" if checks[0]["passed"] else "nee") and set(lit) <= {"field", "nee"}


@pytest.mark.lpy
@lpy
def test_grow_verify_compares_the_first_steps_with_nee(tmp_path):
    """``grow --verify 2`` on rose-simple4-light.lpy: its first two lit steps also lit by an independent ``nee`` run,
    every leaf and bud compared in verify.csv, the totals in summary.json's ``verify`` and on one line of stderr."""
    p = _grow(SEED_ROSE_LIT, "--steps", 3, "--photons", 100_000, "--verify", 2, "--out", tmp_path)
    assert p.returncode == 0, p.stderr
    rows = list(csv.DictReader(open(tmp_path / "verify.csv")))
    assert {r["step"] for r in rows} == {"0", "1"} and {r["kind"] for r in rows} == {"leaves", "buds"}
    summary = json.loads((tmp_path / "summary.json").read_text())
    v = summary["verify"]
    assert v["steps"] == 2 and v["nee_photons"] == 100_000 and v["estimator"] == "nee"
    assert v["leaves"]["par"]["sigma"] > 0 and v["buds"]["organs"] > 0 and v["all"]["within"] > 0.8
    assert "verify" in summary["steps"][1] and "verify" not in summary["steps"][2]
    assert sum(line.startswith("lpy-light: verify: nee against nee") for line in p.stderr.splitlines()) == 1


@pytest.mark.lpy
@lpy
def test_a_model_that_does_not_call_us_lit_from_outside(tmp_path):
    """The report's rose-simple4.lpy, unchanged (positional parameters, Sweep leaves, an EndEach of its own):
    ``grow --organs ... --at`` lights steps N, 2N, ... and the last, without a line of lpy-light in the model."""
    p = _grow(SEED_ROSE, *SEED_ORGANS, "--at", "1280,860,980", "--targets", "Leaf,Bud", "--steps", 5, "--every", 3,
              "--photons", 100_000, "--out", tmp_path)
    assert p.returncode == 0, p.stderr
    rows = _rows(tmp_path / "organs.csv")
    assert sorted({int(r["step"]) for r in rows}) == [2, 4]
    leaves = [r for r in rows if r["module"] == "Leaf"]
    assert len(leaves) == 9 * 2 and all(float(r["par"]) >= 0 for r in leaves)
    assert sum(float(r["par"]) > 20 for r in leaves) >= 2 * 7      # the youngest leaves hide in the flower bud
    assert {r["role"] for r in rows if r["module"] in ("Internode", "Flower")} == {"shading only"}
    summary = json.loads((tmp_path / "summary.json").read_text())
    assert summary["lit_from_outside"] and summary["position"] == [1280.0, 860.0, 980.0]
    assert [w["count"] for w in summary["warnings"] if "degenerate" in w["kind"]][0] > 1   # Sweep leaves' tips
    assert sum("degenerate" in line for line in p.stderr.splitlines()) == 2            # once, then its count


@pytest.mark.lpy
@lpy
def test_light_added_by_hand_written_by_position():
    """rose-simple4-light.lpy: ``parameter={"Leaf": 3, "Bud": 2}`` writes each organ's light into a positional
    parameter (as L-Py's own light example does, ``lstring[k][2] = v``); the sugar supply reads the leaves'
    absorbed PAR."""
    from openalea.lpy import Lsystem
    lsys = Lsystem(str(SEED_ROSE_LIT), {"PHOTONS": 50_000})
    lstring = lsys.derive(lsys.axiom, 0, 3)
    leaves = [m for m in lstring if m.name == "Leaf"]
    buds = [m for m in lstring if m.name == "Bud"]
    assert leaves and buds
    lit = [m for m in leaves if m[3] is not None]       # None: a leaf no sample reached (inside the flower bud)
    assert len(lit) >= len(leaves) - 2
    assert all(m[3].module == "Leaf" and m[3].par >= 0 and m[3].absorbed_par >= 0 for m in lit)
    assert sum(m[3].par > 20 for m in lit) >= 7                # the youngest leaves hide in the flower bud
    assert all(m[2].module == "Bud" and m[2].par > 0 for m in buds)
    assert lsys.context()["ABSORBED_PAR"] == pytest.approx(sum(m[3].absorbed_par for m in lit))
