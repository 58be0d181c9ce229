"""The L-Py IDE alive through a lit step: :func:`live`.

With its default settings the L-Py IDE runs a model in its GUI thread: a lit step (seconds; the light model's set-up
and the kernel's first compile, more) would hold the window frozen until the Run ends.  When lpy-light is called on
the thread of a running Qt application, :func:`live` returns a :class:`Live`: the heavy work (reading the chamber,
the lamps' normalisation run, the kernel's compile, the tracing) runs in a worker thread while the calling thread
turns the GUI's event loop every :data:`PUMP_EVERY` s, shows what the step is doing in the IDE's status bar
("L-Py step 3/7 · lpy-light: tracing 40 % of 200,000 photons · 2 s") and watches L-Py's Stop.  With the IDE's "use
thread" option the step already runs outside the GUI thread: :func:`live` then only watches Stop and posts the
status bar's text to the GUI thread (Qt's queued calls).

Stop (L-Py's Stop button sets the running L-system's ``early_return``; while the model loads, it releases the IDE's
run instead) ends the wait at once: the step's light is not written (the organs keep what they held), the
worker is told to stop after its chunk of photons and left to finish alone (the next step of the same light model
waits for it), and L-Py ends the run after this step.  While the model loads, Stop raises :class:`Stopped` (the
IDE shows it as the model's error).

Anywhere else -- no Qt application, or not its thread and no IDE (``lpy-light grow``, scripts, notebooks, tests) --
:func:`live` returns None and nothing changes: the same calls, the same numbers.  ``LPY_LIGHT_GUI=off`` in the
environment does the same inside the IDE.  Qt is never imported here: only a binding already imported
(``sys.modules``) is used.
"""
from __future__ import annotations

import contextlib
import gc
import importlib
import os
import sys
import threading
import time

from ..errors import LpyLightError

#: the Qt bindings looked for in ``sys.modules`` (the L-Py IDE's: PyQt5 through PlantGL's ``gui.qt``)
BINDINGS = ("PyQt5", "PyQt6", "PySide6", "PySide2")
#: seconds between two turns of the GUI's event loop while a step works (a repaint, a click, Stop)
PUMP_EVERY = 0.03
#: seconds between two updates of the status bar
STATUS_EVERY = 0.2
#: the environment variable that turns this off (``off``, ``0``, ``no``): plain calls inside the IDE too
ENV = "LPY_LIGHT_GUI"

_here = threading.local()            # the Live in force in this thread (a nested call runs plainly)


class Stopped(LpyLightError):
    """The modeller pressed Stop in the L-Py IDE while lpy-light was working."""


def _binding():
    """``(QtCore module, QCoreApplication)`` of an imported binding with a running application, else (None, None)."""
    for name in BINDINGS:
        core = sys.modules.get(name + ".QtCore")
        if core is None:
            continue
        try:
            app = core.QCoreApplication.instance()
        except Exception:        # noqa: BLE001  (a binding half torn down at exit)
            continue
        if app is not None:
            return core, app
    return None, None


def _ide_window(app=None):
    """The L-Py IDE's main window (``LPyWindow``), or None: its own list of instances where its module is imported,
    else (on the GUI thread only: ``app``) a top-level widget that looks like it."""
    studio = sys.modules.get("openalea.lpy.gui.lpystudio")
    window_class = getattr(studio, "LPyWindow", None)
    for ref in getattr(window_class, "instances", ()):
        window = ref()
        if window is not None:
            return window
    if app is not None and hasattr(app, "topLevelWidgets"):
        for widget in app.topLevelWidgets():
            if all(hasattr(widget, a) for a in ("statusBar", "isRunning", "currentSimulation")):
                return widget
    return None


def _lsystem():
    """``(the running L-system, its context)`` (L-Py's ``__lsystem__``), or (None, None)."""
    lpy = sys.modules.get("openalea.lpy")
    if lpy is None or not hasattr(lpy, "context"):
        return None, None
    try:
        ctx = lpy.context()
        return (ctx["__lsystem__"] if "__lsystem__" in ctx else None), ctx
    except Exception:            # noqa: BLE001  (no L-system running)
        return None, None


def step_label() -> str:
    """Which L-Py step runs: ``"L-Py step 3/7"`` (the iteration being ended, 1-based, of the derivation length), or
    ``"L-Py"`` where L-Py does not say."""
    lsystem, ctx = _lsystem()
    try:
        return "L-Py step %d/%d" % (ctx.getIterationNb() + 1, lsystem.derivationLength)
    except Exception:            # noqa: BLE001
        return "L-Py"


