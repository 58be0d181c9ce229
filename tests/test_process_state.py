"""The process the modeller works in is left as lpy-light found it (issue 47): the locale, which PlantGL's C++ sets
to ``C`` (ASCII text files) and never restores, and memory that does not grow with a long growth run's steps."""
import ctypes
import csv
import locale

import pytest

from lpy_light.process_state import current_locale, preserved_locale
from lpy_light.run.results import CsvStream

LIBC = ctypes.CDLL(None)
LIBC.setlocale.restype = ctypes.c_char_p
LC_ALL = 6          # glibc's value, what PlantGL's std::setlocale(LC_ALL, "C") passes


def c_setlocale_c():
    """What PlantGL's ``pa3_to_str`` does: the C library's setlocale, behind Python's back."""
    LIBC.setlocale(LC_ALL, b"C")


def test_a_c_library_call_changes_the_locale_and_the_guard_puts_it_back(utf8_locale, tmp_path):
    c_setlocale_c()
    assert locale.getpreferredencoding(False) == "ANSI_X3.4-1968"       # what a modeller's process suffered
    locale.setlocale(locale.LC_ALL, "C.UTF-8")
    with preserved_locale():
        c_setlocale_c()
    assert current_locale() == "C.UTF-8" and locale.getpreferredencoding(False) == "UTF-8"
    path = tmp_path / "model.lpy"
    with open(path, "w") as fh:              # the default encoding, as the L-Py IDE saves
        fh.write("# µmol m-2 s-1, σ → 1 %\n")
    assert open(path).read() == "# µmol m-2 s-1, σ → 1 %\n"


def test_the_guard_puts_the_locale_back_when_the_block_fails(utf8_locale):
    with pytest.raises(KeyboardInterrupt):
        with preserved_locale():
            c_setlocale_c()
            raise KeyboardInterrupt
    assert current_locale() == "C.UTF-8"


def test_rows_streamed_step_by_step_appear_whole_at_the_end(tmp_path):
    path = tmp_path / "organs.csv"
    with CsvStream(path, ["step", "organ", "ppfd"]) as out:
        out.write([{"step": 0, "organ": 1, "ppfd": 1.5}])
        assert not path.exists()                 # a reader never sees a half-written file
        out.write([{"step": 1, "organ": 1, "ppfd": float("nan")}, {"step": 1, "organ": 2, "ppfd": 2.0}])
    rows = list(csv.DictReader(open(path)))
    assert [(r["step"], r["organ"], r["ppfd"]) for r in rows] == [("0", "1", "1.5"), ("1", "1", ""), ("1", "2", "2.0")]
    assert [p.name for p in tmp_path.iterdir()] == ["organs.csv"]


def test_a_stream_left_by_an_error_leaves_nothing_and_the_old_file_as_it_was(tmp_path):
    path = tmp_path / "organs.csv"
    path.write_text("old\n")
    with pytest.raises(RuntimeError):
        with CsvStream(path, ["step"]) as out:
            out.write([{"step": 0}])
            raise RuntimeError("disk")
    assert path.read_text() == "old\n" and [p.name for p in tmp_path.iterdir()] == ["organs.csv"]
