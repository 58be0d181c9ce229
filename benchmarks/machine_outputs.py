"""Another machine's numbers for the kernel's digest cases, against the stored values: how far apart two kinds of
machine put the same seed's tallies, in the stored run's own σ.

The folder holds one ``CASE.npz`` per case of ``tests/test_kernel_digests.py`` with the arrays that case digests,
in order (``arr_0``, ``arr_1``, ...), as ``../shared/data/kernel-outputs-emeraldrapids/dump.py`` writes them on
that machine.  For each case: whether its digest is this machine's pinned one, the largest |z| and the
root-mean-square z over the tallies the stored run reached (z = (there - stored) / σ_stored), beside the test's
bounds (every |z| < 4, rms < 0.5).  Arrays traced by another version of the kernel are compared all the same:
then the difference is the two kernels' as well as the two machines'.

    .venv/bin/python benchmarks/machine_outputs.py ../shared/data/kernel-outputs-emeraldrapids
"""
from __future__ import annotations

import argparse
import sys
from pathlib import Path

import numpy as np

sys.path.insert(0, str(Path(__file__).resolve().parents[1] / "tests"))
import test_kernel_digests as cases  # noqa: E402


def case_values(name: str, arrays: list) -> np.ndarray:
    """The values the statistical test compares, from a case's digested arrays (see ``_run`` and ``_rose``)."""
    if name.startswith("rose"):          # per organ: photons, σ, ppfd, σ, absorbed, σ, (par, σ, rfr, σ)
        n = len(arrays) // 7
        return np.concatenate([np.concatenate([arrays[7 * i + 2], arrays[7 * i + 4]]) for i in range(n)])
    return arrays[0][:-1].ravel()        # the tallies but the closure row


def main(argv=None) -> int:
    ap = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    ap.add_argument("folder", type=Path)
    args = ap.parse_args(argv)
    pinned = cases.PINNED.get(cases.fingerprint(), {}).get("digests", {})
    print("%-24s %-8s %8s %8s   (bounds: |z| < %g, rms < %g)" % ("case", "digest", "max|z|", "rms z",
                                                                   cases.Z_MAX, cases.Z_RMS_MAX))
    for name in cases.CASES:
        path = args.folder / (name + ".npz")
        if not path.exists():
            continue
        with np.load(path) as f:
            arrays = [f["arr_%d" % i] for i in range(len(f.files))]
        ref = cases.stored(name)
        value = case_values(name, arrays)
        reached = ref["std"] > 0
        same_nan = np.isnan(value) & np.isnan(ref["value"])
        z = np.where(same_nan, 0.0, (value - ref["value"]) / np.where(reached, ref["std"], np.nan))[reached]
        same = "same" if cases._digest(arrays) == pinned.get(name) else "differs"
        print("%-24s %-8s %8.3f %8.4f" % (name, same, np.abs(z).max(), np.sqrt(np.mean(z ** 2))))
    return 0


if __name__ == "__main__":
    sys.exit(main())
