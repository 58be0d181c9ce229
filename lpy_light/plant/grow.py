"""``lpy-light grow``: an L-Py model derived step by step, its organs lit inside the chamber, the results written
as the run goes (``organs.csv`` step by step, ``summary.json``, pictures).

A model that makes its own :class:`~lpy_light.plant.light.LightModel` is lit by it (its ``EndEach`` calls
``intercept``); one that knows nothing of lpy-light is lit from outside (``--organs MODULE=MATERIAL ... --at
X,Y,Z``).  The parser is :mod:`lpy_light.cli`'s.
"""
from __future__ import annotations

import dataclasses
import logging
import math
import signal
import sys
import threading
from contextlib import contextmanager, nullcontext
from pathlib import Path

from ..errors import InputError
from ..run.results import check_out_dir, machine


def _organ_specs(items) -> dict:
    """``--organs Leaf=FeuilleVieille_Sup/FeuilleVieille_Inf`` → ``{"Leaf": ("FeuilleVieille_Sup", ...)}``."""
    organs = {}
    for item in items:
        module, eq, material = item.partition("=")
        module, material = module.strip(), material.strip()
        if not eq or not module or not material:
            raise InputError("--organs expects MODULE=MATERIAL or MODULE=FRONT/BACK, got %r" % item)
        sides = [m.strip() for m in material.split("/")]
        if len(sides) > 2 or not all(sides):
            raise InputError("--organs %s: expected one material or FRONT/BACK, got %r" % (module, material))
        organs[module] = sides[0] if len(sides) == 1 else tuple(sides)
    return organs


def _point(text, what) -> tuple:
    try:
        xyz = tuple(float(x) for x in text.split(","))
    except ValueError:
        xyz = ()
    if len(xyz) != 3 or not all(map(math.isfinite, xyz)):
        raise InputError("%s expects X,Y,Z (three numbers), got %r" % (what, text))
    return xyz


def _outside_model(args, path):
    """The light model of ``grow --organs``: built here, for a model that knows nothing of lpy-light."""
    from .light import LightModel
    from ..chamber.scene import UNITS

    if args.plant_unit not in UNITS:
        raise InputError("--plant-unit must be one of %s" % ", ".join(UNITS))
    organs = _organ_specs(args.organs)
    targets = None if args.targets is None else [t.strip() for t in args.targets.split(",") if t.strip()]
    return LightModel(args.scene, organs=organs, photons=args.photons or 1_000_000, precision=args.precision,
                      estimator=args.estimator or "nee",
                      seed=1 if args.seed is None else args.seed, threads=args.threads, plant_unit=args.plant_unit,
                      position=None if args.at is None else _point(args.at, "--at"), parameter=None, targets=targets)


def extern_values(sets) -> dict:
    """``["PAR_MIN=20", "SCENE=angers"]`` → ``{"PAR_MIN": 20, "SCENE": "angers"}``: Python literals, else text."""
    import ast
    out = {}
    for text in sets:
        name, eq, value = text.partition("=")
        if not eq or not name.strip().isidentifier():
            raise InputError("--set %s: expected NAME=VALUE (an extern of the model)" % text)
        try:
            out[name.strip()] = ast.literal_eval(value.strip())
        except (ValueError, SyntaxError):
            out[name.strip()] = value.strip()
    return out


@contextmanager
def _ctrl_c_noted():
    """Within the block, a Ctrl-C raises KeyboardInterrupt as usual and is also noted (the Event yielded): the
    growth loop must stop even where the KeyboardInterrupt is lost -- raised inside a rule L-Py's C++ called,
    or turned into a SystemError by numba's cache loader (a grow interrupted at the wrong moment ran to its end,
    or ended with a traceback)."""
    noted = threading.Event()
    if threading.current_thread() is not threading.main_thread():
        yield noted
        return

    def on_ctrl_c(signum, frame):
        noted.set()
        raise KeyboardInterrupt

    previous = signal.signal(signal.SIGINT, on_ctrl_c)
    try:
        yield noted
    finally:
        signal.signal(signal.SIGINT, previous)


