"""The L-Py IDE as a modeller uses it, with lpy-light inside: a lit Run must leave the window alive, Stop must end
it, and a model edited and saved with Ctrl+S must be whole on disk.

Needs the bundle with the IDE (``bash ../shared/lpy/install.sh --ide .venv-lpy``) and a display::

    LANG=C.UTF-8 xvfb-run -a .venv-lpy/bin/python scripts/ide_check.py --out /tmp/ide

It drives the IDE's own window (``openalea.lpy.gui.lpystudio.LPyWindow``): its Run, Step and Stop actions (what the
toolbar buttons trigger), its ``openfile`` (File > Open once a name is chosen), typing into its code editor and
Ctrl+S as key events.  A 50 ms QTimer of the GUI thread (the pulse) records when it fires and what the status bar
says; the gaps between two pulses are when the window could neither repaint nor answer.

1. **Run, default settings** (the model runs in the GUI thread): the report's rose lit at every step
   (``lsystems/rose-simple4-light.lpy``, ``--run-steps`` steps of ``--photons`` photons), the first Run of the
   session (lpy-light's first import in it).  Reports the longest gap between two pulses in each part of the Run:
   the lit steps (``intercept``) and ``LightModel(...)`` (at most ``GAP_LIMIT`` s wanted), lpy-light's first import
   (numba's: the interpreter may run a full garbage collection in it, which no thread can interrupt; reported, not
   judged), and L-Py's own work (parsing the model, its ``extern()`` calls, its rules, the plot of the result:
   reported, not lpy-light's to shorten); and whether the status bar named every step ("L-Py step k/N").
2. **Stop, default settings**: the same Run, Stop pressed while step 2 traces: the Run must end within
   ``STOP_LIMIT`` s of it, before its last step, without L-Py's 'Kill Simulation' dialog, and the model file be
   byte for byte what it was.
3. and 4. The same two with L-Py's "use thread" option on (the model runs in a thread of the IDE).
5. **Open, Step, edit, save** (issue 47: after a lit step PlantGL had left the process in the C locale, the IDE read
   and wrote files as ASCII, and a model holding µ was saved as 0 bytes): another model opened, Stepped twice,
   edited, Ctrl+S: the file on disk must be whole and the locale the one before.

A dialog the IDE opens (an error) is recorded, pictured (the first: ``dialog.png``) and closed.  Prints what it saw,
writes ``ide.json`` (the figures) and ``ide.png`` (the window after the save); exit status 0 when every check
passed.  Timings are wall-clock on a machine that may be busy: the gaps are what a modeller would see there.
``LPY_LIGHT_GUI=off`` in the environment shows the IDE as it was before lpy-light kept it alive.

The edit is Latin-1 text (µ, ±): the IDE itself takes the editor's text through Latin-1 when it saves
(``lpycodeeditor.getCode``), so a σ or → typed there becomes '?' whatever the locale -- L-Py's, not ours; the
models in ``lsystems/`` hold no character outside it (``tests/test_lpy.py``).
"""
from __future__ import annotations

import argparse
import functools
import gc
import json
import locale
import os
import re
import shutil
import sys
import time
from pathlib import Path

ROOT = Path(__file__).resolve().parent.parent
print = functools.partial(print, file=sys.__stdout__, flush=True)    # noqa: A001  (the IDE takes sys.stdout for its shell)


def small(src: Path, dst: Path, derivation: int | None = None, **externs) -> Path:
    """A copy of ``src`` with some ``extern(NAME = value)`` defaults changed, and its ``derivation length`` where
    given (a quick Run)."""
    lines = []
    for line in src.read_text(encoding="utf-8").splitlines(keepends=True):
        head = line.replace(" ", "")
        for name, value in externs.items():
            if head.startswith("extern(%s=" % name):
                line = "extern(%s=%r)\n" % (name, value)
        if derivation is not None and head.startswith("derivationlength:"):
            line = "derivation length: %d\n" % derivation
        lines.append(line)
    dst.write_text("".join(lines), encoding="utf-8")
    return dst


GAP_LIMIT = 0.25      # s: the longest the window may go without turning its event loop while lpy-light works
STOP_LIMIT = 1.0      # s: from Stop to the Run's end
STEP_SHOWN = re.compile(r"L-Py step (\d+)/(\d+)")


