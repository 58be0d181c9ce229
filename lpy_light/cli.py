"""The ``lpy-light`` command line.

    lpy-light run SCENE.toml [--photons N] [--seed S] [--threads T] --out DIR
              [--calibrate MEASURED.csv] [--plot] [--reference REF]
    lpy-light grow MODEL.lpy --steps N [--photons P] --out DIR   # needs L-Py (conda)
    lpy-light scenes                       # list the built-in scenes

SCENE may be a path or the name of a built-in scene (``angers``,
``angers-12bands``, ...).  Bad input exits with status 2 and one line
``lpy-light: error: FILE:LINE: what was expected``; no results are written.
"""
from __future__ import annotations

import argparse
import logging
import os
import signal
import sys
import threading
from pathlib import Path

from .errors import InputError, LpyLightError

DATA = Path(__file__).parent / "data"
MAX_NEE_PICKS = 4096      # shadow rays per vertex; 0 (every target) is the way to ask for more


def builtin_scenes() -> dict:
    return {p.stem: p for p in sorted(DATA.glob("*/*.toml"))}


def resolve_scene(name: str) -> Path:
    path = Path(name)
    if path.exists():
        return path
    scenes = builtin_scenes()
    if name in scenes:
        return scenes[name]
    raise InputError("scene file not found (built-in scenes: %s)" % ", ".join(scenes), name)


def check_out_dir(out):
    """Refuse an output folder that cannot be written before any photon is traced."""
    if not str(out).strip():
        raise InputError("--out must name a folder (got an empty string)")
    out = Path(out)
    if out.exists() and not out.is_dir():
        raise InputError("--out must be a folder; this is a file", out)
    parent = out
    while not parent.exists():
        parent = parent.parent
    if not parent.is_dir() or not os.access(parent, os.W_OK | os.X_OK):
        raise InputError("--out: cannot write in %s" % parent, out)


def check_outputs(out, inputs):
    """Refuse a run whose results would overwrite one of its own input files (``--out`` = the scene's folder
    with a sensor list named ``sensors.csv``, say)."""
    from .results import RESULT_FILES
    read = {Path(p).resolve() for p in inputs}
    for name in RESULT_FILES:
        target = (Path(out) / name).resolve()
        if target in read:
            raise InputError("--out would overwrite the input file %s with this run's %s: choose another folder"
                             % (target, name), out)


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
                   help="photons (all bands travel together; default 1e6, or a cap of 1e10 with --precision)")
    r.add_argument("--precision", type=float, default=None, metavar="REL",
                   help="stop when every sensor's relative σ is at most REL (e.g. 0.01); --photons is then a cap")
    r.add_argument("--seed", type=int, default=1, help="random seed (default 1); results depend on it alone")
    r.add_argument("--threads", type=int, default=None, help="threads (default: all cores)")
    r.add_argument("--out", required=True, help="output folder")
    r.add_argument("--estimator", choices=("weighted", "nee", "analog"), default="weighted",
                   help="weighted (default: expected absorption, bands share events without any weight "
                        "growing), nee (weighted + next-event tallies on sensors and receivers: far fewer "
                        "photons for the same precision) or analog (SEC2's counting: one photon, one event)")
    r.add_argument("--quiet", action="store_true", help="no progress lines")
    r.add_argument("--nee-picks", type=int, default=1, metavar="K",
                   help="with --estimator nee: targets per next event, drawn at random (default 1; 0 = all)")
    r.add_argument("--nee-images", type=float, default=0.5, metavar="K",
                   help="with --estimator nee: next events through a perfect mirror per vertex, on average (default "
                        "0.5; 0 = none: light whose last bounce is specular is then counted)")
    r.add_argument("--nee-zones", type=float, default=0.3, metavar="K",
                   help="with --estimator nee: two-step next events per vertex through the surface right beside a "
                        "disc sensor (within 4 radii of a wall or table), on average (default 0.3; 0 = none: that "
                        "light then comes only from the photons that land there)")
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
    r.add_argument("--reference", metavar="FILE", default=None,
                   help="compare with a reference (SEC2 mesures .txt, photon-mapping captor_result csv or a run's "
                        "sensors.csv): prints the comparison, and with --plot maps the difference in σ units")
    r.add_argument("--reference-band", metavar="LABEL", default=None,
                   help="band compared with the reference (default 655-665 when the scene has it, else the first)")
    sub.add_parser("scenes", help="list the built-in scenes")
    _grow_parser(sub)
    return p


