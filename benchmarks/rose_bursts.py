"""Bud bursts of ``lsystems/rose.lpy`` against the photon cap: does growth depend on a setting that should only
change its noise?

Grows the rose in the real L-Py (run it with ``.venv-lpy/bin/python``: ``scripts/test-lpy.sh`` makes that venv)
``--steps`` steps for each cap and seed, with what the rules read asked to a precision
(``PRECISION={"par": 0.04, "rfr": 0.02}`` by default), and counts the buds that burst (``Apex`` modules of order
≥ 1 at the end).  Prints one line per run as it ends, then per cap the mean, the seeds' standard deviation and the
standard error of the mean, and the difference of the two caps' means with its standard error.  A light model
whose buds' R:FR is biased at the lower cap bursts more (or fewer) buds there.

Each run is a process of its own (``--jobs`` at a time); a run's light does not depend on its threads, so the
counts are the same for any ``--jobs``.

    .venv-lpy/bin/python benchmarks/rose_bursts.py [--caps 1e6 4e6] [--seeds 1 2 ... 10] [--steps 30]
                                                   [--precision par=0.04,rfr=0.02] [--jobs 1]
"""
from __future__ import annotations

import argparse
import math
import subprocess
import sys
import time
from concurrent.futures import ThreadPoolExecutor
from pathlib import Path

ROSE = Path(__file__).resolve().parent.parent / "lsystems" / "rose.lpy"

ONE_RUN = """
import sys
from openalea.lpy import Lsystem
cap, seed, steps, precision = float(sys.argv[1]), int(sys.argv[2]), int(sys.argv[3]), eval(sys.argv[4])
lsys = Lsystem(sys.argv[5], {"STEPS": steps, "PHOTONS": int(cap), "PRECISION": precision, "SEED": seed})
lstring = lsys.derive()
print(sum(1 for m in lstring if m.name == "Apex" and m[0] >= 1))
"""


def precision_of(text: str) -> dict:
    """``"par=0.04,rfr=0.02"`` → ``{"par": 0.04, "rfr": 0.02}``."""
    out = {}
    for part in text.split(","):
        name, _, value = part.partition("=")
        out[name.strip()] = float(value)
    return out


def bursts(cap: float, seed: int, steps: int, precision: dict) -> tuple[int, float]:
    """Buds burst after ``steps`` steps of rose.lpy at this photon cap and seed, and the run's seconds."""
    t = time.perf_counter()
    p = subprocess.run([sys.executable, "-c", ONE_RUN, repr(cap), str(seed), str(steps), repr(precision), str(ROSE)],
                       capture_output=True, text=True)
    if p.returncode != 0:
        raise SystemExit("rose.lpy at cap %g, seed %d failed:\n%s" % (cap, seed, p.stderr[-2000:]))
    return int(p.stdout.strip().splitlines()[-1]), time.perf_counter() - t


def mean_sd(values):
    n = len(values)
    mean = sum(values) / n
    sd = math.sqrt(sum((v - mean) ** 2 for v in values) / (n - 1)) if n > 1 else float("nan")
    return mean, sd, sd / math.sqrt(n)


def main():
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--caps", type=float, nargs="+", default=[1e6, 4e6])
    ap.add_argument("--seeds", type=int, nargs="+", default=list(range(1, 11)))
    ap.add_argument("--steps", type=int, default=30)
    ap.add_argument("--precision", default="par=0.04,rfr=0.02")
    ap.add_argument("--jobs", type=int, default=1)
    a = ap.parse_args()
    precision = precision_of(a.precision)
    runs = [(cap, seed) for seed in a.seeds for cap in a.caps]
    counts = {}

    def one(run):
        n, seconds = bursts(run[0], run[1], a.steps, precision)
        counts[run] = n
        print("cap %.0e  seed %2d  bursts %3d  (%.0f s)" % (run[0], run[1], n, seconds), flush=True)

    with ThreadPoolExecutor(max_workers=max(1, a.jobs)) as pool:
        list(pool.map(one, runs))
    print("\nrose.lpy, %d steps, precision %s, %d seeds" % (a.steps, a.precision, len(a.seeds)))
    stats = {}
    for cap in a.caps:
        values = [counts[cap, s] for s in a.seeds]
        stats[cap] = mean_sd(values)
        print("cap %.0e: bursts %s  mean %.1f  sd %.1f  se %.1f" % ((cap, values) + stats[cap]))
    if len(a.caps) == 2:
        (m0, _, e0), (m1, _, e1) = stats[a.caps[0]], stats[a.caps[1]]
        print("difference %.0e - %.0e: %+.1f ± %.1f (standard error)" % (a.caps[0], a.caps[1], m0 - m1,
                                                                         math.hypot(e0, e1)))


if __name__ == "__main__":
    main()
