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


def test_cache_falls_back_to_the_users_cache_where_the_package_is_read_only(tmp_path, monkeypatch):
    """A ``pip install`` into a read-only site-packages: numba caches the kernel in the user's cache, and the
    stale-code guard must watch that folder (else an upgrade would load callers compiled against the old
    callees).  Breaks if numba_cache_dir stops following numba's choice."""
    from numba.core import config
    from lpy_light.kernel import numba_cache_dir
    pkg = tmp_path / "site-packages" / "kernel"
    pkg.mkdir(parents=True)
    (pkg / "a.py").write_text("x = 1\n")
    (pkg / "__pycache__").write_text("")      # not a folder: unwritable as a read-only install's (even for root)
    monkeypatch.setattr(config, "CACHE_DIR", "")
    monkeypatch.setenv("XDG_CACHE_HOME", str(tmp_path / "user-cache"))
    cache = numba_cache_dir(pkg)
    assert cache is not None and (tmp_path / "user-cache") in cache.parents
    compiled = cache / "a.f-1.py311.nbi"
    compiled.write_text("old install")
    _drop_stale_numba_cache(pkg)                        # an install whose stamp is unknown: dropped
    assert not compiled.exists() and (cache / "numba-sources.sha256").is_file()
    compiled.write_text("this install")
    _drop_stale_numba_cache(pkg)
    assert compiled.exists()
    (pkg / "a.py").write_text("x = 2\n")                # an upgrade
    _drop_stale_numba_cache(pkg)
    assert not compiled.exists()


def test_numba_cache_dir_follows_numba_cache_dir_setting(tmp_path, monkeypatch):
    from numba.core import config
    from lpy_light.kernel import numba_cache_dir
    monkeypatch.setattr(config, "CACHE_DIR", str(tmp_path / "mine"))
    (tmp_path / "a.py").write_text("x = 1\n")
    assert (tmp_path / "mine") in numba_cache_dir(tmp_path).parents
