"""The ``lpy-light`` command line.

    lpy-light run SCENE.toml [--photons N] [--seed S] [--threads T] --out DIR
              [--calibrate MEASURED.csv] [--plot] [--reference REF]
    lpy-light grow MODEL.lpy --steps N [--photons P] --out DIR   # needs L-Py (conda)
    lpy-light calibrate SCENE SURVEY.csv --out DIR   # the scene fitted to measured readings
    lpy-light scenes                       # list the built-in scenes
    lpy-light compile [--estimator E ...]  # compile run's kernel now (scripts/setup.sh does), trace nothing

SCENE may be a path or the name of a built-in scene (``angers``,
``angers-12bands``, ...).  Bad input exits with status 2 and one line
``lpy-light: error: FILE:LINE: what was expected``; no results are written.
"""
from __future__ import annotations

import argparse
import contextlib
import logging
import signal
import sys
import threading
from pathlib import Path

from .errors import InputError, LpyLightError
from .estimators.registry import DEFAULT_ESTIMATOR, ESTIMATORS, NextEventSettings
from .process_state import preserved_locale
from .run.results import check_out_dir, check_outputs
from .chamber.scene import builtin_scenes, resolve_scene  # noqa: F401  (scene lookup lives with scenes)

DEFAULT_PRECISION = 0.01  # `run` without --photons/--precision: every sensor and band to 1 % (nee)
DEFAULT_CAP = 100_000_000  # ... but no more photons than this (a sensor in the dark would hold the run)


def _count(text: str) -> int:
    try:
        value = float(text)
    except ValueError:
        raise argparse.ArgumentTypeError("expected a number, got %r" % text) from None
    if not value >= 1 or value != int(value) or value > 1e15:
        raise argparse.ArgumentTypeError("expected a whole number >= 1, got %r" % text)
    return int(value)


class _Parser(argparse.ArgumentParser):
    """argparse with its errors on one line (the usage is what ``--help`` is for), exit status 2."""

    def error(self, message):
        self.exit(2, "%s: error: %s (see %s --help)\n" % (self.prog, message, self.prog))


def _parser() -> argparse.ArgumentParser:
    p = _Parser(prog="lpy-light", description="Light interception in a modelled growth chamber.")
    sub = p.add_subparsers(dest="command", required=True)
    r = sub.add_parser("run", help="trace photons through a scene and write sensors.csv and summary.json")
    r.add_argument("scene", help="scene TOML file, or a built-in scene name (see 'lpy-light scenes')")
    r.add_argument("--photons", type=_count, default=None,
                   help="photons (all bands travel together). Alone: exactly this many. With --precision: a cap "
                        "(default cap 1e10). Without either: nee stops at 1%%%% (cap %g), weighted/analog trace 1e6"
                        % DEFAULT_CAP)
    r.add_argument("--precision", type=float, default=None, metavar="REL",
                   help="stop when every sensor's relative σ is at most REL (default with nee and no --photons: "
                        "%g); --photons is then a cap" % DEFAULT_PRECISION)
    r.add_argument("--seed", type=int, default=1, help="random seed (default 1); results depend on it alone")
    r.add_argument("--threads", type=int, default=None, help="threads (default: all cores)")
    r.add_argument("--out", required=True, help="output folder")
    r.add_argument("--estimator", choices=tuple(ESTIMATORS), default=DEFAULT_ESTIMATOR,
                   help="; ".join("%s%s: %s" % (e.name, " (default)" if e.name == DEFAULT_ESTIMATOR else "", e.summary)
                                  for e in ESTIMATORS.values()))
    r.add_argument("--quiet", action="store_true", help="no progress lines")
    r.add_argument("--dask", metavar="ADDRESS", default=None,
                   help="trace the photon chunks on a Dask cluster, with the same numbers as here: 'local' or "
                        "'local:N' (N worker processes on this machine, on 127.0.0.1 only; --threads per worker), "
                        "a scheduler's address (tls://host:8786) or scheduler file (.json); "
                        "needs pip install 'lpy-light[dask]' (docs/scaling.md)")
    nee = ESTIMATORS["nee"].settings
    r.add_argument("--nee-picks", type=int, default=None, metavar="K",
                   help="with next events: targets per next event, drawn at random (default: the estimator's, nee "
                        "%d; 0 = all)" % nee.picks)
    r.add_argument("--nee-images", type=float, default=None, metavar="K",
                   help="with next events: next events through a perfect mirror per vertex, on average (default: "
                        "the estimator's, nee %g; 0 = none: light whose last bounce is specular is then counted)"
                        % nee.images)
    r.add_argument("--nee-images2", type=float, default=None, metavar="K",
                   help="with next events: next events through two perfect mirrors per vertex, on average "
                        "(default: the estimator's, nee %g; 0 = none: light after two specular bounces is then "
                        "counted)" % nee.images2)
    r.add_argument("--nee-zones", type=float, default=None, metavar="K",
                   help="with --estimator nee: two-step next events per vertex through the surface right beside a "
                        "disc sensor (within 4 radii of a wall or table), on average (default: the estimator's, nee "
                        "%g; 0 = none: that light then comes only from the photons that land there)" % nee.zones)
    r.add_argument("--no-nee-control", action="store_true",
                   help="with --estimator nee: no control variate (each sensor's point-source value deposited at "
                        "every vertex, picks carrying only the difference); for comparisons")
    r.add_argument("--calibrate", metavar="FILE", default=None,
                   help="csv of measured sensors (x,y,z or sensor, and one column per band, µmol m-2 s-1): "
                        "ppfd scaled per band by least squares on them (overrides the scene's 'calibration')")
    r.add_argument("--calibrate-tolerance", type=float, default=None, metavar="D",
                   help="how far (scene units) a measured point may lie from its sensor (default: the sensor's radius)")
    r.add_argument("--plot", action="store_true",
                   help="write PNG maps of each sensor plane (needs matplotlib: pip install 'lpy-light[plot]')")
    r.add_argument("--reference", metavar="FILE", action="append", default=None,
                   help="compare with a reference (SEC2 mesures .txt, photon-mapping captor_result csv or a run's "
                        "sensors.csv): prints the comparison and the ratio per row of each sensor plane, and with "
                        "--plot maps the difference in σ units and draws the rows; given twice, the two references' "
                        "average (per emitted photon)")
    r.add_argument("--reference-band", metavar="LABEL", default=None,
                   help="band compared with the reference (default 655-665 when the scene has it, else the first)")
    sub.add_parser("scenes", help="list the built-in scenes")
    k = sub.add_parser("compile", help="compile the kernel of 'run' for an estimator now, tracing nothing (the first "
                                       "run then starts at once; scripts/setup.sh does it for the main job)")
    k.add_argument("--estimator", nargs="+", default=[DEFAULT_ESTIMATOR],
                   choices=tuple(e.name for e in ESTIMATORS.values() if not e.stored),
                   help="the estimators whose kernel to compile (default: %s)" % DEFAULT_ESTIMATOR)
    k.add_argument("--scene", default="angers", help="the scene whose kernel it is (default: angers: the kernel "
                   "of a chamber's sensors)")
    _calibrate_parser(sub)
    _grow_parser(sub)
    _sweep_parser(sub)
    return p


