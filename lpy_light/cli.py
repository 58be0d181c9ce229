"""The ``lpy-light`` command line.

    lpy-light run SCENE.toml [--photons N] [--seed S] [--threads T] --out DIR
    lpy-light grow MODEL.lpy --steps N [--photons P] --out DIR   # needs L-Py (conda)
    lpy-light scenes                       # list the built-in scenes

SCENE may be a path or the name of a built-in scene (``angers``,
``angers-12bands``, ...).  Bad input exits with status 2 and one line
``lpy-light: error: FILE:LINE: what was expected``; no results are written.
"""
from __future__ import annotations

import argparse
import json
import logging
import os
import signal
import sys
import threading
from pathlib import Path

from .errors import InputError, LpyLightError

DATA = Path(__file__).parent / "data"


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
    out = Path(out)
    if out.exists() and not out.is_dir():
        raise InputError("--out must be a folder; this is a file", out)
    parent = out
    while not parent.exists():
        parent = parent.parent
    if not parent.is_dir() or not os.access(parent, os.W_OK | os.X_OK):
        raise InputError("--out: cannot write in %s" % parent, out)


def _count(text: str) -> int:
    try:
        value = float(text)
    except ValueError:
        raise argparse.ArgumentTypeError("expected a number, got %r" % text) from None
    if not value >= 1 or value != int(value) or value > 1e15:
        raise argparse.ArgumentTypeError("expected a whole number >= 1, got %r" % text)
    return int(value)


def _parser() -> argparse.ArgumentParser:
    p = argparse.ArgumentParser(prog="lpy-light", description="Light interception in a modelled growth chamber.")
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
    kscene = simulate.KernelScene(chamber, estimator=args.estimator)
    if args.nee_picks < 0:
        raise InputError("--nee-picks must be >= 0")
    kscene.nee_picks = args.nee_picks
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
    summary = write_run(args.out, chamber, result, norm)
    if not args.quiet:
        print("lpy-light: %d photons in %.2f s (%.3g photons/s)%s; results in %s"
              % (result.photons, result.seconds, summary["photons_per_second"] or 0,
                 " — PARTIAL (interrupted)" if result.partial else "", args.out), file=sys.stderr)
    return 130 if result.partial else 0


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
    from .results import atomic_write, csv_text

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
    atomic_write(out / "summary.json", json.dumps(summary, indent=2, default=float) + "\n")
    if model.last_step is not None:
        try:
            from .plant_view import plant_picture
            plant_picture(out / "plant.png", model.last_organs, model.last_step.organs,
                          title="%s, step %d" % (path.stem, model.last_step.step))
        except ImportError:
            logging.getLogger("lpy_light").warning("matplotlib not installed: no plant.png")
    return 130 if partial else 0


def main(argv=None) -> int:
    logging.basicConfig(format="lpy-light: warning: %(message)s", level=logging.WARNING)
    args = _parser().parse_args(argv)
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