def live(label: str = "", doing: str = "") -> Live | None:
    """A :class:`Live` where lpy-light runs inside a Qt application's GUI thread (it pumps) or inside the L-Py IDE
    with "use thread" (it watches Stop); None anywhere else (and where ``LPY_LIGHT_GUI=off``), or when a Live is
    already in force in this thread.  ``label`` names the step in the status bar, ``doing`` what it starts with."""
    if os.environ.get(ENV, "").strip().lower() in ("off", "0", "no", "false"):
        return None
    if getattr(_here, "live", None) is not None:
        return None
    core, app = _binding()
    if core is None:
        return None
    try:
        pump = core.QThread.currentThread() == app.thread()
    except Exception:            # noqa: BLE001
        return None
    window = _ide_window(app if pump else None)
    if not pump and window is None:
        return None              # a Qt application elsewhere in the process (a viewer's thread): not ours
    lsystem, _ = _lsystem()
    return Live(core, pump, window, lsystem, label, doing)


def imported(name: str):
    """``importlib.import_module(name)``; in a worker with the GUI alive where :func:`live` (the light model's first
    import, when a model's ``from lpy_light import LightModel`` runs, loads numba and the kernel: ~2 s)."""
    alive = live(doing="loading lpy-light") if name not in sys.modules else None
    if alive is None:
        return importlib.import_module(name)
    quick_extern()
    with alive, no_full_collection():
        return alive.call(importlib.import_module, name)


def _caller_frame():
    """L-Py's ``get_caller_frame``: the frame that called the function calling it (``extern``'s caller)."""
    return sys._getframe(2)


def quick_extern():
    """L-Py's ``extern()`` (``openalea.lpy.defaultparameters``) finds its caller with ``inspect.getouterframes``, which
    reads the source of every frame of the stack: ~27 ms a call in the IDE, so a model's few ``extern`` lines held the
    window ~0.1-0.3 s.  Its ``get_caller_frame`` is given the same frame by ``sys._getframe(2)`` (µs).  In the IDE
    only (:func:`imported`); anything else in L-Py is left as it is."""
    module = sys.modules.get("openalea.lpy.defaultparameters")
    if module is not None and getattr(module, "get_caller_frame", None) is not None:
        module.get_caller_frame = _caller_frame


@contextlib.contextmanager
def no_full_collection():
    """The interpreter's cyclic garbage collector off while the block runs, and the objects alive at its end moved
    to the permanent generation (:func:`gc.freeze`).  numba's import makes ~10⁵ long-lived objects: enough to start a
    full collection of the whole IDE's heap (0.1-0.6 s that holds every thread, the GUI's too).  Frozen, they are
    never scanned again (nor freed: an import's modules live as long as the process anyway)."""
    enabled = gc.isenabled()
    gc.disable()
    try:
        yield
    finally:
        gc.freeze()
        if enabled:
            gc.enable()