def _sweep_parser(sub):
    s = sub.add_parser("sweep", allow_abbrev=False,
                       help="many runs as one command: a grid of an .lpy model's externs (grow) or of scenes (run); "
                            "resumable; on this machine or on Dask",
                       description="Every combination of the inputs and the --set values is one run, written to "
                                   "OUT/NAME/ with sweep.csv indexing them; the same command again skips the "
                                   "finished runs. Options the sweep does not know (--steps 30, --photons 1e6) go "
                                   "to every run: put them after the inputs.")
    s.add_argument("inputs", nargs="+", help=".lpy models (each run: lpy-light grow) or scenes (lpy-light run)")
    s.add_argument("--set", action="append", default=[], metavar="NAME=VALUES",
                   help="a grid axis: NAME=V1,V2,... or NAME=A..B (whole numbers); a model's extern "
                        "(--set PAR_MIN=20,40,80) or a run option (--set seed=1..4); repeatable")
    s.add_argument("--out", required=True, help="output folder: one sub-folder per run, and sweep.csv")
    s.add_argument("--dask", metavar="ADDRESS", default=None,
                   help="run on a Dask cluster: local[:N], tls://host:8786, or a scheduler file (see run --dask)")
    s.add_argument("--workers", type=int, default=None,
                   help="runs at once on this machine (default: one per core; each run has --threads 1 unless given)")
    s.add_argument("--quiet", action="store_true", help="no line per finished run")


def nee_options(args) -> dict:
    """The next-event settings the command line sets (the ``--nee-*`` given; the others stay the estimator's),
    checked, each error naming its option."""
    given = {"picks": args.nee_picks, "images": args.nee_images, "images2": args.nee_images2, "zones": args.nee_zones,
             "control": False if args.no_nee_control else None}
    out = {name: value for name, value in given.items() if value is not None}
    for name, value in out.items():
        try:
            NextEventSettings(**{name: value})
        except InputError as exc:
            raise InputError(str(exc).replace("next-event setting %r" % name, "--nee-" + name)) from None
    return out


