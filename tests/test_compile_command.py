"""``lpy-light compile`` (which ``scripts/setup.sh`` runs) makes ready every compiled function the README's main
job calls: after it, the job compiles nothing (its first run traces at once)."""
import os
import subprocess
import sys
from pathlib import Path

ROOT = Path(__file__).resolve().parents[1]

#: in a fresh process: ``compile``, the kernel's compiled functions then, the main job (few photons), and those
#: the job added
RUN = """
import sys
from numba.core.dispatcher import Dispatcher
from lpy_light.cli import main

def ready():
    return {(name, f.py_func.__qualname__, str(sig)) for name, m in list(sys.modules.items())
            if name.startswith("lpy_light.kernel") for f in vars(m).values() if isinstance(f, Dispatcher)
            for sig in f.overloads}

assert main(["compile"]) == 0
before = ready()
assert main(["run", "angers", "--photons", "20000", "--threads", "1", "--quiet", "--out", sys.argv[1]]) == 0
print("READY", len(before), "ADDED", sorted(ready() - before))
"""


def test_the_main_job_compiles_nothing_after_compile(tmp_path):
    env = {k: v for k, v in os.environ.items() if not k.startswith("NUMBA_")}
    out = subprocess.run([sys.executable, "-c", RUN, str(tmp_path / "out")], cwd=ROOT, env=env, capture_output=True,
                         text=True, check=True)
    line = next(x for x in out.stdout.splitlines() if x.startswith("READY"))
    assert line.endswith("ADDED []"), line
    assert int(line.split()[1]) >= 3          # the loop and the two functions of the run's fingerprint
    assert "the kernel of 'run --estimator nee' is ready" in out.stderr
