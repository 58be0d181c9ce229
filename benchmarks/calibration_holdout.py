"""Does a calibration help where it was not measured?  ``survey-v`` (Angers, 240 sites, 12 bands) split into a
survey that is fitted and sites that are held out, the way a modeller's survey relates to the plant above it.

For each split, ``lpy-light calibrate``'s fit (:func:`lpy_light.calibration.calibrate.calibrate`) on the fitted
sites, then the held-out sites predicted by the chamber as described with one scale per band fitted on the same
survey ("before") and by the fitted chamber ("after").  Prints per band: the report's cross-validated rms, the
held-out rms before and after and their ratio; then the median ratio, the bands within 1.1 and the report's
cross-validated rms over the held-out one (is the report honest?).

Splits (``--splits``, all by default):

* ``half-even`` / ``half-odd``: the even (odd) y-rows fitted, the others held out (``docs/calibration.md``'s
  "half its rows");
* ``column-110``, ``column-710``, ``column-1210``: the 10 sites of one column (one x) at z = 1000 mm fitted,
  the other 230 held out: a survey on one line at one height;
* ``row-930``, ``row-1830``: the 12 sites of one y-row at z = 1000 mm fitted, the other 228 held out;
* ``height-1000``: the 120 sites at z = 1000 mm fitted, z = 1400 mm held out;
* ``whole``: all 240 sites fitted, nothing held out (what ``lpy-light calibrate angers-12bands survey-v.csv``
  does; with ``--out`` its report and ``rows.png``).

All splits share one set of lamp runs over the 240 sites and the probes (``--cache DIR`` keeps them between
invocations).  ~35 runs of ``--photons`` (2·10⁶: ~10 s each on 2 cores) plus up to 12 per split.

    .venv/bin/python benchmarks/calibration_holdout.py [--splits column-710,half-even] [--cache runs/cal-cache]
"""
from __future__ import annotations

import argparse
import dataclasses
import hashlib
import json
import pickle
import sys
import time
from pathlib import Path

import numpy as np

ROOT = Path(__file__).resolve().parent.parent
sys.path.insert(0, str(ROOT))

from lpy_light.calibration import calibrate as cal_mod          # noqa: E402
from lpy_light.calibration.survey import _rows_of, read_survey  # noqa: E402
from lpy_light.chamber.scene import load_scene, resolve_scene   # noqa: E402
from lpy_light.chamber.sensors import Sensors                   # noqa: E402

SURVEY = ROOT / "lpy_light" / "data" / "angers-chamber" / "survey" / "survey-v.csv"


def subset(survey, mask, rows=None):
    """The sites of ``survey`` where ``mask``, their rows named anew (or ``rows``)."""
    s = survey.sensors
    sensors = Sensors(s.kind[mask], s.center[mask], s.normal[mask], s.radius[mask], s.corners[mask],
                      [src for src, m in zip(s.source, mask) if m])
    row, how = (rows[mask], "y-rows of survey-v") if rows is not None else _rows_of(sensors.center)
    _, row = np.unique(row, return_inverse=True)
    return dataclasses.replace(survey, sensors=sensors, values=survey.values[mask], line=survey.line[mask],
                               row=row, row_source=how)


def splits(survey):
    """{name: (fitted mask, held-out mask, rows of the fitted sites or None: as calibrate names them)}."""
    x, y, z = survey.sensors.center.T
    low = np.isclose(z, 1000)
    _, yrow = np.unique(y, return_inverse=True)
    out = {"half-even": (yrow % 2 == 0, yrow % 2 == 1, None), "half-odd": (yrow % 2 == 1, yrow % 2 == 0, None)}
    for c in (110, 710, 1210):
        m = low & np.isclose(x, c)
        out["column-%d" % c] = (m, ~m, None)
    for r in (930, 1830):
        m = low & np.isclose(y, r)
        out["row-%d" % r] = (m, ~m, None)
    out["height-1000"] = (low, ~low, None)
    out["whole"] = (np.ones(len(x), bool), np.zeros(len(x), bool), None)
    return out


class View:
    """LampRuns restricted to some of its sites (a split's fitted, held-out and probe sites)."""

    def __init__(self, runs, index):
        self.big, self.index = runs, index

    @property
    def runs(self):
        return self.big.runs

    @property
    def photons(self):
        return self.big.photons

    def densities(self, lamps=None, materials=None):
        return self.big.densities(lamps, materials)[:, self.index]


class DiskRuns(cal_mod.LampRuns):
    """LampRuns that keep each run in ``folder`` (keyed by the sites, photons, seed and overrides)."""

    folder: Path | None = None

    def density(self, lamp, lamps, materials):
        key = self.key(lamp, lamps, materials)
        if self.folder is None:
            return super().density(lamp, lamps, materials)
        h = hashlib.sha1(repr((self.chamber.sensors.center.tobytes(), self.photons, self.seed, key)).encode())
        f = self.folder / ("%s.pkl" % h.hexdigest())
        if key not in self.cache and f.exists():
            self.cache[key] = pickle.loads(f.read_bytes())
        out = super().density(lamp, lamps, materials)
        if not f.exists():
            f.write_bytes(pickle.dumps(out))
        return out