def watch_lpy_light(spans: list):
    """Record in ``spans`` when lpy-light works in the model's thread: its first import (from the model's
    ``from lpy_light import LightModel``), each ``LightModel(...)`` and each ``intercept``: ``(start, end, what)``.
    The rest of a Run is L-Py's own (parsing the model, ``extern()``, rules, the plot of the result)."""
    from lpy_light.plant import ide          # light: no numba

    def timed(fn, what):
        @functools.wraps(fn)
        def wrapper(*args, **kwargs):
            t0 = time.perf_counter()
            try:
                return fn(*args, **kwargs)
            finally:
                spans.append((t0, time.perf_counter(), what))
        return wrapper

    real = ide.imported

    def imported(name):
        fresh = name not in sys.modules
        module = timed(real, "import")(name)
        if fresh and name == "lpy_light.plant.light":
            cls = module.LightModel
            cls.__init__ = timed(cls.__init__, "LightModel()")
            cls.intercept = timed(cls.intercept, "intercept")
        return module
    ide.imported = imported


def split_gaps(times: list, spans: list) -> dict:
    """The longest stretch without a pulse in each kind of lpy-light's spans (``import``, ``LightModel()``,
    ``intercept``) and outside them (``L-Py``: L-Py's own work), each gap between two pulses cut at the spans' ends:
    ``{kind: (seconds, where)}``, where as ``"3.21 s into a 4.02 s intercept"``."""
    out = {kind: (0.0, "") for kind in ("import", "LightModel()", "intercept", "L-Py")}
    for a, b in zip(times, times[1:]):
        rest = b - a
        for s, e, w in spans:
            cut = max(0.0, min(b, e) - max(a, s))
            rest -= cut
            if cut > out[w][0]:
                out[w] = (cut, "%.2f s into a %.2f s %s" % (max(a, s) - s, e - s, w))
        if rest > out["L-Py"][0]:
            out["L-Py"] = (rest, "%.2f s after the Run's start" % (a - times[0]))
    return out