def cmd_grow(args) -> int:
    from . import light as lightmod
    from .lpy import require_lpy
    from .precision import parse_goal
    from .verify import VERIFY_COLUMNS, summary_line
    from ..run.results import CsvStream, atomic_write, json_text

    path = Path(args.model)
    if not path.is_file():
        raise InputError("L-Py model not found", path)
    check_out_dir(args.out)
    try:
        goal = parse_goal(args.precision)      # checked again against the model's bands
    except InputError as exc:                  # named as the user wrote it: "--precision rfr: ..."
        raise InputError("--" + exc.reason) from None
    args.precision = None if goal is None else goal.given
    if args.threads is not None and not 1 <= args.threads <= 1024:
        raise InputError("--threads must be in 1..1024")
    outside = args.organs is not None
    if not outside and (args.at is not None or args.targets is not None):
        raise InputError("--at and --targets go with --organs (lighting a model from outside)")
    lpy = require_lpy()
    before = len(lightmod.MODELS)
    variables = {} if outside else {k: v for k, v in (("STEPS", args.steps), ("PHOTONS", args.photons),
                                                     ("PRECISION", args.precision), ("SEED", args.seed)) if v}
    variables.update(extern_values(args.set))
    try:
        lsys = lpy.Lsystem(str(path), variables)
    except Exception as exc:    # L-Py reports syntax errors as generic exceptions
        raise InputError("L-Py could not read the model: %s" % str(exc).splitlines()[0], path) from None
    steps = args.steps or lsys.derivationLength
    if outside:
        model = _outside_model(args, path)
    elif len(lightmod.MODELS) == before:
        raise InputError("the model creates no lpy_light.LightModel: add one (see lsystems/rose.lpy), or light it "
                         "from outside with --organs MODULE=MATERIAL ... --at X,Y,Z", path)
    else:
        model = lightmod.MODELS[-1]
        for name, value in (("photons", args.photons), ("precision", args.precision), ("seed", args.seed),
                            ("threads", args.threads)):
            if value is not None:
                setattr(model, name, lightmod._photons(value) if name == "photons" else value)
    if args.estimator is not None and (args.estimator != model.estimator or model.auto is not None):
        model.use_estimator(args.estimator)
    if getattr(args, "verify", None):
        model.verify = args.verify
    out = Path(args.out)
    summaries, pictures = [], []
    out.mkdir(parents=True, exist_ok=True)
    organs_csv = CsvStream(out / "organs.csv", lightmod.ORGAN_COLUMNS)      # step by step: memory stays flat
    verify_csv = CsvStream(out / "verify.csv", VERIFY_COLUMNS) if model.verify else nullcontext()

    def on_step(step, organs):
        organs_csv.write(lightmod.organ_rows(step))
        if step.comparison:
            verify_csv.write(step.comparison)
        roles = [light.role for light in step.organs.values()]
        summaries.append({"step": step.step, "organs": len(step.organs), "targets": roles.count("target"),
                          "shading_only": roles.count("shading only"), "not_reached": roles.count(lightmod.NOT_REACHED),
                          "triangles": step.triangles,
                          "photons": step.photons, "seconds": step.seconds, "tessellated": step.tessellated,
                          "reused": step.reused, **step.extra})
        if args.plot_every and organs and (step.step + 1) % args.plot_every == 0:
            pictures.append(_plant_picture(out / ("plant_%03d.png" % step.step), model, path, step, organs))
        if not args.quiet:
            reach = "" if "precision" not in step.extra else (
                ", σ goal %s" % ("reached" if step.extra["precision_reached"] else "NOT reached"))
            compiled = step.extra.get("compile_seconds", 0.0)
            compiled = "%.1f s of it compiling the kernel, first run only; " % compiled if compiled else ""
            print("  step %d: %d organs, %d triangles, %d photons%s, %.2f s (%s%d shapes re-tessellated, %d reused)"
                  % (step.step, len(step.organs), step.triangles, step.photons, reach, step.seconds, compiled,
                     step.tessellated, step.reused), file=sys.stderr, flush=True)
            if "field_check" in step.extra:
                check = step.extra["field_check"]
                print("    field %s checked against nee at %d photons (%.1f CPU s, %.2f of the field's): %s%s"
                      % (check["field"], check["photons"], check["cpu_s"], check["share_of_field"] or 0,
                         summary_line(check), "" if check["passed"] else " -- FAILED: lit by nee until renewed"),
                      file=sys.stderr, flush=True)
            if "auto" in step.extra:
                print("    estimator auto: %s -- %s" % (step.extra["auto"]["estimator"], step.extra["auto"]["why"]),
                      file=sys.stderr, flush=True)
            if "verify" in step.extra:
                print("    verify against nee at %d photons: %s" % (model.photons, summary_line(step.extra["verify"])),
                      file=sys.stderr, flush=True)

    model.on_step = on_step
    partial = False
    lstring = lsys.axiom
    derived = 0
    with organs_csv, verify_csv, model.warnings_once() as seen, _ctrl_c_noted() as ctrl_c:
        try:
            for i in range(steps):
                lstring = lsys.derive(lstring, i, 1)
                derived = i + 1
                if outside and ((i + 1) % args.every == 0 or i == steps - 1):
                    model.step = i
                    model.intercept(lstring, lsys.sceneInterpretation(lstring))
                if ctrl_c.is_set():      # a Ctrl-C whose KeyboardInterrupt L-Py's C++ did not pass on
                    raise KeyboardInterrupt
        except KeyboardInterrupt:
            partial = True
        except Exception:
            if not ctrl_c.is_set():
                raise
            partial = True               # ... or that arrived as another error (numba's cache loader: SystemError)
        if not outside and model.last_step is None and not partial:
            logging.getLogger("lpy_light").warning(
                "the model's LightModel was never called: call light.intercept(lstring, lscene) in EndEach, with "
                "frameDisplay(True) in StartEach")
    summary = {"model": str(path), "steps": summaries, "partial": partial, "photons_per_step": model.photons,
               "precision": model.precision, "lit_from_outside": outside,
               "bands": model.chamber.band_labels, "plant_unit_m": model.scale * model.chamber.metres_per_unit,
               "position": list(map(float, model.position)), "scene": str(model.chamber.source),
               "seed": model.seed, "estimator": model.estimator,
               "auto": None if model.auto is None else model.auto.choices,
               "settings": dataclasses.asdict(model.kscene.settings), "warnings": seen.summary(),
               "machine": machine()}
    if model.keeper is not None:
        kept = getattr(model.keeper, "store", None) or getattr(model.keeper, "field", None)
        summary[model.estimator] = dataclasses.asdict(model.keeper.settings)
        summary["stores_built"] = model.keeper.built
        summary["store"] = None if kept is None else kept.describe()
        if hasattr(model.keeper, "checks"):
            summary["field_checks"] = model.keeper.checks      # each field's self-check against nee
    if model.verify:
        summary["verify"] = model.verification.summary(model)
    if model.last_step is not None and model.last_organs:
        pictures.append(_plant_picture(out / "plant.png", model, path, model.last_step, model.last_organs))
    summary["pictures"] = [p for p in pictures if p]
    atomic_write(out / "summary.json", json_text(summary))
    if not args.quiet:
        for line in seen.repeated_lines():
            print("lpy-light: " + line, file=sys.stderr)
        if model.verify:
            v = summary["verify"]
            print("lpy-light: verify: %s against nee at %d photons, %d step(s): %s -> verify.csv"
                  % (model.verification.label(model), model.photons, v["steps"], summary_line(v)), file=sys.stderr)
        files = ", ".join(["summary.json"] + (["verify.csv"] if model.verify else [])
                          + [Path(p).name for p in summary["pictures"]])
        if partial:
            print("lpy-light: interrupted after %d of %d derivation step(s), %d lit; partial results (\"partial\": "
                  "true in summary.json) in %s: organs.csv, %s" % (derived, steps, len(summaries), out, files),
                  file=sys.stderr)
        else:
            print("lpy-light: %d step(s) lit; results in %s: organs.csv (per organ and band: ppfd ± ppfd_std "
                  "µmol m-2 s-1, absorbed µmol s-1, par, rfr), %s" % (len(summaries), out, files), file=sys.stderr)
    return 130 if partial else 0


def _plant_picture(path, model, source, step, organs):
    """A PNG of the organs coloured by PAR (fixed scale): its path, or None without matplotlib."""
    try:
        from .plant_view import plant_picture
        plant_picture(path, organs, step.organs, title="%s, step %d" % (Path(source).stem, step.step),
                      top=model.colour_top)
        return str(path)
    except ImportError:
        logging.getLogger("lpy_light").warning("matplotlib not installed: no %s" % Path(path).name)
        return None
