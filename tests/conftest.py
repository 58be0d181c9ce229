import sys
from pathlib import Path

sys.path.insert(0, str(Path(__file__).parent))

import pytest

ANGERS = Path(__file__).resolve().parents[1] / "lpy_light" / "data" / "angers-chamber"


@pytest.fixture(scope="session")
def angers_dir():
    return ANGERS
