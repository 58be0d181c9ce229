"""The kernel's numba cache: one folder per version of the kernel (its sources' digest and numba's version),
shared by every clone, venv and install of that version, and never a caller compiled against an older callee
(numba alone keys each function on its own file)."""
import os
import shutil
import subprocess
import sys
import time
from pathlib import Path

from numba.core import config

import lpy_light.kernel as kernel
from lpy_light.kernel import _drop_stale_numba_cache, kernel_cache_dir, numba_cache_dir

KERNEL = Path(kernel.__file__).parent


def _package(folder, **files):
    folder.mkdir(parents=True)
    for name, text in files.items():
        (folder / (name + ".py")).write_text(text)
    return folder


def test_one_folder_per_version_in_the_users_cache(tmp_path, monkeypatch):
    """Two clones of one version (same sources, other paths) share a folder, in the user's cache where
    NUMBA_CACHE_DIR is not set (a read-only site-packages as well); an edit to any source is another folder."""
    monkeypatch.setattr(config, "CACHE_DIR", "")
    monkeypatch.setenv("XDG_CACHE_HOME", str(tmp_path / "user-cache"))
    a = _package(tmp_path / "clone-a" / "kernel", a="x = 1\n", b="y = 2\n")
    b = _package(tmp_path / "clone-b" / "kernel", a="x = 1\n", b="y = 2\n")
    assert kernel_cache_dir(a) == kernel_cache_dir(b) == numba_cache_dir(a)
    assert (tmp_path / "user-cache") in kernel_cache_dir(a).parents and kernel_cache_dir(a).is_dir()
    (b / "b.py").write_text("y = 3\n")                  # an edit to another file than a cached function's
    kernel._DIRS.clear()
    assert kernel_cache_dir(b) != kernel_cache_dir(a)


def test_the_folder_follows_numba_cache_dir(tmp_path, monkeypatch):
    monkeypatch.setattr(config, "CACHE_DIR", str(tmp_path / "mine"))
    (tmp_path / "a.py").write_text("x = 1\n")
    assert (tmp_path / "mine") in numba_cache_dir(tmp_path).parents


def test_the_kernels_functions_and_only_they_are_cached_there():
    from numba import njit

    from lpy_light.kernel import nee, trace

    @njit(cache=True)
    def elsewhere(x):
        return x

    for f in (trace.trace_photons, nee.next_event):
        assert Path(f._cache.cache_path) == numba_cache_dir()
    assert Path(elsewhere._cache.cache_path) != numba_cache_dir()


def test_old_versions_pruned_beyond_the_most_recently_used(tmp_path, monkeypatch):
    monkeypatch.setattr(config, "CACHE_DIR", str(tmp_path / "cache"))
    root = tmp_path / "cache" / "lpy-light"
    for k in range(kernel.KEEP_VERSIONS + 2):
        old = root / ("kernel-0-%d" % k)
        old.mkdir(parents=True)
        (old / "last-used").touch()
        os.utime(old / "last-used", (time.time() - 1000 + k, time.time() - 1000 + k))
    here = _package(tmp_path / "kernel", a="x = 1\n")
    new = kernel_cache_dir(here)
    kept = sorted(p.name for p in root.glob("kernel-*"))
    assert new.name in kept and len(kept) == kernel.KEEP_VERSIONS
    assert "kernel-0-0" not in kept and "kernel-0-%d" % (kernel.KEEP_VERSIONS + 1) in kept


def test_a_second_clone_loads_what_the_first_compiled(tmp_path):
    """The kernel copied to two folders (two clones of one version, files of other times): a function compiled
    from the first is loaded from the cache by the second, not compiled again."""
    for clone in ("a", "b"):
        shutil.copytree(KERNEL, tmp_path / clone / "kernel", ignore=shutil.ignore_patterns("__pycache__"))
    env = {k: v for k, v in os.environ.items() if not k.startswith("NUMBA_")}
    env["NUMBA_CACHE_DIR"] = str(tmp_path / "cache")
    code = ("import numpy as np; from kernel import fingerprint as f; f._compiled_math(np.ones(3)); "
            "s = f._compiled_math.stats; print(f.__file__, sum(s.cache_hits.values()), sum(s.cache_misses.values()))")
    seen = []
    for clone in ("a", "b"):
        out = subprocess.run([sys.executable, "-c", code], cwd=tmp_path / clone, capture_output=True, text=True,
                             env=dict(env, PYTHONPATH=str(tmp_path / clone)), check=True).stdout.split()
        assert Path(out[0]).parent == tmp_path / clone / "kernel"
        seen.append([int(n) for n in out[1:]])
    assert seen == [[0, 1], [1, 0]]           # (hits, misses): compiled in the first, loaded in the second


def test_a_folder_numba_chose_is_dropped_on_any_source_edit_and_kept_otherwise(tmp_path):
    """Where the version's folder cannot be written, numba caches where it would for any package (keyed by
    each function's own file): the whole cache is dropped when any kernel source changes."""
    (tmp_path / "a.py").write_text("x = 1\n")
    (tmp_path / "b.py").write_text("y = 2\n")
    cache = tmp_path / "__pycache__"
    cache.mkdir()
    compiled = [cache / "a.f-1.py311.nbi", cache / "a.f-1.py311.1.nbc"]
    for f in compiled:
        f.write_text("stale")
    _drop_stale_numba_cache(tmp_path, cache)           # no stamp yet: unknown provenance, dropped
    assert not any(f.exists() for f in compiled)
    for f in compiled:
        f.write_text("fresh")
    _drop_stale_numba_cache(tmp_path, cache)           # nothing changed: kept
    assert all(f.exists() for f in compiled)
    (tmp_path / "b.py").write_text("y = 3\n")          # an edit to another file than the cached function's
    _drop_stale_numba_cache(tmp_path, cache)
    assert not any(f.exists() for f in compiled)


def test_no_writable_cache_root_means_numbas_own_folders(tmp_path, monkeypatch):
    monkeypatch.setattr(config, "CACHE_DIR", "")
    blocked = tmp_path / "user-cache"
    blocked.write_text("")                  # not a folder: the user's cache cannot be made (even as root)
    monkeypatch.setenv("XDG_CACHE_HOME", str(blocked))
    here = _package(tmp_path / "kernel", a="x = 1\n")
    assert kernel_cache_dir(here) is None
    assert numba_cache_dir(here) == here / "__pycache__"