def cmd_run(args) -> int:
    from .run import simulate
    from .chamber.scene import load_scene

    if args.threads is not None and not 1 <= args.threads <= simulate.MAX_THREADS:
        raise InputError("--threads must be in 1..%d" % simulate.MAX_THREADS)
    if not 0 <= args.seed <= simulate.MAX_SEED:
        raise InputError("--seed must be a whole number in 0..2^63-1")
    check_out_dir(args.out)
    if ESTIMATORS[args.estimator].stored:
        raise InputError("--estimator %s lights a plant's organs from a stored chamber (lpy-light grow, LightModel); "
                         "a chamber's sensors are traced with nee" % args.estimator)
    if args.precision is not None and not 0 < args.precision < 1:
        raise InputError("--precision must be a relative σ in (0, 1), e.g. 0.01")
    if args.photons is None and args.precision is None and ESTIMATORS[args.estimator].next_events:
        args.precision, args.photons = DEFAULT_PRECISION, DEFAULT_CAP      # the best answer by default
    if args.photons is None:
        args.photons = 10_000_000_000 if args.precision is not None else 1_000_000
    path = resolve_scene(args.scene)
    chamber = load_scene(path)
    measured, ref, ref_band = _before_run(args, chamber)
    check_outputs(args.out, chamber.inputs + [Path(f) for f in [args.calibrate] + (args.reference or []) if f])
    kscene = simulate.KernelScene(chamber, estimator=args.estimator)
    if kscene.settings.sensors or kscene.settings.receivers:
        kscene.configure(**nee_options(args))
    with contextlib.ExitStack() as cluster_scope:
        executor = None
        if args.dask is not None:
            from .run import cluster
            client = cluster_scope.enter_context(cluster.dask_client(args.dask, threads=args.threads))
            executor = cluster.DaskChunks(client)
        if executor is None:    # numba compiles the kernel on a first run: said, and timed apart from tracing
            _compile_kernel(kscene, args.quiet)
        if ESTIMATORS[args.estimator].next_events:
            kscene.prune_next_events(threads=args.threads if executor is None else None)
        return _trace_and_write(args, path, chamber, kscene, measured, ref, ref_band, executor)


def cmd_compile(args) -> int:
    """``lpy-light compile``: the kernels ``run`` needs for ``args.estimator`` on ``args.scene`` compiled (or
    found in numba's cache, :func:`lpy_light.kernel.kernel_cache_dir`), and the arithmetic fingerprint that a
    run's summary gives; no photon traced, nothing written but the cache."""
    import time

    from .run import simulate
    from .chamber.scene import load_scene
    from .kernel import numba_cache_dir
    from .kernel.fingerprint import arithmetic_fingerprint

    start = time.perf_counter()
    chamber = load_scene(resolve_scene(args.scene))
    for name in args.estimator:
        simulate.compile_kernel(simulate.KernelScene(chamber, estimator=name), note=lambda text, name=name: print(
            "lpy-light: compiling the kernel of 'run --estimator %s' (once per version of lpy-light and numba) ..."
            % name, file=sys.stderr, flush=True))
    arithmetic_fingerprint()
    print("lpy-light: the kernel of 'run --estimator %s' is ready in %.1f s (cached in %s)"
          % (" / ".join(args.estimator), time.perf_counter() - start, numba_cache_dir()), file=sys.stderr, flush=True)
    return 0


def _compile_kernel(kscene, quiet: bool) -> None:
    """Compile the kernel for this run's estimator (first run only; loaded from numba's cache after),
    saying so while it compiles."""
    from .run import simulate

    said = []

    def note(text):
        said.append(text)
        if not quiet:
            print("lpy-light: " + text, file=sys.stderr, flush=True)

    seconds = simulate.compile_kernel(kscene, note=note)
    if said and not quiet:
        print("lpy-light: kernel compiled in %.1f s" % seconds, file=sys.stderr, flush=True)


