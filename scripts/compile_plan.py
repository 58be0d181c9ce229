"""Record the kernel's compile plan (``kernel/compile_plan.pkl``, :mod:`kernel.warm`): for each case below, in a
process of its own with an empty numba cache, which helpers the entry point calls, for which types, and how long
each took to compile.  Run it after a change to the kernel's helpers or records (``tests/test_warm.py`` says when):

    .venv/bin/python scripts/compile_plan.py

Cases: the README's main job (``nee``, no organs) and two steps of the procedural rose (``nee``; the second has organ
targets).
"""
import os
import pickle
import subprocess
import sys
import tempfile
from pathlib import Path

ROOT = Path(__file__).resolve().parent.parent

#: (what, Python code run with the plan recorded)
CASES = [
    ("run angers (nee)", "from lpy_light.cli import main; main(['run', 'angers', '--photons', '1000', '--quiet', "
                         "'--out', %r])"),
    ("a rose step (nee, organ targets)", "import runpy, sys; sys.argv = ['rose.py', '--photons', '3000', "
                                         "'--steps', '2']; runpy.run_path(%r, run_name='__main__')"),
]

RECORD = """
import pickle, sys
from lpy_light.kernel import warm
from lpy_light.kernel.trace import trace_photons
warm.MIN_SHARED = float("inf")          # compile alone: every helper call is then seen under the entry point
with warm.record([trace_photons]) as found:
    {code}
sys.stdout.flush()
sys.stdout.buffer.write(b"PLAN:" + pickle.dumps(found))
"""


def record_case(code) -> dict:
    """The plan entries one case's first compile makes, recorded in a fresh process and cache."""
    with tempfile.TemporaryDirectory() as tmp:
        env = {k: v for k, v in os.environ.items() if not k.startswith("NUMBA_")}
        env["NUMBA_CACHE_DIR"] = tmp
        out = subprocess.run([sys.executable, "-c", RECORD.format(code=code)], cwd=ROOT, env=env,
                             capture_output=True, check=True).stdout
    return pickle.loads(out[out.rindex(b"PLAN:") + 5:])


def main():
    plan = {}
    out_dir = tempfile.mkdtemp()
    for what, code in CASES:
        arg = out_dir if "angers" in what else str(ROOT / "benchmarks" / "rose.py")
        found = record_case(code % arg)
        for key, calls in found.items():
            print("%s: %s, %d helper calls, %.1f s" % (what, key[1], len(calls), sum(c[3] for c in calls)))
        for key, calls in found.items():          # the union of the cases' calls, each its longest time
            merged = {c[:3]: c for c in plan.get(key, [])}
            for c in calls:
                if c[:3] not in merged or merged[c[:3]][3] < c[3]:
                    merged[c[:3]] = c
            plan[key] = list(merged.values())
    import numba

    from lpy_light.kernel import warm
    with open(warm.PLAN, "wb") as f:
        pickle.dump((numba.__version__, plan), f)
    print("wrote %s (%d entry signatures: %s helper calls)" % (warm.PLAN, len(plan),
                                                             ", ".join(str(len(c)) for c in plan.values())))


if __name__ == "__main__":
    main()
