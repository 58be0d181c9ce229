"""Two checkouts of lpy-light timed against each other, command by command, alternately (CPU seconds).

On a shared machine wall clock moves by ±25 % with the other jobs; the CPU seconds of the same command,
run in the two checkouts one after the other and repeated, compare like with like.  Each checkout needs
its own ``.venv`` (``bash scripts/setup.sh`` in it).  Prints each figure as it comes, then a table.

    python3 benchmarks/ab_compare.py --before /tmp/old-checkout --after . [--repeat 3] [--what raw nee rose compile]

* ``raw``: ``benchmarks/raw_embree.py --threads 1 --rays 1e6 --photons 1e6 --repeat 3``, the kernel's M rays
  and M photons per CPU-second (``weighted``);
* ``nee``: ``lpy-light run angers --photons 2e6 --estimator nee --threads 1``, the whole command's CPU s;
* ``rose``: ``benchmarks/rose.py --photons 3e5 --steps 5 --threads 1``, the steps' CPU s;
* ``compile``: with numba's cache empty (``NUMBA_CACHE_DIR``, a new folder each time), ``lpy-light run angers
  --photons 1e5`` per estimator (CPU and wall s of the whole cold run: numba's compile and a second of tracing).
"""
import argparse
import os
import re
import resource
import shutil
import subprocess
import sys
import tempfile
import time
from pathlib import Path


def _run(tree, cmd, env=None):
    """(CPU s of the child, wall s, its output)."""
    r0 = resource.getrusage(resource.RUSAGE_CHILDREN)
    t0 = time.perf_counter()
    p = subprocess.run(cmd, cwd=tree, capture_output=True, text=True, env=env)
    wall = time.perf_counter() - t0
    r1 = resource.getrusage(resource.RUSAGE_CHILDREN)
    if p.returncode:
        sys.exit("%s failed in %s:\n%s" % (" ".join(cmd), tree, p.stderr[-2000:]))
    return (r1.ru_utime - r0.ru_utime) + (r1.ru_stime - r0.ru_stime), wall, p.stdout + p.stderr


def measure(tree, what, out_dir):
    """{figure: value} for one checkout."""
    py, cli = str(tree / ".venv/bin/python"), str(tree / ".venv/bin/lpy-light")
    out = {}
    if "raw" in what:
        _, _, txt = _run(tree, [py, "benchmarks/raw_embree.py", "--threads", "1", "--rays", "1e6", "--photons", "1e6",
                                "--repeat", "3"])
        m = re.search(r"kernel ([\d.]+) M rays/CPU-s, ([\d.]+) M photons/CPU-s", txt)
        out["raw_embree: kernel M rays/CPU-s"] = float(m.group(1))
        out["raw_embree: kernel M photons/CPU-s"] = float(m.group(2))
    if "nee" in what:
        shutil.rmtree(out_dir, ignore_errors=True)
        cpu, _, _ = _run(tree, [cli, "run", "angers", "--photons", "2e6", "--estimator", "nee", "--seed", "3",
                                "--threads", "1", "--quiet", "--out", str(out_dir)])
        out["angers nee 2e6, 1 thread: CPU s"] = cpu
    if "rose" in what:
        _, _, txt = _run(tree, [py, "benchmarks/rose.py", "--photons", "300000", "--steps", "5", "--threads", "1"])
        rows = [line.split() for line in txt.splitlines() if re.match(r"\s+\d+\s+\d+\s+\d+", line)]
        out["rose 5 steps: CPU s"] = sum(float(r[4]) for r in rows)
        out["rose last step: CPU s"] = float(rows[-1][4])
    if "compile" in what:
        for est in ("weighted", "nee", "analog"):
            cache = out_dir.parent / "numba-cache"
            shutil.rmtree(cache, ignore_errors=True)
            shutil.rmtree(out_dir, ignore_errors=True)
            env = dict(os.environ, NUMBA_CACHE_DIR=str(cache))
            cpu, wall, _ = _run(tree, [cli, "run", "angers", "--photons", "1e5", "--estimator", est, "--threads", "1",
                                       "--quiet", "--out", str(out_dir)], env)
            out["cold first run, %s: CPU s" % est] = cpu
            out["cold first run, %s: wall s" % est] = wall
    return out


def main(argv=None):
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--before", required=True, type=Path)
    ap.add_argument("--after", required=True, type=Path)
    ap.add_argument("--repeat", type=int, default=3)
    ap.add_argument("--what", nargs="+", default=["raw", "nee", "rose", "compile"],
                    choices=["raw", "nee", "rose", "compile"])
    args = ap.parse_args(argv)
    trees = {"before": args.before.resolve(), "after": args.after.resolve()}
    got = {}
    with tempfile.TemporaryDirectory() as tmp:
        for label, tree in trees.items():   # compile (or load) each kernel first: the timings are of runs
            for est in ("weighted", "nee"):
                _run(tree, [str(tree / ".venv/bin/lpy-light"), "run", "angers", "--photons", "1e4", "--estimator",
                            est, "--quiet", "--out", str(Path(tmp) / "warm" / (label + est))])
        for rep in range(args.repeat):
            for label in (("before", "after") if rep % 2 == 0 else ("after", "before")):
                for k, v in measure(trees[label], args.what, Path(tmp) / "out").items():
                    got.setdefault(k, {}).setdefault(label, []).append(v)
                    print("%-40s %-6s %.3g" % (k, label, v), flush=True)
    print("\n%-40s %-24s %-24s" % ("", "before (min-max)", "after (min-max)"))
    for k, v in got.items():
        print("%-40s %-24s %-24s" % (k, "%.3g-%.3g" % (min(v["before"]), max(v["before"])),
                                     "%.3g-%.3g" % (min(v["after"]), max(v["after"]))))


if __name__ == "__main__":
    sys.exit(main())
