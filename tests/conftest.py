import sys
from pathlib import Path

sys.path.insert(0, str(Path(__file__).parent))

import pytest

ANGERS = Path(__file__).resolve().parents[1] / "lpy_light" / "data" / "angers-chamber"


@pytest.fixture(scope="session")
def angers_dir():
    return ANGERS


@pytest.fixture
def utf8_locale():
    """The process in a UTF-8 locale (a modeller's desktop), put back as it was after the test."""
    import locale
    saved = locale.setlocale(locale.LC_ALL)
    try:
        locale.setlocale(locale.LC_ALL, "C.UTF-8")
    except locale.Error:
        pytest.skip("no C.UTF-8 locale on this machine")
    yield
    locale.setlocale(locale.LC_ALL, saved)
