"""The L-Py IDE as a modeller uses it, with lpy-light inside: Run a lit model, then open another, Step it, edit it
and save it with Ctrl+S -- the file on disk must be whole (issue 47: after a lit step PlantGL had left the process in
the C locale, the IDE read and wrote files as ASCII, and a model holding µ was saved as 0 bytes).

Needs the bundle with the IDE (``bash ../shared/lpy/install.sh --ide .venv-lpy``) and a display::

    LANG=C.UTF-8 xvfb-run -a .venv-lpy/bin/python scripts/ide_check.py --out /tmp/ide

It drives the IDE's own window (``openalea.lpy.gui.lpystudio.LPyWindow``): its Run and Step actions (what the
toolbar buttons trigger), its ``openfile`` (File > Open once a name is chosen), typing into its code editor and
Ctrl+S as key events.  A dialog the IDE opens (an error) is recorded, pictured (the first: ``dialog.png``) and
closed.
Prints what it saw and writes ``ide.png``, a screenshot of the window after the save; exit status 0 when the saved
file is whole and the locale is the one before.

The edit is Latin-1 text (µ, ±): the IDE itself takes the editor's text through Latin-1 when it saves
(``lpycodeeditor.getCode``), so a σ or → typed there becomes '?' whatever the locale -- L-Py's, not ours; the
models in ``lsystems/`` hold no such character (``tests/test_lpy.py``).
"""
from __future__ import annotations

import argparse
import functools
import locale
import os
import shutil
import sys
import time
from pathlib import Path

ROOT = Path(__file__).resolve().parent.parent
print = functools.partial(print, file=sys.__stdout__, flush=True)    # noqa: A001  (the IDE takes sys.stdout for its shell)


def small(src: Path, dst: Path, **externs) -> Path:
    """A copy of ``src`` with some ``extern(NAME = value)`` defaults changed (a quick Run)."""
    lines = []
    for line in src.read_text(encoding="utf-8").splitlines(keepends=True):
        for name, value in externs.items():
            head = line.replace(" ", "")
            if head.startswith("extern(%s=" % name):
                line = "extern(%s=%r)\n" % (name, value)
        lines.append(line)
    dst.write_text("".join(lines), encoding="utf-8")
    return dst


def main() -> int:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--out", default="ide-check", help="folder for the models' copies and the screenshot")
    ap.add_argument("--run-steps", type=int, default=6, help="STEPS of the rose that is Run")
    args = ap.parse_args()
    out = Path(args.out).resolve()
    out.mkdir(parents=True, exist_ok=True)
    run_model = small(ROOT / "lsystems" / "rose.lpy", out / "rose.lpy", STEPS=args.run_steps, PHOTONS=200_000)
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

    win = LPyWindow()
    win.show()

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

    win.openfile(str(run_model))
    settle()
    t0 = time.time()
    win.actionRun.trigger()                       # the toolbar's Run (runs to its end unless the IDE uses a thread)
    wait_task("Run %s (%d steps, %.1f s in the action)" % (run_model.name, args.run_steps, time.time() - t0))
    win.openfile(str(edited))                     # File > Open, the name chosen
    settle()
    shown = win.codeeditor.toPlainText()
    print("opened %s: %d characters in the editor, µ shown: %s" % (edited.name, len(shown), "µ" in shown))
    for i in range(2):
        t0 = time.time()
        win.actionStep.trigger()
        print("  (the Step action took %.1f s)" % (time.time() - t0))
        wait_task("Step %d" % (i + 1))
    added = "# edited in the IDE: PAR_MIN = 10 µmol m-2 s-1 ± 5 %"      # Latin-1: the IDE keeps no other (below)
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
    ok = whole and after == before and not dialogs
    print("IDE check: %s" % ("OK" if ok else "FAILED"))
    win.close()
    settle()
    os._exit(0 if ok else 1)      # the IDE's threads and atexit hooks are not ours to wait for


if __name__ == "__main__":
    sys.exit(main())