def main() -> int:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--out", default="ide-check", help="folder for the models' copies, ide.json and the screenshot")
    ap.add_argument("--run-steps", type=int, default=7, help="lit steps of the rose that is Run")
    ap.add_argument("--photons", type=int, default=200_000, help="photons per lit step of the Run")
    ap.add_argument("--no-thread", action="store_true", help="leave out the Runs with L-Py's 'use thread' on")
    args = ap.parse_args()
    out = Path(args.out).resolve()
    out.mkdir(parents=True, exist_ok=True)
    run_model = small(ROOT / "lsystems" / "rose-simple4-light.lpy", out / "rose-lit.lpy", derivation=args.run_steps,
                      PHOTONS=args.photons)
    edited = out / "rose-simple4-light.lpy"
    shutil.copy(ROOT / "lsystems" / "rose-simple4-light.lpy", edited)
    original = edited.read_text(encoding="utf-8")

    from PyQt5.QtCore import Qt, QTimer
    from PyQt5.QtTest import QTest
    from PyQt5.QtWidgets import QApplication
    qapp = QApplication(sys.argv + ["-qwindowtitle", "L-Py"])
    from openalea.lpy.gui.lpystudio import LPyWindow
    before = locale.setlocale(locale.LC_ALL)
    print("locale before: %s (text files: %s)" % (before, locale.getpreferredencoding(False)))
    print("machine: %d cores, load average %s (timings are wall-clock: a busy machine shows in them)"
          % (os.cpu_count(), " ".join("%.2f" % x for x in os.getloadavg())))
    dialogs = []

    def close_dialogs():
        w = qapp.activeModalWidget()
        if w is not None:
            if not dialogs:
                w.grab().save(str(out / "dialog.png"))
            dialogs.append("%s %r: %s" % (type(w).__name__, w.windowTitle(), getattr(w, "text", lambda: "")()))
            w.close()
            if len(dialogs) >= 20:            # the IDE reopens it: it will not get past this
                print("dialogs: 20 x %s\nIDE check: FAILED" % dialogs[0])
                os._exit(1)
    timer = QTimer()
    timer.timeout.connect(close_dialogs)
    timer.start(500)

    spans = []
    watch_lpy_light(spans)
    collections = []            # the interpreter's full garbage collections (whichever thread runs one holds the GIL)

    def on_gc(phase, info, started=[0.0]):
        if info["generation"] == 2:
            if phase == "start":
                started[0] = time.perf_counter()
            else:
                collections.append((started[0], time.perf_counter()))
    gc.callbacks.append(on_gc)
    win = LPyWindow()
    win.show()

    # the GUI loop's pulse: a 50 ms timer of the GUI thread, when it fired and what the status bar said
    beats = []                  # (time, status bar text)
    stop_at = {}                # the Stop test: {"step": k} to press Stop while step k traces; "time" once pressed

    def beat():
        now = time.perf_counter()
        text = win.statusBar().currentMessage()
        beats.append((now, text))
        m = STEP_SHOWN.search(text)
        if ("step" in stop_at and "time" not in stop_at and m and int(m.group(1)) == stop_at["step"]
                and "tracing" in text):
            stop_at["time"] = time.perf_counter()
            stop_at["shown"] = text
            win.actionStop.trigger()          # the toolbar's Stop
    pulse = QTimer()
    pulse.timeout.connect(beat)
    pulse.start(50)

    def settle(seconds=0.5):
        end = time.time() + seconds
        while time.time() < end:
            qapp.processEvents()
            time.sleep(0.02)

    def wait_task(what, limit=900):
        t0 = time.time()
        settle(0.5)
        while win.isRunning() and time.time() - t0 < limit:
            settle(0.2)
        settle(0.5)
        print("%s: %.1f s; locale %s" % (what, time.time() - t0, locale.setlocale(locale.LC_ALL)))

    def lit_run(threaded: bool, stop_step: int | None = None) -> dict:
        """Run ``run_model`` (L-Py's 'use thread' as ``threaded``), Stop pressed while step ``stop_step`` traces
        where given; what the GUI's pulse saw."""
        win.with_thread = threaded
        win.openfile(str(run_model))
        settle()
        data = run_model.read_bytes()
        stat = run_model.stat()
        n_dialogs = len(dialogs)
        stop_at.clear()
        if stop_step is not None:
            stop_at["step"] = stop_step
        first = len(beats)
        t0 = time.perf_counter()
        win.actionRun.trigger()           # the toolbar's Run: with default settings it returns at the Run's end
        while win.isRunning() and time.perf_counter() - t0 < 900:
            qapp.processEvents()          # 'use thread': the GUI thread is the IDE's own, free
            time.sleep(0.01)
        t1 = time.perf_counter()
        settle(0.5)
        times = [t0] + [t for t, _ in beats[first:] if t <= t1] + [t1]
        texts = [""] + [x for t, x in beats[first:] if t <= t1] + [""]
        gaps = sorted(((times[i + 1] - times[i], times[i] - t0, texts[i], texts[i + 1])
                       for i in range(len(times) - 1)), reverse=True)
        ours = [(s, e, w) for s, e, w in spans if s >= t0 and e <= t1]
        full_gc = [e - s for s, e in collections if t0 <= s <= t1]
        split = split_gaps(times, ours)
        shown = sorted({int(m.group(1)) for _, x in beats[first:] for m in [STEP_SHOWN.search(x)] if m})
        simu = win.currentSimulation()
        row = {"settings": "use thread" if threaded else "default", "seconds": t1 - t0, "pulses": len(times) - 2,
               "longest_gap": gaps[0][0],
               "longest_gaps_by_kind": {k: {"seconds": g, "where": w} for k, (g, w) in split.items()},
               "longest_gap_in_lpy_light": max(split["LightModel()"][0], split["intercept"][0]),
               "lpy_light_seconds": sum(e - s for s, e, _ in ours),
               "full_collections": len(full_gc), "longest_full_collection": max(full_gc, default=0.0),
               "gaps": [{"seconds": g, "at": a, "status_before": x, "status_after": y} for g, a, x, y in gaps[:5]],
               "steps_shown": shown, "iterations": simu.nbiterations,
               "status_after": win.statusBar().currentMessage(), "dialogs": dialogs[n_dialogs:],
               "model_untouched": run_model.read_bytes() == data and run_model.stat().st_mtime == stat.st_mtime}
        if stop_step is not None:
            row["stop_pressed"] = "time" in stop_at
            row["stop_seconds"] = t1 - stop_at["time"] if "time" in stop_at else None
            row["stop_status"] = stop_at.get("shown")
        return row

    def report(row, stop=False) -> bool:
        what = "Run, %s settings" % row["settings"] if not stop else "Stop, %s settings" % row["settings"]
        gap = row["gaps"][0]
        by_kind = row["longest_gaps_by_kind"]
        print("%s (%s, %d lit steps of %d photons): %.1f s (lpy-light working %.1f s of it), %d GUI pulses; the "
              "longest gap between two: %.2f s (%.1f s in, status bar %r, then %r)"
              % (what, run_model.name, args.run_steps, args.photons, row["seconds"], row["lpy_light_seconds"],
                 row["pulses"], gap["seconds"], gap["at"], gap["status_before"], gap["status_after"]))
        for kind, label in (("intercept", "in the lit steps (intercept)"), ("LightModel()", "in LightModel(...)"),
                            ("import", "in lpy-light's first import"), ("L-Py", "in L-Py's own work")):
            if by_kind[kind]["where"]:
                print("  longest gap %s: %.2f s (%s)" % (label, by_kind[kind]["seconds"], by_kind[kind]["where"]))
        print("  full garbage collections of the interpreter during the Run: %d, the longest %.2f s"
              % (row["full_collections"], row["longest_full_collection"]))
        print("  steps named in the status bar: %s; iterations done: %d; status bar after: %r; model file untouched: "
              "%s; dialogs: %s" % (row["steps_shown"], row["iterations"], row["status_after"],
                                   row["model_untouched"], "; ".join(row["dialogs"]) or "none"))
        ok = row["model_untouched"] and not row["dialogs"] and row["longest_gap_in_lpy_light"] <= GAP_LIMIT
        if stop:
            print("  Stop pressed: %s (%r); the Run ended %s s after it"
                  % (row["stop_pressed"], row["stop_status"],
                     "%.2f" % row["stop_seconds"] if row["stop_seconds"] is not None else "?"))
            ok = (ok and row["stop_pressed"] and row["stop_seconds"] <= STOP_LIMIT
                  and row["iterations"] < args.run_steps)
        else:
            ok = (ok and row["steps_shown"] == list(range(1, args.run_steps + 1))
                  and row["iterations"] == args.run_steps)
        print("  -> %s" % ("OK" if ok else "FAILED"))
        return ok

    runs, verdicts = [], []
    for threaded in ([False] if args.no_thread else [False, True]):
        row = lit_run(threaded)
        verdicts.append(report(row))
        runs.append(row)
        row = lit_run(threaded, stop_step=2)
        verdicts.append(report(row, stop=True))
        runs.append(row)
    win.with_thread = False                       # the IDE's default again

    win.openfile(str(edited))                     # File > Open, the name chosen
    settle()
    shown = win.codeeditor.toPlainText()
    print("opened %s: %d characters in the editor, µ shown: %s" % (edited.name, len(shown), "µ" in shown))
    for i in range(2):
        t0 = time.time()
        win.actionStep.trigger()
        print("  (the Step action took %.1f s)" % (time.time() - t0))
        wait_task("Step %d" % (i + 1))
    added = "# edited in the IDE: PAR_MIN = 10 µmol m-2 s-1 ± 5 %"      # Latin-1: the IDE keeps no other (above)
    editor = win.codeeditor
    win.raise_()
    win.activateWindow()
    qapp.setActiveWindow(win)                 # the modeller clicks into the editor (the 3D viewer was active)
    editor.setFocus()
    editor.moveCursor(editor.textCursor().End)
    QTest.keyClick(editor, Qt.Key_Return)
    editor.insertPlainText(added)             # as typed (Qt's test keys are ASCII only: µ, σ, → go in as text)
    QTest.keyClick(editor, Qt.Key_Return)
    settle()
    simu = win.currentSimulation()
    print("before Ctrl+S: file %s, edited %s, read-only %s" % (simu.fname, simu.isEdited(), simu.readonly))
    QTest.keyClick(editor, Qt.Key_S, Qt.ControlModifier)      # Ctrl+S
    settle(1.0)
    win.grab().save(str(out / "ide.png"))
    after = locale.setlocale(locale.LC_ALL)
    data = edited.read_bytes()
    try:
        saved = data.decode("utf-8")
    except UnicodeDecodeError:
        saved = None
    whole = saved is not None and saved.startswith(original.rstrip("\n")[:-200]) and added in saved
    print("saved %s: %d bytes (was %d), UTF-8: %s, the edit in it: %s, the rest as it was: %s"
          % (edited.name, len(data), len(original.encode("utf-8")), saved is not None,
             saved is not None and added in saved, whole))
    print("locale after: %s (text files: %s)" % (after, locale.getpreferredencoding(False)))
    print("dialogs: %s" % ("; ".join(dialogs) if dialogs else "none"))
    print("screenshot: %s" % (out / "ide.png"))
    saved_ok = whole and after == before
    ok = saved_ok and all(verdicts) and not dialogs
    (out / "ide.json").write_text(json.dumps({"runs": runs, "saved_whole": whole, "locale_kept": after == before,
                                              "dialogs": dialogs, "ok": ok, "gap_limit": GAP_LIMIT,
                                              "stop_limit": STOP_LIMIT, "cores": os.cpu_count(),
                                              "load_average": os.getloadavg()}, indent=1), encoding="utf-8")
    print("IDE check: %s" % ("OK" if ok else "FAILED"))
    win.close()
    settle()
    os._exit(0 if ok else 1)      # the IDE's threads and atexit hooks are not ours to wait for


if __name__ == "__main__":
    sys.exit(main())
