"""lpy-light against Radiance's rtrace (``-aa 0 -lr 0``) on a room both simulate exactly (opt-in).

Needs ``pip install 'lpy-light[crosscheck]'`` (pyradiance ships rtrace); ``pytest -m slow``.
The scene and the comparison are in ``benchmarks/radiance_crosscheck.py``.
"""
import sys
from pathlib import Path

import numpy as np
import pytest

sys.path.insert(0, str(Path(__file__).resolve().parents[1] / "benchmarks"))


@pytest.mark.slow
def test_room_irradiance_matches_rtrace(tmp_path):
    pytest.importorskip("pyradiance")
    from radiance_crosscheck import compare

    out = compare(photons=2e7, repeats=16, ad=1024, threads=2, folder=tmp_path, verbose=True)
    # per sensor within 4σ (both σ's), and the weighted mean ratio within 4σ of 1
    assert np.all(np.abs(out["z"]) < 4), out["z"]
    assert abs(out["mean_ratio"] - 1) < 4 * out["mean_ratio_std"], (out["mean_ratio"], out["mean_ratio_std"])
    # power: the mean ratio is known to ~0.1 %, so a lamp power or reflectance error of 0.5 % would fail
    assert 4 * out["mean_ratio_std"] < 0.005