def cmd_run(args) -> int:
    from . import simulate, units
    from .results import write_run
    from .scene import load_scene

    if args.threads is not None and not 1 <= args.threads <= simulate.MAX_THREADS:
        raise InputError("--threads must be in 1..%d" % simulate.MAX_THREADS)
    if not 0 <= args.seed <= simulate.MAX_SEED:
        raise InputError("--seed must be a whole number in 0..2^63-1")
    check_out_dir(args.out)
    if args.precision is not None and not 0 < args.precision < 1:
        raise InputError("--precision must be a relative σ in (0, 1), e.g. 0.01")
    if args.photons is None:
        args.photons = 10_000_000_000 if args.precision is not None else 1_000_000
    path = resolve_scene(args.scene)
    chamber = load_scene(path)
    measured, ref, ref_band = _before_run(args, chamber)
    check_outputs(args.out, chamber.inputs + [Path(f) for f in (args.calibrate, args.reference) if f])
    kscene = simulate.KernelScene(chamber, estimator=args.estimator)
    if not 0 <= args.nee_picks <= MAX_NEE_PICKS:
        raise InputError("--nee-picks must be in 0..%d (0: every target at every vertex)" % MAX_NEE_PICKS)
    kscene.nee_picks = args.nee_picks
    if not 0 <= args.nee_images <= 64:
        raise InputError("--nee-images must be in 0..64")
    kscene.nee_images = args.nee_images
    if not 0 <= args.nee_zones <= 64:
        raise InputError("--nee-zones must be in 0..64")
    kscene.nee_zones = args.nee_zones
    kscene.nee_control = not args.no_nee_control
    if args.estimator == "nee":
        kscene.prune_next_events(threads=args.threads)
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
            print("lpy-light: %s: %d triangles, %d sensors, %d band(s); tracing %d photons"
                  % (path, len(chamber.triangles), len(chamber.sensors), chamber.n_bands, args.photons),
                  file=sys.stderr)
        result = simulate.run(kscene, args.photons, seed=args.seed, threads=args.threads,
                              progress=None if args.quiet else simulate.progress_printer(),
                              stop=stop.is_set, precision=args.precision)
    finally:
        tracing[0] = False
    norm = None
    if chamber.spectrum is not None and chamber.bands is not None and len(chamber.sensors):
        photons, std = result.sensors()
        norm = units.from_spectrum(photons, std, chamber.sensors.area * chamber.metres_per_unit ** 2,
                                   chamber.spectrum, chamber.bands)
    extra, calibration, comparison = _after_run(args, chamber, result, norm, measured, ref, ref_band)
    if args.estimator == "nee":
        extra["next_events"] = {"picks": kscene.nee_picks, "images": kscene.nee_images, "zones": kscene.nee_zones,
                                "zones_built": int(len(kscene.zones.target_plane)), "control": kscene.nee_control,
                                "mirror_planes": int(kscene.mir_on.sum()),
                                "sources_off": [m.name for m, on in zip(kscene.materials, kscene.mat_nee) if not on]}
    if calibration is not None:
        norm = calibration.norm
    summary = write_run(args.out, chamber, result, norm, extra)
    if calibration is not None:
        from .results import atomic_write, csv_text
        atomic_write(Path(args.out) / "calibration.csv", csv_text(calibration.rows))
    if comparison is not None:
        print("lpy-light: %s vs %s (band %s): %s" % (path.name, ref.source, ref_band, comparison.line()))
    if args.plot:
        _plots(args, chamber, result, norm, comparison, ref, ref_band)
    if not args.quiet and "relative_sigma" in summary:
        sig = summary["relative_sigma"]
        at = sig["max_at"]
        print("lpy-light: relative σ per sensor and band: median %.3g %%, largest %.3g %% (sensor %d at %s %s, "
              "band %s)%s" % (100 * sig["median"], 100 * sig["max"], at["sensor"],
                              ", ".join("%g" % x for x in at["position"]), chamber.unit, at["band"],
                              "" if args.precision is None else "; --precision %g %s" % (
                                  args.precision, "reached" if summary.get("precision_reached") else "NOT reached")),
              file=sys.stderr)
    if not args.quiet:
        print("lpy-light: %d photons in %.2f s (%.3g photons/s)%s; results in %s"
              % (result.photons, result.seconds, summary["photons_per_second"] or 0,
                 " — PARTIAL (interrupted)" if result.partial else "", args.out), file=sys.stderr)
    return 130 if result.partial else 0


def _before_run(args, chamber):
    """Read and check what the run's results will be compared or calibrated with, before tracing."""
    from . import reference, units

    if args.plot:
        from .plots import require_matplotlib
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
        rpath = Path(args.reference)
        if not rpath.is_file():
            raise InputError("reference file not found", rpath)
        if rpath.suffix == ".csv" and not rpath.name.startswith("captor_result"):
            ref = reference.read_run(rpath, band=band)
        else:
            ref = reference.read(rpath)
        if len(ref.photons) != len(chamber.sensors):
            raise InputError("reference has %d sensors, the scene %d" % (len(ref.photons), len(chamber.sensors)),
                             ref.source)
    return measured, ref, band


def _after_run(args, chamber, result, norm, measured, ref, ref_band):
    """Calibration and comparison of a finished run: (summary extras, Calibration or None, Comparison or None)."""
    from . import reference, units

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
        extra["reference"] = {"file": ref.source, "band": ref_band, "n_photons": ref.n_photons,
                              "within_4sigma": comparison.within_4sigma, "bias": comparison.bias,
                              "bias_std": comparison.bias_std, "rms": comparison.rms, "rms_noise": comparison.rms_noise,
                              "max_abs_z": float(abs(comparison.z).max()), "line": comparison.line()}
    return extra, calibration, comparison


