"""The memory of a long growth run: ``lpy-light grow`` in a child process, its resident memory read at every step.

A growth run of 2,000 steps, or a sweep's worker, must not hold every step's results: ``organs.csv`` is written
step by step.  This prints the child's RSS (``VmRSS``, MB) at each step line it prints, and the growth from step
``--from`` to the end::

    python benchmarks/grow_memory.py lsystems/rose-simple4-light.lpy --steps 150      # the report's rose, lit every step

Other arguments go to ``lpy-light grow`` unchanged.  Linux only (``/proc``).
"""
from __future__ import annotations

import argparse
import re
import subprocess
import sys
import tempfile
import time
from pathlib import Path


def rss_mb(pid: int) -> float:
    """Resident memory of process ``pid`` in MB, from ``/proc/PID/status``."""
    for line in Path("/proc/%d/status" % pid).read_text().splitlines():
        if line.startswith("VmRSS:"):
            return int(line.split()[1]) / 1024
    return float("nan")


def main(argv=None) -> int:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("model")
    ap.add_argument("--from", dest="start", type=int, default=20, help="the step from which growth is measured")
    args, rest = ap.parse_known_args(argv)
    out = tempfile.mkdtemp(prefix="grow-memory-")
    cmd = [sys.executable, "-m", "lpy_light", "grow", args.model, "--out", out, *rest]
    print("$ " + " ".join(cmd), flush=True)
    child = subprocess.Popen(cmd, stderr=subprocess.PIPE, text=True, encoding="utf-8")
    t0, per_step = time.perf_counter(), {}
    for line in child.stderr:
        m = re.match(r"\s*step (\d+):", line)
        if m:
            per_step[int(m.group(1))] = rss_mb(child.pid)
            step = int(m.group(1))
            if step % 10 == 0:
                print("step %4d  RSS %7.1f MB  (%.0f s)" % (step, per_step[step], time.perf_counter() - t0), flush=True)
        elif not line.startswith("  "):
            print(line.rstrip(), flush=True)
    code = child.wait()
    steps = sorted(per_step)
    later = [per_step[s] for s in steps if s >= args.start]
    if len(later) >= 2:
        xs = [s for s in steps if s >= args.start]
        mx, my = sum(xs) / len(xs), sum(later) / len(later)
        slope = sum((x - mx) * (y - my) for x, y in zip(xs, later)) / sum((x - mx) ** 2 for x in xs)
        print("%d lit steps in %.0f s; RSS at step %d: %.1f MB, at step %d: %.1f MB, at the last (%d): %.1f MB; "
              "from step %d on: most %.1f MB, least %.1f MB, the last minus the first %+.1f MB, trend %+.3f MB a step"
              % (len(steps), time.perf_counter() - t0, steps[0], per_step[steps[0]], xs[0], later[0], steps[-1],
                 per_step[steps[-1]], args.start, max(later), min(later), later[-1] - later[0], slope))
    return code


if __name__ == "__main__":
    sys.exit(main())
