"""lpy-light inside a Qt GUI, the L-Py IDE's (:mod:`lpy_light.plant.ide`): while a step works the GUI's event loop
turns, the status bar names the step, Stop ends the step at once; outside a GUI nothing changes.

The plain tests stand a small stand-in for a Qt binding in ``sys.modules`` (what :mod:`~lpy_light.plant.ide` looks
for; it never imports Qt itself); the ``lpy`` test runs the real L-Py under the real PyQt5 (offscreen, in a child
process, so that no Qt application outlives it in this one).  The IDE itself, under Xvfb: ``scripts/ide_check.py``.
"""
import json
import os
import subprocess
import sys
import threading
import time
import types
import weakref

import numpy as np
import pytest

from lpy_light.plant import ide
from test_lpy import lpy
from test_organs import black_room, disc_mesh, square_mesh, _model  # noqa: F401  (fixture)

MESHES = {1: disc_mesh(30, z=500), 2: square_mesh(40.0, z=450)}


class FakeQt:
    """A Qt binding's ``QtCore`` as :mod:`lpy_light.plant.ide` uses it: an application whose thread is this
    process's main thread, ``processEvents`` (recorded: the pulses; ``on_pulse()`` called at each), queued calls
    (recorded: ``posted``)."""

    def __init__(self):
        self.pulses, self.posted = [], []
        self.on_pulse = None
        fake = self
        main = object()

        class App:
            def thread(self):
                return main

        app = App()

        class QCoreApplication:
            @staticmethod
            def instance():
                return app

            @staticmethod
            def processEvents():
                assert threading.current_thread() is threading.main_thread()
                fake.pulses.append(time.perf_counter())
                if fake.on_pulse is not None:
                    fake.on_pulse()

        class QThread:
            @staticmethod
            def currentThread():
                return main if threading.current_thread() is threading.main_thread() else object()

        class QMetaObject:
            @staticmethod
            def invokeMethod(obj, name, connection, arg):
                fake.posted.append((threading.current_thread() is threading.main_thread(), name, arg))

        self.QCoreApplication, self.QThread, self.QMetaObject = QCoreApplication, QThread, QMetaObject
        self.Qt = types.SimpleNamespace(QueuedConnection="queued")
        self.Q_ARG = lambda kind, value: value


class FakeLsystem:
    """What L-Py's context gives as ``__lsystem__``: Stop sets its ``early_return``."""
    early_return = False
    derivationLength = 5


class FakeContext(dict):
    def getIterationNb(self):
        return 2


@pytest.fixture
def gui(monkeypatch):
    """A Qt application in this thread (a stand-in binding), and an L-system running (a stand-in L-Py)."""
    monkeypatch.delenv(ide.ENV, raising=False)
    qt = FakeQt()
    for name in ide.BINDINGS:
        monkeypatch.delitem(sys.modules, name + ".QtCore", raising=False)
    monkeypatch.setitem(sys.modules, "PyQt5.QtCore", qt)
    qt.lsystem = FakeLsystem()
    context = FakeContext(__lsystem__=qt.lsystem)
    monkeypatch.setitem(sys.modules, "openalea.lpy", types.SimpleNamespace(context=lambda: context))
    monkeypatch.delitem(sys.modules, "openalea.lpy.gui.lpystudio", raising=False)
    return qt


def _same(a: dict, b: dict) -> bool:
    """Two steps' organ lights, bit for bit."""
    if a.keys() != b.keys():
        return False
    for k in a:
        if (a[k] is None) != (b[k] is None):
            return False
        if a[k] is not None and not all(np.array_equal(getattr(a[k], f), getattr(b[k], f), equal_nan=True)
                                        for f in ("ppfd", "ppfd_std", "absorbed", "absorbed_std")):
            return False
    return True


def test_outside_a_gui_nothing_changes(monkeypatch):
    """No Qt binding imported, no application, not its thread and no IDE, or LPY_LIGHT_GUI=off: plain calls."""
    monkeypatch.delenv(ide.ENV, raising=False)
    for name in ide.BINDINGS:
        monkeypatch.delitem(sys.modules, name + ".QtCore", raising=False)
    assert ide.live() is None                                   # no binding
    qt = FakeQt()
    monkeypatch.setitem(sys.modules, "PyQt5.QtCore", qt)
    assert ide.live() is not None                               # its application's thread
    got = []
    t = threading.Thread(target=lambda: got.append(ide.live()))
    t.start()
    t.join()
    assert got == [None]                                        # another thread, and no L-Py IDE
    monkeypatch.setenv(ide.ENV, "off")
    assert ide.live() is None
    monkeypatch.delenv(ide.ENV)
    qt.QCoreApplication.instance = staticmethod(lambda: None)
    assert ide.live() is None                                   # no application


