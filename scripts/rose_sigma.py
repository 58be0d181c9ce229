"""Per step of a growth run, the precision of what the growth rules read: PAR and R:FR of buds and leaves.

Reads the ``organs.csv`` that ``lpy-light grow`` writes and prints, for every step and organ kind
(``Bud``, ``Leaf``: the light model's targets), the number of organs, their median PAR
(µmol m-2 s-1), the median and largest relative σ of PAR, the median R:FR and the median and
largest σ of R:FR (absolute, as a rule compares R:FR with a threshold).

    python3 scripts/rose_sigma.py runs/rose/organs.csv [--every N]
"""
from __future__ import annotations

import argparse
import collections
import csv
import math


def organ_rows(path):
    """One row per (step, organ) of the targets: the per-organ columns repeat over the bands."""
    seen = {}
    with open(path, newline="") as f:
        for row in csv.DictReader(f):
            if row.get("role", "target") != "target" or not row["par"]:
                continue
            seen.setdefault((int(row["step"]), row["organ"]), row)
    return seen.values()


def median(values):
    values = sorted(values)
    return values[len(values) // 2] if values else math.nan


def main(argv=None):
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("organs_csv")
    ap.add_argument("--every", type=int, default=1, help="print every N-th step (and the last)")
    args = ap.parse_args(argv)
    steps = collections.defaultdict(lambda: collections.defaultdict(list))
    for row in organ_rows(args.organs_csv):
        par, par_std = float(row["par"]), float(row["par_std"])
        rfr = float(row["rfr"]) if row["rfr"] else math.nan
        rfr_std = float(row["rfr_std"]) if row["rfr_std"] else math.nan
        steps[int(row["step"])][row["module"]].append((par, par_std / par if par > 0 else math.inf, rfr, rfr_std))
    last = max(steps) if steps else 0
    print("step  kind   n   PAR med  PAR σ med  PAR σ max  R:FR med  R:FR σ med  R:FR σ max")
    for step in sorted(steps):
        if step % args.every and step != last:
            continue
        for kind, rows in sorted(steps[step].items()):
            par, rel, rfr, rfr_std = zip(*rows)
            print("%4d  %-5s %3d  %8.1f  %8.1f %%  %8.1f %%  %8.2f  %10.3f  %10.3f"
                  % (step, kind, len(rows), median(par), 100 * median(rel), 100 * max(rel), median(rfr),
                     median(rfr_std), max(rfr_std)))


if __name__ == "__main__":
    main()
