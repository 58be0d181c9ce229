"""A new user's first run: a clean clone, ``scripts/setup.sh``, then the README's main command, twice; then a
second clone of the same commit, its setup and its first run.

The clones are made in a temporary folder, so their ``.venv`` is new, and numba's cache is a folder of that
temporary folder (``NUMBA_CACHE_DIR``; the kernel's cache is ``$NUMBA_CACHE_DIR/lpy-light/kernel-<version>``, as
``~/.cache/lpy-light/kernel-<version>`` is without it): empty for the first clone, as on a machine that never ran
this version, and the first clone's for the second, as for a user's second clone, venv or install of one version.
Prints each setup's time (creating the venv, pip installing, and ``lpy-light compile``, the main job's kernel:
its seconds as it says them), then for each run the whole command's wall and CPU seconds, the kernel's compile
(``kernel compiled in`` on stderr: 0 when loaded from the cache) and the tracing (``N photons in X s``).  Wall
seconds depend on what else the machine runs; CPU seconds less so.

    python3 benchmarks/first_run.py [--repo .] [--keep]
"""
import argparse
import os
import re
import resource
import shlex
import subprocess
import sys
import tempfile
import time
from pathlib import Path

#: the README's main command (its first code block), run in the clone
COMMAND = ".venv/bin/lpy-light run angers --out runs/angers"


def _timed(cmd, cwd, env):
    """(wall s, CPU s of the child, its stderr) of a shell command; exits on failure."""
    r0 = resource.getrusage(resource.RUSAGE_CHILDREN)
    t0 = time.perf_counter()
    p = subprocess.run(cmd, cwd=cwd, env=env, shell=True, capture_output=True, text=True)
    wall = time.perf_counter() - t0
    r1 = resource.getrusage(resource.RUSAGE_CHILDREN)
    if p.returncode:
        sys.exit("first_run: %s failed (exit %d):\n%s" % (cmd, p.returncode, (p.stdout + p.stderr)[-3000:]))
    return wall, (r1.ru_utime - r0.ru_utime) + (r1.ru_stime - r0.ru_stime), p.stderr


def _figures(stderr):
    """(compile s, tracing s, photons, the σ line) from a run's stderr."""
    m = re.search(r"kernel compiled in ([\d.]+) s", stderr)
    t = re.search(r"(\d+) photons in ([\d.]+) s", stderr)
    s = re.search(r"standard error per sensor[^\n]*", stderr)
    return (float(m.group(1)) if m else 0.0, float(t.group(2)) if t else float("nan"),
            int(t.group(1)) if t else 0, s.group(0) if s else "")


def main(argv=None):
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--repo", type=Path, default=Path(__file__).resolve().parent.parent,
                    help="the repository to clone (default: this one; its committed state)")
    ap.add_argument("--keep", action="store_true", help="keep the temporary clone")
    args = ap.parse_args(argv)
    tmp = tempfile.mkdtemp(prefix="lpy-light-first-run-")
    env = {k: v for k, v in os.environ.items() if not k.startswith("NUMBA_")}   # numba's defaults, as a user's,
    env["NUMBA_CACHE_DIR"] = str(Path(tmp) / "numba-cache")                      # in a cache folder still empty
    sigma = ""
    for n, runs in ((1, ("first", "second")), (2, ("first",))):
        clone = Path(tmp) / ("clone%d" % n)
        subprocess.run(["git", "clone", "-q", str(args.repo), str(clone)], check=True)
        commit = subprocess.run(["git", "rev-parse", "--short", "HEAD"], cwd=clone, capture_output=True,
                                text=True).stdout.strip()
        print("%s clone of %s (commit %s) in %s, %d CPU(s), load average %.2f: %s"
              % ("a first" if n == 1 else "a second", args.repo, commit, clone, len(os.sched_getaffinity(0)),
                 os.getloadavg()[0], "numba's cache empty" if n == 1 else "the first clone's cache"))
        wall, cpu, err = _timed("bash scripts/setup.sh", clone, env)
        m = re.search(r"is ready in ([\d.]+) s", err)
        print("setup (bash scripts/setup.sh: venv + pip install + lpy-light compile): %6.1f s wall  %6.1f s CPU"
              "  (lpy-light compile: %s s)" % (wall, cpu, m.group(1) if m else "?"), flush=True)
        print("%-12s %8s %8s %10s %10s  %s" % ("run", "wall s", "CPU s", "compile s", "tracing s", "photons"))
        for run in runs:
            wall, cpu, err = _timed(COMMAND, clone, env)
            compile_s, trace_s, photons, sigma = _figures(err)
            print("%-12s %8.1f %8.1f %10.1f %10.1f  %d" % (run, wall, cpu, compile_s, trace_s, photons), flush=True)
    print("  " + sigma.replace("lpy-light: ", ""))
    print("command: cd CLONE && %s  (load average now %.2f: on a shared machine, a run whose CPU s is not about"
          " 2x its tracing s had one core)" % (COMMAND, os.getloadavg()[0]))
    if not args.keep:
        subprocess.run(["rm", "-rf", tmp], check=False)
    else:
        print("kept: %s" % shlex.quote(tmp))


if __name__ == "__main__":
    sys.exit(main())
