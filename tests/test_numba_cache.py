"""The kernel's numba cache is dropped when any kernel source changes (numba alone would reuse a caller
compiled against an older callee from another file)."""
from lpy_light.kernel import _drop_stale_numba_cache


def test_cache_dropped_on_any_source_edit_and_kept_otherwise(tmp_path):
    (tmp_path / "a.py").write_text("x = 1\n")
    (tmp_path / "b.py").write_text("y = 2\n")
    cache = tmp_path / "__pycache__"
    cache.mkdir()
    compiled = [cache / "a.f-1.py311.nbi", cache / "a.f-1.py311.1.nbc"]
    for f in compiled:
        f.write_text("stale")
    _drop_stale_numba_cache(tmp_path)                  # no stamp yet: unknown provenance, dropped
    assert not any(f.exists() for f in compiled)
    for f in compiled:
        f.write_text("fresh")
    _drop_stale_numba_cache(tmp_path)                  # nothing changed: kept
    assert all(f.exists() for f in compiled)
    (tmp_path / "b.py").write_text("y = 3\n")          # an edit to another file than the cached function's
    _drop_stale_numba_cache(tmp_path)
    assert not any(f.exists() for f in compiled)