def main(argv=None):
    ap = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    ap.add_argument("--splits", default=None, help="comma-separated (default: all)")
    ap.add_argument("--photons", type=float, default=2e6)
    ap.add_argument("--seed", type=int, default=1)
    ap.add_argument("--cache", default=None, help="folder keeping the lamp runs between invocations")
    ap.add_argument("--json", default=None, help="write the figures here")
    ap.add_argument("--out", default=None, help="write each split's calibrate outputs in OUT/SPLIT")
    args = ap.parse_args(argv)
    chamber = load_scene(resolve_scene("angers-12bands"))
    survey = read_survey(SURVEY, chamber)
    probes, _, _ = cal_mod.probe_sites(chamber, survey)
    if args.cache:
        DiskRuns.folder = Path(args.cache)
        DiskRuns.folder.mkdir(parents=True, exist_ok=True)
    runs = DiskRuns(chamber, Sensors.concat([survey.sensors, probes]), int(args.photons), args.seed,
                    say=lambda t: None)
    S = len(survey)
    chosen = splits(survey)
    names = args.splits.split(",") if args.splits else [n for n in chosen if n != "whole"]
    results = {}
    for name in names:
        fit_mask, held_mask, rows = chosen[name]
        fitted = subset(survey, fit_mask, rows)
        held = subset(survey, held_mask) if held_mask.any() else None
        own_probes, _, _ = cal_mod.probe_sites(chamber, fitted)
        assert np.allclose(own_probes.center, probes.center), "a split's probes differ from the shared runs'"
        index = np.concatenate([np.flatnonzero(fit_mask), np.flatnonzero(held_mask), S + np.arange(len(probes))])
        t = time.perf_counter()
        cal = cal_mod.calibrate(chamber, fitted, check=held, runs=View(runs, index))
        seconds = time.perf_counter() - t
        if args.out:
            cal_mod.write_outputs(Path(args.out) / name, cal, "angers-12bands", "angers-12bands")
        if held is None:
            print(cal_mod.report_text(cal, "angers-12bands, %s" % name))
            continue
        rb, ra = cal.check["rms_before"], cal.check["rms_after"]
        ratio = ra / rb
        honest = cal.cv_after / ra
        sa = cal.check["rms_after_sigma"]
        z = (cal.cv_after - ra) / np.sqrt(cal.cv_after_sigma ** 2 + sa ** 2)   # the two rms apart, in their σ
        results[name] = {"fitted_sites": int(fit_mask.sum()), "held_sites": int(held_mask.sum()),
                         "cv_before": cal.cv_before.tolist(), "cv_after": cal.cv_after.tolist(),
                         "held_before": rb.tolist(), "held_after": ra.tolist(), "ratio": ratio.tolist(),
                         "cv_over_held": honest.tolist(), "cv_after_sigma": cal.cv_after_sigma.tolist(),
                         "held_after_sigma": sa.tolist(), "z": z.tolist(),
                         "fitted": [p["parameter"] for p in cal.parameters if p["fitted"]],
                         "warnings": cal.warnings, "seconds": seconds}
        print("\n## %s: %d sites fitted, %d held out (%.0f s, %d runs in all)" % (
            name, fit_mask.sum(), held_mask.sum(), seconds, runs.runs))
        print("| band | cv before | cv after | held before | held after | after / before | cv after / held after "
              "| (cv − held) / σ |")
        print("|---|---|---|---|---|---|---|---|")
        for b, band in enumerate(cal.bands):
            print("| %s | %.1f | %.1f ± %.1f | %.1f | %.1f ± %.1f | %.2f | %.2f | %+.1f |" % (
                band, 100 * cal.cv_before[b], 100 * cal.cv_after[b], 100 * cal.cv_after_sigma[b], 100 * rb[b],
                100 * ra[b], 100 * sa[b], ratio[b], honest[b], z[b]))
        print("median after / before %.2f, max %.2f, bands <= 1.1: %d of %d; cv after / held after: median %.2f "
              "(%.2f-%.2f); cv after within 2σ of held after in %d of %d bands" % (
                  np.median(ratio), ratio.max(), (ratio <= 1.1).sum(), len(ratio), np.median(honest), honest.min(),
                  honest.max(), (np.abs(z) <= 2).sum(), len(z)))
        print("fitted: %s" % (", ".join(results[name]["fitted"]) or "nothing but the bands' scales"))
        for w in cal.warnings:
            print("warning: %s" % w)
        sys.stdout.flush()
    if args.json:
        Path(args.json).write_text(json.dumps(results, indent=1))


if __name__ == "__main__":
    main()