def _plots(args, chamber, result, norm, comparison, ref, ref_band):
    """--plot: maps of every sensor plane (ppfd when known, else photons), and of the difference to --reference."""
    from . import plots, units
    from .results import derived_table

    if not len(chamber.sensors):
        logging.getLogger("lpy_light").warning("--plot: the scene has no sensors to map")
        return []
    photons, std = result.sensors()
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
    if not args.quiet:
        print("lpy-light: pictures: %s" % ", ".join(str(p) for p in paths), file=sys.stderr)
    return paths


def _grow_parser(sub):
    g = sub.add_parser("grow", help="grow an L-Py model that calls LightModel.intercept() in EndEach; "
                                    "write organs.csv and a picture of the last step (needs L-Py, from conda)")
    g.add_argument("model", help=".lpy file")
    g.add_argument("--steps", type=_count, required=True, help="derivation steps")
    g.add_argument("--photons", type=_count, default=None, help="photons per step (default: the model's)")
    g.add_argument("--threads", type=int, default=None, help="threads (default: all cores)")
    g.add_argument("--out", required=True, help="output folder")
    g.add_argument("--quiet", action="store_true", help="no progress lines")


def cmd_grow(args) -> int:
    from . import light as lightmod
    from .lpy import require_lpy
    from .results import atomic_write, csv_text, json_text

    path = Path(args.model)
    if not path.is_file():
        raise InputError("L-Py model not found", path)
    lpy = require_lpy()
    before = len(lightmod.MODELS)
    variables = {"STEPS": args.steps}
    if args.photons:
        variables["PHOTONS"] = args.photons
    try:
        lsys = lpy.Lsystem(str(path), variables)
    except Exception as exc:    # L-Py reports syntax errors as generic exceptions
        raise InputError("L-Py could not read the model: %s" % str(exc).splitlines()[0], path) from None
    if len(lightmod.MODELS) == before:
        raise InputError("the model creates no lpy_light.LightModel (see lsystems/rose.lpy)", path)
    model = lightmod.MODELS[-1]
    if args.photons:
        model.photons = args.photons
    if args.threads:
        model.threads = args.threads
    rows, steps = [], []

    def on_step(step, organs):
        rows.extend(lightmod.organ_rows(step))
        steps.append({"step": step.step, "organs": len(step.organs), "triangles": step.triangles,
                      "seconds": step.seconds, "tessellated": step.tessellated, "reused": step.reused})
        if not args.quiet:
            print("  step %d: %d organs, %d triangles, %.2f s (%d organs re-tessellated, %d reused)"
                  % (step.step, len(step.organs), step.triangles, step.seconds, step.tessellated, step.reused),
                  file=sys.stderr, flush=True)

    model.on_step = on_step
    partial = False
    lstring = lsys.axiom
    try:
        for i in range(args.steps):
            lstring = lsys.derive(lstring, i, 1)
    except KeyboardInterrupt:
        partial = True
    out = Path(args.out)
    out.mkdir(parents=True, exist_ok=True)
    atomic_write(out / "organs.csv", csv_text(rows))
    summary = {"model": str(path), "steps": steps, "partial": partial, "photons_per_step": model.photons,
               "bands": model.chamber.band_labels, "plant_unit_m": model.scale * model.chamber.metres_per_unit}
    atomic_write(out / "summary.json", json_text(summary))
    if model.last_step is not None:
        try:
            from .plant_view import plant_picture
            plant_picture(out / "plant.png", model.last_organs, model.last_step.organs,
                          title="%s, step %d" % (path.stem, model.last_step.step))
        except ImportError:
            logging.getLogger("lpy_light").warning("matplotlib not installed: no plant.png")
    return 130 if partial else 0


def _is_a_sensor_list(path) -> bool:
    """Whether a csv in ``--out`` is a sensor list (an input: SEC2's discs or quads), not a result."""
    from .sensors import _DISC_COLUMNS, _QUAD_COLUMNS
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
    from .results import RESULT_FILES
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
    try:
        args = _parser().parse_args(argv)
    except SystemExit as exc:
        if exc.code == 2 and argv[:1] == ["run"]:     # refused by argparse: --out holds no results either
            _remove_stale_results(_out_in_argv(argv[1:]))
        raise
    saved = {sig: signal.getsignal(sig) for sig in (signal.SIGTERM, signal.SIGINT)}
    try:
        if args.command == "scenes":
            for name, path in builtin_scenes().items():
                print("%-22s %s" % (name, path))
            return 0
        if args.command == "run":
            return cmd_run(args)
        if args.command == "grow":
            return cmd_grow(args)
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
    return 1


if __name__ == "__main__":
    sys.exit(main())