def _trace_and_write(args, path, chamber, kscene, measured, ref, ref_band, executor=None) -> int:
    from .run import simulate
    from .chamber import units
    from .run.results import write_run

    stop, tracing = threading.Event(), [True]

    def on_term(signum, frame):
        # SIGTERM or a first Ctrl-C: finish the chunks in flight, write partial results, exit 130;
        # a second Ctrl-C while tracing stops at once (simulate.run keeps the chunks summed so far).
        # The handlers stay until main() returns, so a signal never cuts the writing of the results.
        if signum == signal.SIGINT and stop.is_set() and tracing[0]:
            raise KeyboardInterrupt
        stop.set()

    signal.signal(signal.SIGTERM, on_term)
    signal.signal(signal.SIGINT, on_term)
    try:
        if not args.quiet:
            goal = ("tracing %d photons" % args.photons if args.precision is None else
                    "tracing until every %s's σ ≤ %g %% (at most %.3g photons)"
                    % ("sensor" if len(chamber.sensors) else "organ", 100 * args.precision, args.photons))
            print("lpy-light: %s: %d triangles, %d sensors, %d band(s); %s"
                  % (path, len(chamber.triangles), len(chamber.sensors), chamber.n_bands, goal), file=sys.stderr)
        result = simulate.run(kscene, args.photons, seed=args.seed, threads=args.threads,
                              progress=None if args.quiet else simulate.progress_printer(),
                              stop=stop.is_set, precision=args.precision, executor=executor)
    finally:
        tracing[0] = False
    norm = units.scene_normalisation(chamber, result)
    extra, calibration, comparison = _after_run(args, chamber, result, norm, measured, ref, ref_band)
    if ESTIMATORS[args.estimator].next_events:
        ks = kscene.settings
        extra["next_events"] = {"picks": ks.picks, "images": ks.images, "images2": ks.images2, "zones": ks.zones,
                                "zones_built": int(len(kscene.zones.target_plane)), "control": ks.control,
                                "mirror_planes": int(kscene.mir_on.sum()),
                                "sources_off": [m.name for m, on in zip(kscene.materials, kscene.mat_nee) if not on]}
    if calibration is not None:
        norm = calibration.norm
    summary = write_run(args.out, chamber, result, norm, extra)
    if calibration is not None:
        from .run.results import atomic_write, csv_text
        atomic_write(Path(args.out) / "calibration.csv", csv_text(calibration.rows))
    if comparison is not None:
        print("lpy-light: %s vs %s (band %s): %s" % (path.name, ref.source, ref_band, comparison.line()))
        for profile in comparison.profiles:
            print("\n".join("lpy-light: " + line for line in profile.lines()))
    if args.plot:
        _plots(args, chamber, result, norm, comparison, ref, ref_band)
    if not args.quiet:
        for line in _what_it_means(args, chamber, result, summary, norm, executor):
            print("lpy-light: " + line, file=sys.stderr)
    return 130 if result.partial else 0


def _what_it_means(args, chamber, result, summary, norm, executor=None) -> list:
    """The lines a run ends with: how long, how precise, where the results are and what their columns hold."""
    from .chamber import units

    where = "" if executor is None else " on %d Dask worker(s) at %s" % (executor.workers, executor.address)
    lines = ["%d photons in %.2f s (%.3g photons/s, estimator %s)%s%s"
             % (result.photons, result.seconds, summary["photons_per_second"] or 0, result.estimator, where,
                " — PARTIAL (interrupted)" if result.partial else "")]
    sig = summary.get("relative_sigma")
    if sig is not None:
        at = sig["max_at"]
        goal = "" if args.precision is None else "; goal %g %% %s" % (
            100 * args.precision, "reached" if summary.get("precision_reached") else "NOT reached (cap %d photons: "
            "raise --photons)" % args.photons)
        lines.append("standard error per sensor and band: median %.2g %%, largest %.2g %% (sensor %d at %s %s, band %s)%s"
                     % (100 * sig["median"], 100 * sig["max"], at["sensor"],
                        ", ".join("%g" % x for x in at["position"]), chamber.unit, at["band"], goal))
    if len(chamber.sensors) and norm is not None:
        photons, std = result.sensors()
        value, _ = units.ppfd(photons, std, chamber.sensors.area * chamber.metres_per_unit ** 2, norm)
        mean = value.mean(axis=0)
        shown = ", ".join("%s nm %.4g" % (label, m) for label, m in list(zip(chamber.band_labels, mean))[:4])
        lines.append("mean ppfd over the %d sensors (µmol m-2 s-1): %s%s%s" % (
            len(chamber.sensors), shown, ", ..." if len(mean) > 4 else "",
            "" if norm.assumption != units.SPECTRUM_ASSUMPTION else
            " (the lamp spectrum's, which sets the units: the map's shape is the simulation's)"))
    what = ("ppfd ± ppfd_std in µmol m-2 s-1 per sensor and band" if norm is not None else
            "photons ± photons_std per sensor and band (no lamp spectrum in the scene: no µmol)")
    extra = " and sensors_derived.csv (PAR, R:FR)" if "derived" in summary else ""
    lines.append("results in %s: sensors.csv (%s)%s, summary.json (precision, energy closure, settings)"
                 % (args.out, what, extra))
    return lines