class Live:
    """A step (or the light model's set-up) run with the GUI alive: see the module's docstring.

    Used as a context manager (it is the Live in force in its thread); :meth:`call` runs a function in a worker
    thread and waits for it, :meth:`tick` turns the event loop from work done in the calling thread (reading the
    plant's shapes through PlantGL, which must stay there), :meth:`progress` makes a kernel run's progress callback,
    :meth:`stop_asked` is what the kernel's run checks between chunks.
    """

    def __init__(self, core, pump: bool, window, lsystem, label: str = "", doing: str = ""):
        self.core, self.pump, self.window, self.lsystem = core, pump, window, lsystem
        self.label, self.doing, self.detail = label, doing, ""
        self.worker = None                # the last worker started (:meth:`call`)
        self.stop = threading.Event()
        self.started = time.perf_counter()
        self.shown = None                 # the last text put in the status bar
        self._last_turn = self._last_status = -1.0
        self._bar = None
        self._running = False             # the IDE's run was on when this began (pump mode): its release is a Stop
        self._kill = getattr(window, "killsimudialog", None)       # L-Py's 'Kill Simulation' dialog, which Stop arms
        self._armed = getattr(self._kill, "condition", None)       # (a new condition: Stop pressed since)
        if window is not None:
            try:
                self._bar = window.statusBar()
                self._running = bool(pump and window.isRunning())
            except Exception:    # noqa: BLE001
                self._bar = None

    def __enter__(self):
        _here.live = self
        return self

    def __exit__(self, *exc):
        _here.live = None
        return False

    # -- asked from the worker ----------------------------------------------------------------------------------
    def stop_asked(self) -> bool:
        """True once Stop was seen (the kernel's run ends after its current chunk)."""
        return self.stop.is_set()

    def progress(self, user=None):
        """A progress callback for :func:`lpy_light.run.simulate.run` that tells the status bar, and calls ``user``
        (the light model's own ``progress``, with its ``note``) as before."""
        live = self

        def show(done, total, seconds):
            if show.estimating:
                live.detail = "tracing: %s photons (σ goal: first estimate to come)" % format(done, ",")
            else:
                live.detail = "tracing %d %% of %s photons" % (100.0 * done / max(total, 1), format(total, ","))
            if user is not None:
                if hasattr(user, "estimating"):
                    user.estimating = show.estimating
                user(done, total, seconds)

        def note(text):
            live.detail = text.rstrip(" .")
            if getattr(user, "note", None) is not None:
                user.note(text)

        show.note = note
        show.estimating = False
        return show

    # -- in the calling thread ----------------------------------------------------------------------------------
    def stopped(self) -> bool:
        """Whether Stop was pressed: the L-system's ``early_return`` (a step), the IDE's run released while this
        began inside it (the model loading), or :attr:`stop` already set."""
        if not self.stop.is_set():
            try:
                if self.lsystem is not None and self.lsystem.early_return:
                    self.stop.set()
                    self._spare_the_kill()
                elif self._running and not self.window.isRunning():
                    self.stop.set()
            except Exception:    # noqa: BLE001  (an L-system being cleared)
                pass
        return self.stop.is_set()

    def _spare_the_kill(self):
        """L-Py's Stop (``LPyWindow.cancelTask``) sets ``early_return`` and arms its 'Kill Simulation' dialog
        (``killsimulationdialog.py``): 0.1 s later, if the IDE's task still runs, the dialog opens, counts 5 s down
        and kills the task (``lsystem.forceRelease()``, ``clear()``).  The run ends by itself within that time here
        (this step at once, L-Py after it), but with default settings the dialog still opens, nested in the event
        loop that L-Py's own plot of the result turns (``plotScene``) before the task is released: the Run could not
        end before the count-down.  So, once the step has seen Stop, the dialog armed by that Stop is told the task
        has ended (its ``condition``); the next Stop arms it again."""
        kill = self._kill
        if kill is None or not hasattr(kill, "condition"):
            return
        end = time.perf_counter() + (0 if self.pump else 0.08)    # the IDE's thread: the GUI thread arms it now
        while kill.condition is self._armed and time.perf_counter() < end:
            time.sleep(0.002)
        if kill.condition is not self._armed:
            kill.condition = _task_ended


    def tick(self):
        """Between pieces of work done in the calling thread: turn the event loop if it is time, and raise
        :class:`Stopped` once Stop was pressed."""
        now = time.perf_counter()
        if now - self._last_turn >= PUMP_EVERY:
            self._turn(now)
        if self.stopped():
            raise Stopped("stopped in the L-Py IDE (%s)" % (self.doing or self.label or "lpy-light"))

    def call(self, fn, *args, **kwargs):
        """``fn(*args, **kwargs)`` in a worker thread, the event loop turning (or, off the GUI thread, Stop watched)
        until it ends; its value, or its exception raised here.  Stop raises :class:`Stopped` at once and leaves
        the worker (told to stop) to end alone: it is ``Live.worker``."""
        box = {}

        def work():
            try:
                box["value"] = fn(*args, **kwargs)
            except BaseException as exc:      # noqa: BLE001  (raised again in the calling thread)
                box["error"] = exc

        self.worker = worker = threading.Thread(target=work, name="lpy-light", daemon=True)
        worker.start()
        try:
            while worker.is_alive():
                self._turn(time.perf_counter())
                if self.stopped():
                    worker.join(PUMP_EVERY)          # it may be at its end
                    if worker.is_alive():
                        raise Stopped("stopped in the L-Py IDE (%s)" % (self.doing or self.label or "lpy-light"))
                    break
                worker.join(PUMP_EVERY)
        except KeyboardInterrupt:
            self.stop.set()                          # Ctrl-C in the terminal: the worker stops too
            raise
        if "error" in box:
            raise box["error"]
        return box["value"]

    def wait(self, worker):
        """Wait for a worker left running by an earlier Stop, the GUI alive (an error in it was its step's)."""
        while worker is not None and worker.is_alive():
            self._turn(time.perf_counter())
            worker.join(PUMP_EVERY)

    def show(self, doing: str | None = None):
        """Put ``label · lpy-light: doing · seconds`` in the status bar now."""
        if doing is not None:
            self.doing, self.detail = doing, ""
        self._status(time.perf_counter(), force=True)

    def _turn(self, now):
        if self.pump:
            self.core.QCoreApplication.processEvents()
        self._last_turn = now
        self._status(now)

    def _status(self, now, force=False):
        if self._bar is None or (not force and now - self._last_status < STATUS_EVERY):
            return
        self._last_status = now
        doing = ": ".join(t for t in (self.doing or "working", self.detail) if t)
        text = " · ".join(t for t in (self.label, "lpy-light: " + doing, "%.0f s" % (now - self.started)) if t)
        try:
            if self.pump:
                self._bar.showMessage(text)
            else:                  # the IDE's thread: Qt's widgets are the GUI thread's
                core = self.core
                core.QMetaObject.invokeMethod(self._bar, "showMessage", core.Qt.QueuedConnection,
                                              core.Q_ARG(str, text))
            self.shown = text
        except Exception:          # noqa: BLE001  (a window closing; a binding without Q_ARG)
            self._bar = None


def _task_ended() -> bool:
    """The condition given to L-Py's 'Kill Simulation' dialog once lpy-light has ended the step on Stop."""
    return False
