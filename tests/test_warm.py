"""A first run's compile on two cores (:mod:`kernel.warm`): the recorded plan is that of today's kernel, the
helpers it shares out are all the entry point needs, and the kernel so compiled gives the same numbers."""
import os
import pickle
import subprocess
import sys
from pathlib import Path

import numba
import pytest

from lpy_light.kernel import warm

ROOT = Path(__file__).resolve().parents[1]

#: in a fresh process and cache: the README's main job (few photons, one thread), with the entry point's
#: direct helper compiles recorded; prints the plan it saw, whether the helpers were shared, the sensors' digest
#: and the reference counts left in the loop's code
RUN = """
import hashlib, json, pickle, sys
from pathlib import Path
from lpy_light.kernel import warm
from lpy_light.kernel import trace
from lpy_light.cli import main
shared = []
share = trace.share_compile
trace.share_compile = lambda *a: shared.append(share(*a)) or shared[-1]
if sys.argv[1] == "serial":
    warm.MIN_SHARED = float("inf")
with warm.record([trace.trace_photons]) as found:
    main(["run", "angers", "--photons", "20000", "--threads", "1", "--quiet", "--out", sys.argv[2]])
digest = hashlib.sha256((Path(sys.argv[2]) / "sensors.csv").read_bytes()).hexdigest()
ir = next(iter(trace.trace_photons.overloads.values())).library.get_llvm_str()
sys.stdout.flush()
sys.stdout.buffer.write(b"RESULT:" + pickle.dumps((found, shared, digest, ir.count("NRT_incref"))))
"""


def _run(mode, tmp_path):
    env = {k: v for k, v in os.environ.items() if not k.startswith("NUMBA_")}
    env["NUMBA_CACHE_DIR"] = str(tmp_path / ("cache-" + mode))
    out = subprocess.run([sys.executable, "-c", RUN, mode, str(tmp_path / mode)], cwd=ROOT, env=env,
                         capture_output=True, check=True).stdout
    return pickle.loads(out[out.rindex(b"RESULT:") + 7:])


def test_the_plan_is_current_and_a_shared_compile_gives_the_same_kernel(tmp_path):
    """Two cold compiles of the main job's kernel: one alone, recording what the entry point compiles (it must be
    in the plan, else ``python scripts/compile_plan.py`` was not run after a change to the kernel), one shared
    with a child process (then the entry point compiles no helper itself: the plan covered them all).  Same
    sensors, bit for bit, and the same loop: no reference counting in either (the child's helpers compiled
    with numba's defaults had it, and traced at half the speed: numba's cache key ignores the flags)."""
    found_serial, shared_serial, digest_serial, nrt_serial = _run("serial", tmp_path)
    found_shared, shared, digest_shared, nrt_shared = _run("shared", tmp_path)
    assert digest_shared == digest_serial
    assert nrt_serial == nrt_shared == 0       # helpers compiled as the loop's callees: no reference counting
    assert shared_serial == [False] and len(found_serial) == 1
    version, plan = warm.read_plan()
    if version != numba.__version__:           # another numba's types may differ: the shortcut is lost, not more
        pytest.skip("the plan was recorded with numba %s, this is %s: python scripts/compile_plan.py records it "
                    "for this one" % (version, numba.__version__))
    (entry, calls), = found_serial.items()
    planned = {c[:3] for c in plan.get(entry, [])}
    missing = [c[:2] for c in calls if c[:3] not in planned]
    assert not missing, "helpers not in the plan (run scripts/compile_plan.py): %s" % missing
    if warm._cpus() >= 2:
        assert shared == [True] and found_shared == {}


def test_shares_go_to_whoever_finishes_first():
    calls = [("m", name, (), s) for name, s in (("a", 5.0), ("b", 4.0), ("c", 2.0), ("d", 1.0), ("e", 1.0))]
    mine, theirs = warm.shares(calls, child_start=1.0)
    assert [c[1] for c in mine] == ["a", "c"] and [c[1] for c in theirs] == ["b", "d", "e"]   # 7 s each, the child from 1 s
    assert warm.shares(calls[:1], child_start=1.0) == (calls[:1], [])


def test_no_plan_or_a_ready_kernel_means_no_child(tmp_path):
    from lpy_light.kernel.trace import trace_photons
    assert warm.plan_for(trace_photons, (), tmp_path / "missing.pkl") is None
    (tmp_path / "bad.pkl").write_bytes(b"not a pickle")
    assert warm.plan_for(trace_photons, (), tmp_path / "bad.pkl") is None
    assert not warm._is_python("/usr/bin/lpy") and warm._is_python(sys.executable)