def _before_run(args, chamber):
    """Read and check what the run's results will be compared or calibrated with, before tracing."""
    from .report import reference
    from .chamber import units

    if args.plot:
        from .report.plots import require_matplotlib
        require_matplotlib()
    measured = None
    if args.calibrate is not None:
        if not Path(args.calibrate).is_file():
            raise InputError("calibration file not found", args.calibrate)
        chamber.calibration = (Path(args.calibrate), None)
    if args.calibrate_tolerance is not None:
        if not args.calibrate_tolerance > 0:
            raise InputError("--calibrate-tolerance must be > 0 (scene units)")
        if chamber.calibration is None:
            raise InputError("--calibrate-tolerance needs --calibrate FILE or a scene 'calibration'")
        chamber.calibration = (chamber.calibration[0], args.calibrate_tolerance)
    if chamber.calibration is not None:
        measured = units.read_measured(chamber.calibration[0], chamber, chamber.calibration[1])
    ref = band = None
    if args.reference_band is not None and args.reference is None:
        raise InputError("--reference-band needs --reference FILE")
    if args.reference is not None:
        labels = chamber.band_labels
        band = args.reference_band or ("655-665" if "655-665" in labels else labels[0])
        if band not in labels:
            raise InputError("--reference-band %s is not a band of the scene (%s)" % (band, ", ".join(labels)))
        refs = []
        for rpath in map(Path, args.reference):
            if not rpath.is_file():
                raise InputError("reference file not found", rpath)
            if rpath.suffix == ".csv" and not rpath.name.startswith("captor_result"):
                ref = reference.read_run(rpath, band=band)
            else:
                ref = reference.read(rpath)
            if len(ref.photons) != len(chamber.sensors):
                raise InputError("reference has %d sensors, the scene %d" % (len(ref.photons),
                                                                            len(chamber.sensors)), ref.source)
            refs.append(ref)
        ref = reference.average(refs)
    return measured, ref, band


def _after_run(args, chamber, result, norm, measured, ref, ref_band):
    """Calibration and comparison of a finished run: (summary extras, Calibration or None, Comparison or None)."""
    from .report import reference
    from .chamber import units

    extra = {}
    calibration = comparison = None
    if measured is not None:
        photons, std = result.sensors()
        calibration = units.calibrate(measured, photons, std, chamber.sensors.area * chamber.metres_per_unit ** 2,
                                      chamber.band_labels, fallback=norm)
        extra["calibration"] = calibration.summary
        if norm is not None:
            extra["spectrum_normalisation"] = {"how": norm.how, "assumption": norm.assumption,
                                               "scale": norm.scale.tolist(), "scale_std": norm.scale_std.tolist()}
    if ref is not None:
        photons, std = result.sensors()
        b = chamber.band_labels.index(ref_band)
        comparison = reference.compare(photons[:, b], std[:, b], result.photons, ref)
        comparison.profiles = reference.row_profiles(photons[:, b], std[:, b], ref, chamber.sensors.center,
                                                     chamber.sensors.normal, unit=chamber.unit)
        extra["reference"] = {"file": ref.source, "band": ref_band, "n_photons": ref.n_photons,
                              "within_4sigma": comparison.within_4sigma, "bias": comparison.bias,
                              "bias_std": comparison.bias_std, "rms": comparison.rms, "rms_noise": comparison.rms_noise,
                              "max_abs_z": float(abs(comparison.z).max()), "line": comparison.line(),
                              "rows": [{"plane": p.plane, "axis": p.axis, "slope": p.slope, "slope_std": p.slope_std,
                                        "position": p.position.tolist(), "ratio": p.ratio.tolist(),
                                        "ratio_std": p.ratio_std.tolist(), "sensors": p.count.tolist()}
                                       for p in comparison.profiles]}
    return extra, calibration, comparison


def _plots(args, chamber, result, norm, comparison, ref, ref_band):
    """--plot: maps of every sensor plane (ppfd when known, else photons), and of the difference to --reference."""
    from .report import plots, reference
    from .chamber import units
    from .run.results import derived_table

    if not len(chamber.sensors):
        logging.getLogger("lpy_light").warning("--plot: the scene has no sensors to map")
        return []
    photons, std = result.sensors()
    b = chamber.band_labels.index(ref_band) if ref_band is not None else 0
    area_m2 = chamber.sensors.area * chamber.metres_per_unit ** 2
    value = par = rfr = None
    if norm is not None:
        value, _ = units.ppfd(photons, std, area_m2, norm)
        derived = derived_table(chamber, result, norm)
        if derived and "par" in derived[0]:
            par = [row["par"] for row in derived]
        if derived and "r_fr" in derived[0]:
            rfr = [row["r_fr"] for row in derived]
    import numpy as np
    panels = plots.run_panels(chamber.band_labels, photons, value, None if par is None else np.array(par),
                              None if rfr is None else np.array(rfr))
    name = Path(chamber.source).stem
    paths = plots.sensor_maps(args.out, chamber.sensors.center, chamber.sensors.normal, panels, prefix="map",
                              title="%s, %d photons" % (name, result.photons), unit=chamber.unit)
    if comparison is not None:
        paths += plots.sensor_maps(args.out, chamber.sensors.center, chamber.sensors.normal,
                                   [("%s vs %s" % (ref_band, Path(ref.source).name), comparison.z,
                                     "(ours − reference) / σ")],
                                   prefix="diff", title="%s: %s" % (name, comparison.line()), unit=chamber.unit,
                                   diverging=True)
        columns = reference.row_profiles(photons[:, b], std[:, b], ref, chamber.sensors.center,
                                         chamber.sensors.normal, unit=chamber.unit, across=0)
        paths += plots.profile_plots(args.out, comparison.profiles, columns,
                                     title="%s vs %s (%s)" % (name, Path(ref.source).name if " + " not in ref.source
                                                              else "the references' average", ref_band))
    if not args.quiet:
        print("lpy-light: pictures: %s" % ", ".join(str(p) for p in paths), file=sys.stderr)
    return paths