def test_the_first_import_runs_no_full_collection():
    """While the IDE's first import runs (numba's ~10⁵ objects) the cyclic collector is off, and what it made is
    frozen: no full collection of the IDE's heap holds the GUI afterwards.  The collector is on again after, as it was
    before."""
    import gc
    assert gc.isenabled()
    frozen = gc.get_freeze_count()
    seen = []
    with ide.no_full_collection():
        seen.append(gc.isenabled())
        junk = [[i] for i in range(50_000)]
    assert seen == [False] and gc.isenabled()
    assert gc.get_freeze_count() >= frozen + 50_000
    del junk
    gc.unfreeze()                         # give this test process its collector back as it was


@lpy
def test_extern_sets_its_callers_names_with_the_quick_frame(monkeypatch):
    """L-Py's ``extern()`` with :func:`ide.quick_extern` sets the defaults in its caller's namespace, as L-Py's own
    ``get_caller_frame`` does, at any depth of the stack; ``extern('NAME')`` still checks the name."""
    import importlib
    dp = importlib.import_module("openalea.lpy.defaultparameters")     # (the package names a function so)
    monkeypatch.setattr(dp, "get_caller_frame", dp.get_caller_frame)       # restored after the test
    ns = {"extern": dp.extern}
    code = "extern(a=1, b=2)\nextern(a=5)\nextern('b')\n"
    exec(code, ns)
    ide.quick_extern()
    assert dp.get_caller_frame is ide._caller_frame
    fast = {"extern": dp.extern, "a": 7}
    exec(code, fast)
    assert (ns["a"], ns["b"], ns["__externs__"]) == (1, 2, {"a", "b"})
    assert (fast["a"], fast["b"], fast["__externs__"]) == (7, 2, {"a", "b"})

    def nested():
        local_ns = {"extern": dp.extern}
        exec("extern(c=3)", local_ns)
        return local_ns["c"]
    assert nested() == 3
    with pytest.raises(NameError):
        exec("extern('missing')", {"extern": dp.extern})


def test_a_step_turns_the_gui_loop_and_gives_the_same_numbers(gui, black_room, monkeypatch):  # noqa: F811
    """In the GUI thread, ``LightModel(...)`` and a step run in a worker while the event loop turns every few
    hundredths of a second; the organs' light is the plain call's, bit for bit."""
    monkeypatch.setenv(ide.ENV, "off")
    plain = _model(black_room, photons=400_000, threads=2).intercept(MESHES)
    monkeypatch.delenv(ide.ENV)
    model = _model(black_room, photons=400_000, threads=2)
    first = len(gui.pulses)
    t0 = time.perf_counter()
    got = model.intercept(MESHES)
    t1 = time.perf_counter()
    assert _same(plain, got) and got[1] is not None
    pulses = [t0] + gui.pulses[first:] + [t1]
    assert len(pulses) > 5 and max(np.diff(pulses)) < 0.5, np.diff(pulses)     # 0.03 s asked; a busy machine
    assert model.step == 1 and model._pending is None


def test_stop_ends_the_step_at_once_and_the_next_step_waits_for_its_worker(gui, black_room):  # noqa: F811
    """L-Py's Stop (the L-system's ``early_return``) ends a step within a second: for meshes, ``Stopped`` is raised
    (for an lstring the step returns with its organs' light not written); nothing of the step is kept, and the
    next step waits for the worker left stopping, then lights as usual."""
    model = _model(black_room, photons=50_000_000, threads=2)
    stopped = {}

    def press_stop():
        if "at" not in stopped and len(gui.pulses) > 10:
            stopped["at"] = time.perf_counter()
            gui.lsystem.early_return = True
    gui.on_pulse = press_stop
    with pytest.raises(ide.Stopped):
        model.intercept(MESHES)
    assert time.perf_counter() - stopped["at"] < 1.0
    assert model.step == 0
    gui.lsystem.early_return = False
    gui.on_pulse = None
    model.photons = 100_000
    got = model.intercept(MESHES)
    assert got[1] is not None and model.step == 1 and model._pending is None


def test_with_use_thread_the_status_goes_to_the_gui_thread(gui, black_room, monkeypatch):  # noqa: F811
    """L-Py's "use thread": the step runs in the IDE's thread, not the GUI's; its progress is posted to the IDE's
    status bar through Qt's queued calls, never set from that thread, and Stop still ends it."""
    class Window:
        def statusBar(self):
            return "the status bar"

        def isRunning(self):
            return True
    window = Window()
    monkeypatch.setitem(sys.modules, "openalea.lpy.gui.lpystudio",
                        types.SimpleNamespace(LPyWindow=types.SimpleNamespace(instances=[weakref.ref(window)])))
    model = _model(black_room, photons=50_000_000, threads=2)     # here, in the GUI thread
    pulses = len(gui.pulses)
    out = {}

    def run():
        try:
            out["value"] = model.intercept(MESHES)
        except BaseException as exc:          # noqa: BLE001
            out["error"] = exc
    t = threading.Thread(target=run)
    t.start()
    time.sleep(1.5)
    gui.lsystem.early_return = True
    pressed = time.perf_counter()
    t.join(10)
    assert not t.is_alive() and time.perf_counter() - pressed < 1.0
    assert isinstance(out.get("error"), ide.Stopped)
    texts = [arg for main, name, arg in gui.posted if name == "showMessage"]
    assert texts and not any(main for main, *_ in gui.posted)
    assert any(t.startswith("L-Py step 3/5 · lpy-light: lighting 2 organs") for t in texts), texts
    assert len(gui.pulses) == pulses                  # the IDE's thread never turns the GUI's loop