def _calibrate_parser(sub):
    c = sub.add_parser("calibrate", help="fit a scene to a survey of measured readings (lamp outputs and "
                                         "positions, a diffuser's spread, walls' reflectance): write the fitted scene, "
                                         "a report and a picture (lpy_light.calibration.calibrate)")
    c.add_argument("scene", help="scene TOML file, or a built-in scene name")
    c.add_argument("survey", help="csv: the scene's sensor columns (X,Y,Z,rayon_capteur,Xnorm,Ynorm,Znorm) and one "
                                  "column per band (655-665 or ppfd_655-665), µmol m-2 s-1; optional 'row'")
    c.add_argument("--out", required=True, help="output folder: scene.toml (the fitted scene), report.md, "
                                                "calibration.json, sites.csv, rows.png")
    c.add_argument("--photons", type=_count, default=2_000_000,
                   help="photons per lamp run (default 2e6; every run uses the same seed)")
    c.add_argument("--seed", type=int, default=1, help="random seed of every run (default 1)")
    c.add_argument("--threads", type=int, default=None, help="threads (default: all cores)")
    c.add_argument("--tolerance", type=float, default=None, metavar="D",
                   help="how far a lamp may move, scene units (default: 30 mm)")
    c.add_argument("--check", metavar="HELD.csv", default=None,
                   help="a held-out survey of the same chamber (same columns), never fitted: report.md and "
                        "calibration.json give its rms before and after the fit, what the fit bought")
    c.add_argument("--no-plot", action="store_true", help="no rows.png")
    c.add_argument("--quiet", action="store_true", help="no progress lines")


def cmd_calibrate(args) -> int:
    """``lpy-light calibrate``: read and check everything, fit (:mod:`lpy_light.calibration.calibrate`), then write."""
    from .calibration import calibrate
    from .run import simulate
    from .chamber.scene import load_scene
    from .calibration.survey import read_survey

    if args.threads is not None and not 1 <= args.threads <= simulate.MAX_THREADS:
        raise InputError("--threads must be in 1..%d" % simulate.MAX_THREADS)
    if not 0 <= args.seed <= simulate.MAX_SEED:
        raise InputError("--seed must be a whole number in 0..2^63-1")
    if args.tolerance is not None and not args.tolerance > 0:
        raise InputError("--tolerance must be > 0 (scene units)")
    check_out_dir(args.out)
    path = resolve_scene(args.scene)
    chamber = load_scene(path)
    survey = read_survey(args.survey, chamber)
    held = None
    if args.check is not None:
        held = read_survey(args.check, chamber)
        missing = [b for b, m, h in zip(chamber.band_labels, survey.columns, held.columns) if m and not h]
        if missing:
            raise InputError("the held-out survey has no column for band(s) %s, which the survey measured"
                             % ", ".join(missing), args.check, 1)
    check_outputs(args.out, chamber.inputs + [Path(args.survey)] + ([Path(args.check)] if args.check else []))
    say = (lambda text: None) if args.quiet else (lambda text: print("lpy-light: " + text, file=sys.stderr, flush=True))
    cal = calibrate.calibrate(chamber, survey, photons=args.photons, seed=args.seed, threads=args.threads,
                              tolerance=args.tolerance, say=say, check=held)
    base = args.scene if args.scene in builtin_scenes() and not Path(args.scene).exists() else str(path.resolve())
    calibrate.write_outputs(args.out, cal, base, path.stem, plot=not args.no_plot)
    if not args.quiet:
        for b, before, after, sigma in zip(cal.bands, cal.cv_before, cal.cv_after, cal.cv_after_sigma):
            print("lpy-light: %-8s cross-validated rms %5.1f %% -> %5.1f ± %.1f %%"
                  % (b, 100 * before, 100 * after, 100 * sigma), file=sys.stderr)
        if cal.check is not None:
            for b, before, after, sigma in zip(cal.bands, cal.check["rms_before"], cal.check["rms_after"],
                                               cal.check["rms_after_sigma"]):
                print("lpy-light: %-8s held-out rms %5.1f %% -> %5.1f ± %.1f %%"
                      % (b, 100 * before, 100 * after, 100 * sigma), file=sys.stderr)
        for w in cal.warnings:
            print("lpy-light: warning: " + w, file=sys.stderr)
        print("lpy-light: wrote %s (the fitted scene: lpy-light run %s ...), report.md, calibration.json"
              % (Path(args.out) / "scene.toml", Path(args.out) / "scene.toml"), file=sys.stderr)
    return 0


def _grow_parser(sub):
    g = sub.add_parser("grow", help="grow an L-Py model and light it at every step: a model that calls "
                                    "LightModel.intercept() in EndEach, or any model with --organs; write organs.csv "
                                    "and pictures (needs L-Py and PlantGL, from conda)")
    g.add_argument("model", help=".lpy file")
    g.add_argument("--steps", type=_count, default=None, help="derivation steps (default: the model's derivation length)")
    g.add_argument("--photons", type=_count, default=None,
                   help="photons per step (default: the model's; with a precision, the most a step traces)")
    g.add_argument("--precision", default=None, metavar="REL|par=P,rfr=R",
                   help="what a step waits for before it stops: a relative σ on every target organ's PAR and "
                        "R:FR (0.04), or on what the rules read: par=0.03 (relative), rfr=0.02 (absolute), "
                        "LO-HI=0.05 (a band's ppfd, relative), comma-separated")
    g.add_argument("--seed", type=int, default=None, help="random seed of the light model (default: the model's)")
    g.add_argument("--estimator", choices=("auto", "nee", "field", "reuse"), default=None,
                   help="nee: every step traces the chamber's photons again; field: the light entering the plant's "
                        "region traced once into a field (renewed every 10 steps), each step's rays stay in the "
                        "region; auto: the first field's self-check against nee chooses the field where it bounds "
                        "the field's bias tightly and the field reaches the precision asked for less CPU, else nee "
                        "(chosen again as the plant doubles; summary.json says which and why); reuse: the "
                        "chamber's light traced once into a store and gathered at every organ each step (default: "
                        "the model's, else nee)")
    g.add_argument("--threads", type=int, default=None, help="threads (default: all cores)")
    g.add_argument("--verify", type=_count, default=None, metavar="N",
                   help="also light the first N lit steps by an independent nee run at the model's photons per step, "
                        "and compare every read organ's PAR and R:FR with the estimator's: verify.csv (per organ "
                        "and step), 'verify' in summary.json (bias ± σ for leaves and buds), a line on stderr")
    g.add_argument("--out", required=True, help="output folder")
    g.add_argument("--plot-every", type=_count, default=None, metavar="N",
                   help="also save plant_<step>.png every N steps (plant.png, the last step, is always saved)")
    g.add_argument("--set", action="append", default=[], metavar="NAME=VALUE",
                   help="set an extern of the model, e.g. --set PAR_MIN=20 (a Python literal, else text); repeatable")
    g.add_argument("--quiet", action="store_true", help="no progress lines")
    o = g.add_argument_group("lighting a model that does not call lpy-light (no edit to the model)")
    o.add_argument("--organs", action="append", default=None, metavar="MODULE=MATERIAL[/BACK]",
                   help="a module whose shapes are organs, and its optical material (a name from the scene's "
                        "tables; FRONT/BACK for a leaf's two sides); repeat for each module")
    o.add_argument("--at", default=None, metavar="X,Y,Z",
                   help="where the plant's origin stands, in chamber units (default: the scene's plant_position)")
    o.add_argument("--scene", default="angers-12bands", help="scene file or built-in name (default angers-12bands)")
    o.add_argument("--plant-unit", default="cm", help="unit of the model's coordinates (default cm)")
    o.add_argument("--every", type=_count, default=1, metavar="N",
                   help="light steps N, 2N, ... and always the last (default 1: every step)")
    o.add_argument("--targets", default=None, metavar="MODULE[,MODULE...]",
                   help="modules whose light is estimated (default: every --organs module)")


def _is_a_sensor_list(path) -> bool:
    """Whether a csv in ``--out`` is a sensor list (an input: SEC2's discs or quads), not a result."""
    from .chamber.sensors import _DISC_COLUMNS, _QUAD_COLUMNS
    try:
        with open(path, "rb") as f:
            head = f.read(4096).decode("utf-8-sig", errors="replace").split("\n")[0]
    except OSError:
        return False
    names = {c.strip().strip('"').strip() for c in head.replace(";", ",").replace("\t", ",").split(",")}
    return set(_DISC_COLUMNS) <= names or set(_QUAD_COLUMNS) <= names