CHILD = r'''
import json, os, sys, time
from PyQt5.QtCore import QTimer
from PyQt5.QtWidgets import QApplication, QMainWindow
from openalea.lpy import Lsystem

app = QApplication([])


class Window(QMainWindow):          # what lpy-light looks for in the L-Py IDE's window
    running = False

    def isRunning(self):
        return self.running

    def currentSimulation(self):
        return None


win = Window()
beats = []


def beat():
    beats.append((time.perf_counter(), win.statusBar().currentMessage()))
    if stop_after is not None and len(beats) - first > stop_after and "at" not in stop:
        stop["at"] = time.perf_counter()
        lsys.early_return = True             # what the IDE's Stop does


pulse = QTimer()
pulse.timeout.connect(beat)
pulse.start(50)
out = {}
for photons, stop_after in ((300_000, None), (50_000_000, 40)):
    stop = {}
    first = 10 ** 9
    lsys = Lsystem(sys.argv[1], {"SCENE": sys.argv[2], "PHOTONS": photons, "STEPS": 3})
    first = len(beats)
    win.running = True
    t0 = time.perf_counter()
    lstring = lsys.derive()
    t1 = time.perf_counter()
    win.running = False
    times = [t0] + [t for t, _ in beats[first:]] + [t1]
    out[str(photons)] = {"gap": max(b - a for a, b in zip(times, times[1:])),
                         "iterations": lsys.getLastIterationNb() + 1,
                         "status": sorted({x for _, x in beats[first:] if x}),
                         "stop": t1 - stop["at"] if stop else None,
                         "light": [None if m[1] is None else list(m[1].ppfd) for m in lstring if m.name == "Leaf"]}
print(json.dumps(out))
'''

MODEL = '''from lpy_light import LightModel
extern(SCENE="")
extern(PHOTONS=100000)
extern(STEPS=3)
light = LightModel(SCENE, organs={"Leaf": ({"reflectance": 0.0}, {"reflectance": 0.5})}, lamp_flux=100.0,
                   plant_unit="mm", position=(500, 500, 0), photons=PHOTONS, threads=2)
module Leaf(size, light)


def StartEach():
    frameDisplay(True)


def EndEach(lstring, lscene):
    return light.intercept(lstring, lscene)


Axiom: @M(0, 0, 450) Leaf(40, None)
derivation length: STEPS
production:
Leaf(s, l) --> Leaf(s, l)
interpretation:
Leaf(s, l) --> @O(s)
endlsystem
'''


@pytest.mark.lpy
@lpy
def test_the_real_lpy_under_pyqt_steps_alive_and_stops(tmp_path, black_room):  # noqa: F811
    """A lit L-system derived in the thread of a PyQt5 application (offscreen), as the L-Py IDE runs a model with
    its default settings: the GUI's 50 ms timer fires all along the steps (the gap measured includes L-Py's own
    work, here small), the status bar names each step, and L-Py's Stop (``early_return``) ends the run within a
    second, in its first step, whose light is not written; the light of a whole run is the plain run's."""
    pytest.importorskip("PyQt5.QtWidgets")
    model = tmp_path / "lit.lpy"
    model.write_text(MODEL, encoding="utf-8")
    env = dict(os.environ, QT_QPA_PLATFORM="offscreen")
    env.pop(ide.ENV, None)
    p = subprocess.run([sys.executable, "-c", CHILD, str(model), str(black_room)], capture_output=True,
                       encoding="utf-8", env=env, timeout=600)
    assert p.returncode == 0, p.stderr[-3000:]
    got = json.loads(p.stdout.strip().splitlines()[-1])
    run, stopped = got["300000"], got["50000000"]
    assert run["iterations"] == 3 and run["gap"] < 0.5, run             # 0.03 s asked; a busy machine
    assert {"L-Py step %d/3" % k for k in (1, 2, 3)} <= {s.split(" · ")[0] for s in run["status"]}, run["status"]
    assert stopped["iterations"] == 1 and stopped["stop"] < 1.0 and stopped["light"] == [None], stopped
    from openalea.lpy import Lsystem
    plain = Lsystem(str(model), {"SCENE": str(black_room), "PHOTONS": 300_000, "STEPS": 3}).derive()
    assert run["light"] == [list(m[1].ppfd) for m in plain if m.name == "Leaf"]