def _remove_stale_results(out):
    """After bad input, ``--out`` holds no results: those of an earlier run there would pass for this one's.
    A sensor list that happens to be called ``sensors.csv`` there (``--out`` = the scene's folder) is an
    input, and stays."""
    from .run.results import RESULT_FILES
    if not out or not Path(out).is_dir():
        return
    for name in RESULT_FILES:
        path = Path(out) / name
        if path.is_file() and not (path.suffix == ".csv" and _is_a_sensor_list(path)):
            try:
                path.unlink()
            except OSError:
                pass


def _out_in_argv(argv) -> str | None:
    """The ``--out`` folder of a command line argparse refused (``--out DIR``, ``--out=DIR``, ``--ou DIR``)."""
    for i, a in enumerate(argv):
        name, eq, value = a.partition("=")
        if len(name) >= 3 and "--out".startswith(name):
            return value if eq else (argv[i + 1] if i + 1 < len(argv) else None)
    return None


def main(argv=None) -> int:
    logging.basicConfig(format="lpy-light: warning: %(message)s", level=logging.WARNING)
    argv = list(sys.argv[1:] if argv is None else argv)
    passthrough = []
    try:
        if argv[:1] == ["sweep"]:       # options the sweep does not know go to every run
            args, passthrough = _parser().parse_known_args(argv)
        else:
            args = _parser().parse_args(argv)
    except SystemExit as exc:
        if exc.code == 2 and argv[:1] == ["run"]:     # refused by argparse: --out holds no results either
            _remove_stale_results(_out_in_argv(argv[1:]))
        raise
    saved = {sig: signal.getsignal(sig) for sig in (signal.SIGTERM, signal.SIGINT)}
    try:
        with preserved_locale():      # a command leaves the process as it found it (PlantGL sets the C locale)
            return _command(args, passthrough)
    except LpyLightError as exc:
        print("lpy-light: error: %s" % exc, file=sys.stderr)
        _remove_stale_results(getattr(args, "out", None))
        return 2
    except KeyboardInterrupt:
        print("lpy-light: interrupted", file=sys.stderr)
        return 130
    except OSError as exc:     # the machine, not the input: a full disk, a permission; one line all the same
        print("lpy-light: error: %s%s" % (exc.filename + ": " if isinstance(exc.filename, str) else "",
                                          exc.strerror or exc), file=sys.stderr)
        return 1
    finally:
        if threading.current_thread() is threading.main_thread():
            for sig, handler in saved.items():
                if handler is not None:
                    signal.signal(sig, handler)


def cmd_sweep(args, passthrough) -> int:
    """``lpy-light sweep``: see :mod:`lpy_light.run.sweep`."""
    from .run import sweep

    check_out_dir(args.out)
    if args.workers is not None and not 1 <= args.workers <= 1024:
        raise InputError("--workers must be in 1..1024")
    if args.workers is not None and args.dask is not None and not args.dask.startswith("local"):
        raise InputError("--workers is for sweeps on this machine; a cluster's workers are its own")
    tasks = sweep.tasks_for(args.inputs, args.set, passthrough)
    for t in tasks[:1] + tasks[-1:]:      # parsed as each run will parse it: argparse's one-line error, exit 2
        _parser().parse_args(t.argv + ["--out", "OUT"])
    report = None if args.quiet else (lambda line: print("lpy-light: sweep: %s" % line, file=sys.stderr, flush=True))
    previous = signal.signal(signal.SIGTERM, signal.default_int_handler)     # SIGTERM stops it as Ctrl-C does
    try:
        if args.dask is None:
            return sweep.run_sweep(tasks, args.out, workers=args.workers, report=report)
        from .run import cluster
        address = "local:%d" % args.workers if args.workers and args.dask == "local" else args.dask
        with cluster.dask_client(address, threads=1 if cluster.local_workers(address) else None) as client:
            return sweep.run_sweep(tasks, args.out, client=client, report=report)
    finally:
        signal.signal(signal.SIGTERM, previous)


def _command(args, passthrough) -> int:
    """Run the parsed command; its exit status."""
    if args.command == "scenes":
        for name, path in builtin_scenes().items():
            print("%-22s %s" % (name, path))
        return 0
    if args.command == "run":
        return cmd_run(args)
    if args.command == "compile":
        return cmd_compile(args)
    if args.command == "grow":
        from .plant.grow import cmd_grow
        return cmd_grow(args)
    if args.command == "sweep":
        return cmd_sweep(args, passthrough)
    if args.command == "calibrate":
        return cmd_calibrate(args)
    return 1


if __name__ == "__main__":
    sys.exit(main())
