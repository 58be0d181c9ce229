"""How close the photon kernel gets to Embree's raw ray rate, on the Angers chamber.

Four rates, on 1 and 2 threads (like with like):

(a) ``embreex`` — embreex's own ``EmbreeScene.run(origins, directions, output=1)`` on the chamber's
    triangles (a plain scene: no filters, both sides, no sensors).  Its ``run()`` is one Cython loop
    of ``rtcIntersect1`` calls on the calling thread (no TBB inside); "2 threads" runs two Python
    threads on halves of the batch, which only helps if ``run()`` releases the GIL (the printed
    scaling says whether it does).
(b) ``binding`` — a minimal numba loop calling ``rtcIntersect1`` through the kernel's own binding
    (``kernel.embree`` + ``kernel.ptr``), no physics, writing t, primID, geomID per ray:
    ``binding-plain`` on the same plain scene as (a), ``binding-kernel`` on the kernel's own
    scene (one-sided filter on every triangle, 240 transparent-sensor quads with their filter).
(c) ``kernel`` — ``simulate.run`` on the Angers chamber (estimator ``weighted``, 655-665 nm):
    rays/s = ``Result.rays / Result.seconds`` (photon rays; this estimator casts no shadow rays);
(d) photons/s of the same runs.

The rays of (a) and (b) are the same set, distributed like photon paths: photons leave the lamps
(isotropic, from the lamp axes) and are walked through the kernel's scene with the materials'
scattering probabilities (band mean of R and T; diffuse, mirror or straight-through as the event
table says) — so origins lie on the lamps and on the surfaces photons actually reach, in the
proportions they reach them.  The walk is preparation, not timed.

Timings are best-of-``repeat`` wall-clock (the machine may be shared).  Ratios kernel / raw are
printed per thread count; the target is >= 0.8.  ``--plant`` adds the procedural rose of
``benchmarks/rose.py`` (its last stage, ~21 000 triangles) to all four, as organs in the kernel.

    .venv/bin/python benchmarks/raw_embree.py [--threads 1 2] [--rays 2e6] [--photons 2e6] [--repeat 5] [--plant]

``--steps`` measures instead each estimator's own rays (:mod:`kernel.raylog`): a step is run on one thread with
the ray log open, and every ray it cast is cast again, by kind, in a bare loop through our binding -- on a plain
scene of the same triangles (``bare``: no filters, no sensors, no physics) and on the scene the kernel traced
(``filtered``: its one-sided filter and sensor quads).  Cases: ``nee`` on the procedural rose (516 organs, the
12-band chamber; photon rays, next-event rays to organs), the ``field`` on the same rose (the field traced once,
then a step's rays and bounces in its region), ``weighted`` on Angers (photon rays), and ``nee`` on Angers'
sensors (the README's main job: photon rays and shadow rays).  Per case: the step's rays per CPU second against
the bare loop's on the same rays, and each kind's bare and filtered rates:

    .venv/bin/python benchmarks/raw_embree.py --steps [--cases nee-rose field-rose weighted-angers nee-angers]
                                              [--photons 3e5] [--repeat 3]
"""
from __future__ import annotations

import argparse
import json
import math
import sys
import time
from concurrent.futures import ThreadPoolExecutor
from pathlib import Path

import numpy as np
from numba import njit

from lpy_light.run import simulate
from lpy_light.chamber.scene import resolve_scene
from lpy_light.kernel import embree
from lpy_light.kernel.embree import ARGS, GEOM_ID, INVALID_ID, PRIM_ID, RAYHIT, TFAR
from lpy_light.kernel.ptr import call_ptr3, load_f32, load_u32
from lpy_light.kernel.rays import set_ray
from lpy_light.chamber.scene import load_scene

_TFAR_MAX = 3.0e38
STEP_CASES = ("nee-rose", "field-rose", "weighted-angers", "nee-angers")


# ---- (b): the raw loop through our binding -------------------------------------------------
@njit(nogil=True, cache=False)     # not cached: numba would not see edits to the kernel it calls
def trace_rays(scene, intersect_fn, scratch, org, dirs, out_t, out_prim, out_geom):
    """Closest hit of every ray (float32 origins/directions, (n, 3)); t = inf and ids -1 on a miss."""
    rh = scratch + RAYHIT
    args = scratch + ARGS
    for i in range(org.shape[0]):
        set_ray(scratch, org[i, 0], org[i, 1], org[i, 2], dirs[i, 0], dirs[i, 1], dirs[i, 2], _TFAR_MAX)
        call_ptr3(intersect_fn, scene, rh, args)
        gid = load_u32(rh + GEOM_ID)
        if gid == INVALID_ID:
            out_t[i] = np.inf
            out_prim[i] = -1
            out_geom[i] = -1
        else:
            out_t[i] = load_f32(rh + TFAR)
            out_prim[i] = load_u32(rh + PRIM_ID)
            out_geom[i] = gid


def _binding_pass(handle, org, dirs, threads):
    """Trace all rays on ``threads`` threads (contiguous slices); returns (seconds, t, prim, geom)."""
    n = len(org)
    out_t = np.empty(n, np.float32)
    out_prim = np.empty(n, np.int64)
    out_geom = np.empty(n, np.int64)
    scratches = [embree.new_scratch() for _ in range(threads)]
    fn = embree.intersect1_address()
    bounds = np.linspace(0, n, threads + 1).astype(int)

    def part(k):
        a, b = bounds[k], bounds[k + 1]
        trace_rays(handle, fn, scratches[k].ctypes.data, org[a:b], dirs[a:b], out_t[a:b], out_prim[a:b],
                   out_geom[a:b])

    t0 = time.perf_counter()
    if threads == 1:
        part(0)
    else:
        with ThreadPoolExecutor(threads) as pool:
            list(pool.map(part, range(threads)))
    return time.perf_counter() - t0, out_t, out_prim, out_geom


# ---- rays distributed like photon paths ----------------------------------------------------
def photon_like_rays(kscene, n_rays, seed=12345, max_depth=50):
    """(origins, directions) float32 (n, 3): a walk of photons from the lamps through ``kscene``.

    Each bounce is traced with the kernel's scene (one-sided surfaces as in the kernel); the event
    at a hit is drawn with the band-mean probabilities of the material's event table."""
    rng = np.random.default_rng(seed)
    em = kscene.chamber.emitters
    prob = np.stack([m.events for m in kscene.materials]).mean(axis=2)     # (M, 5)
    cum = np.cumsum(prob, axis=1)
    normal, mat = kscene.tri_normal, kscene.tri_mat[:, 0]
    geom_offset = kscene.geom_offset
    offset = kscene.chamber.physics.offset
    out_o, out_d, total = [], [], 0
    while total < n_rays:
        m = max(1024, int((n_rays - total) / 2.2))
        e = rng.choice(len(em.kind), size=m, p=em.power / em.power.sum())
        if not np.all(em.kind[e] == 0):
            raise ValueError("photon_like_rays handles line lamps only (the Angers chamber's)")
        f = rng.random(m)[:, None]
        o = em.data[e, 0] + f * (em.data[e, 1] - em.data[e, 0])
        z = 1 - 2 * rng.random(m)
        phi = 2 * np.pi * rng.random(m)
        r = np.sqrt(np.maximum(0, 1 - z * z))
        d = np.stack([r * np.cos(phi), r * np.sin(phi), z], 1)
        for depth in range(max_depth + 1):
            if not len(o):
                break
            o32, d32 = o.astype(np.float32), d.astype(np.float32)
            out_o.append(o32)
            out_d.append(d32)
            total += len(o)
            _, t, prim, geom = _binding_pass(kscene.scene.handle, o32, d32, 1)
            hit = (geom >= 0) & (geom != embree.GEOM_SENSORS)
            o, d, t, prim, geom = o[hit], d[hit], t[hit].astype(float), prim[hit], geom[hit]
            tri = prim + geom_offset[geom]
            n = normal[tri]
            back = np.einsum("ij,ij->i", d, n) > 0
            n[back] *= -1
            p = o + t[:, None] * d
            u = rng.random(len(p))
            ev = (u[:, None] >= cum[mat[tri]][:, :4]).sum(1)          # 0..4 as the kernel's events
            keep = ev < 4
            p, d, n, ev, o = p[keep], d[keep], n[keep], ev[keep], o[keep]
            k = len(p)
            # cosine lobe about ±n
            side = np.where((ev == 0) | (ev == 1), 1.0, -1.0)
            a = np.where(np.abs(n[:, :1]) < 0.9, [[1.0, 0, 0]], [[0, 1.0, 0]])
            tb = np.cross(n, a)
            tb /= np.linalg.norm(tb, axis=1, keepdims=True)
            bb = np.cross(n, tb)
            u1, u2 = rng.random(k), rng.random(k)
            rr, ph = np.sqrt(u1), 2 * np.pi * u2
            lz = np.sqrt(1 - u1)
            cos_dir = (rr * np.cos(ph))[:, None] * tb + (rr * np.sin(ph))[:, None] * bb + lz[:, None] * n
            new_d = np.where((ev == 0)[:, None], cos_dir, 0.0)
            new_d = np.where((ev == 2)[:, None], -cos_dir, new_d)
            mirror = d - 2 * np.einsum("ij,ij->i", d, n)[:, None] * n
            new_d = np.where((ev == 1)[:, None], mirror, new_d)
            new_d = np.where((ev == 3)[:, None], d, new_d)
            eps = side * offset * (np.abs(p).max(1) + np.abs(o).max(1))
            o, d = p + eps[:, None] * n, new_d / np.linalg.norm(new_d, axis=1, keepdims=True)
    org, dirs = np.concatenate(out_o)[:n_rays], np.concatenate(out_d)[:n_rays]
    perm = np.random.default_rng(seed + 1).permutation(len(org))   # no ordering advantage to either side
    return np.ascontiguousarray(org[perm]), np.ascontiguousarray(dirs[perm])


# ---- (a): embreex ----------------------------------------------------------------------------
def _embreex_scene(triangles):
    from embreex import rtcore_scene
    from embreex.mesh_construction import TriangleMesh

    scene = rtcore_scene.EmbreeScene()
    mesh = TriangleMesh(scene, np.ascontiguousarray(triangles, dtype=np.float32))
    return scene, mesh


def _embreex_pass(scene, org, dirs, threads):
    bounds = np.linspace(0, len(org), threads + 1).astype(int)

    def part(k):
        a, b = bounds[k], bounds[k + 1]
        return scene.run(org[a:b], dirs[a:b], output=1)

    t0 = time.perf_counter()
    c0 = time.process_time()
    if threads == 1:
        res = [part(0)]
    else:
        with ThreadPoolExecutor(threads) as pool:
            res = list(pool.map(part, range(threads)))
    return time.perf_counter() - t0, time.process_time() - c0, res


# ---- everything -------------------------------------------------------------------------------
def _kernel_scene(scene, plant):
    """The kernel's scene (estimator weighted) and its triangles (kernel order): the chamber, with the
    procedural rose of ``benchmarks/rose.py`` at its last stage on the table when ``plant``."""
    if not plant:
        chamber = load_scene(resolve_scene(scene))
        ks = simulate.KernelScene(chamber, "weighted")
        return ks, chamber.triangles[ks.order]
    from lpy_light.plant.light import LightModel
    from rose import LEAF_MATERIAL, rose

    model = LightModel(scene, plant_unit="cm", estimator="weighted", lamp_flux=[1.0],
                       organs={"Leaf": LEAF_MATERIAL, "Internode": LEAF_MATERIAL[0], "Bud": LEAF_MATERIAL[0]})
    organs = model.organs_from_meshes(rose(4, 4))
    model.kscene.set_organs(organs, model.materials)
    return model.kscene, model.kscene.tri_verts


def measure(threads=(1, 2), rays: int = 1_000_000, photons: int = 1_000_000, repeat: int = 3,
            scene: str = "angers", seed: int = 1, verbose: bool = False, plant: bool = False) -> dict:
    """Raw Embree rates (embreex, our binding) and the kernel's, per thread count; best of ``repeat``.

    Returns ``{"rays": ..., "photons": ..., "rays_per_photon": ..., "by_threads": {T: {...}}}``
    where each entry holds ``embreex``, ``binding_plain``, ``binding_kernel``, ``kernel`` (rays/s,
    wall clock), ``photons_per_s``, the ratios ``kernel_vs_*``, ``embreex_cpu_per_wall`` (≈ T when
    ``run()`` runs on T threads at once), and the same rates per CPU-second of the process under
    ``per_cpu_second`` with their ratios ``cpu_kernel_vs_*``.
    """
    def say(*a):
        if verbose:
            print(*a, flush=True)

    ks, tris = _kernel_scene(scene, plant)
    plain = embree.EmbreeScene(two_sided=tris)           # same triangles, no filters, no sensors
    ex_scene, ex_mesh = _embreex_scene(tris)
    say("scene %s: %d triangles (%d sensors in the kernel's scene)" % (scene, len(tris), ks.n_sensors))
    t0 = time.perf_counter()
    org, dirs = photon_like_rays(ks, int(rays), seed=seed + 12344)
    say("%d photon-like rays prepared in %.1f s" % (len(org), time.perf_counter() - t0))

    # warm-ups (compilation, caches); the two raw paths must agree on the plain scene
    _binding_pass(plain.handle, org[:1000], dirs[:1000], 1)
    s, t_b, p_b, _ = _binding_pass(plain.handle, org[:20000], dirs[:20000], 1)
    _, _, r = _embreex_pass(ex_scene, org[:20000], dirs[:20000], 1)
    agree = float(np.mean(r[0]["primID"] == np.where(p_b < 0, -1, p_b)))
    say("binding and embreex agree on %.4f of the closest hits (plain scene)" % agree)
    simulate.run(ks, 2000, seed=seed, threads=1)

    out = {"scene": scene + (" + rose (%d organs)" % len(ks.organs) if plant else ""), "triangles": len(tris),
           "rays": int(len(org)), "photons": int(photons), "repeat": int(repeat),
           "agreement_plain": agree, "by_threads": {}}
    for T in threads:
        best, cpu_best = {}, {}
        cpu_wall = []

        def keep(name, n, wall, cpu):
            best[name] = max(best.get(name, 0), n / wall)
            cpu_best[name] = max(cpu_best.get(name, 0), n / cpu)

        for _ in range(repeat):
            wall, cpu, _ = _embreex_pass(ex_scene, org, dirs, T)
            cpu_wall.append(cpu / wall)
            keep("embreex", len(org), wall, cpu)
            for name, handle in (("binding_plain", plain.handle), ("binding_kernel", ks.scene.handle)):
                c0 = time.process_time()
                wall = _binding_pass(handle, org, dirs, T)[0]
                keep(name, len(org), wall, time.process_time() - c0)
            c0 = time.process_time()
            res = simulate.run(ks, int(photons), seed=seed, threads=T)
            cpu = time.process_time() - c0
            keep("kernel", res.rays, res.seconds, cpu)
            keep("photons_per_s", res.photons, res.seconds, cpu)
            out["rays_per_photon"] = res.rays / res.photons
        best["embreex_cpu_per_wall"] = float(np.median(cpu_wall))
        for raw in ("embreex", "binding_plain", "binding_kernel"):
            best["kernel_vs_" + raw] = best["kernel"] / best[raw]
            best["cpu_kernel_vs_" + raw] = cpu_best["kernel"] / cpu_best[raw]
        best["per_cpu_second"] = cpu_best
        out["by_threads"][T] = best
        say("threads %d: %s" % (T, json.dumps({k: (round(v, 3) if v < 100 else round(v)) for k, v in best.items()
                                               if not isinstance(v, dict)})))
    plain.close()
    return out


def report(out) -> str:
    lines = ["%s, %d triangles, %d photon-like rays, kernel: %d photons, weighted, %.2f rays/photon; "
             "best of %d" % (out["scene"], out.get("triangles", 0), out["rays"], out["photons"],
                             out["rays_per_photon"], out["repeat"]),
             "%-8s %14s %14s %14s %14s %14s" % ("threads", "embreex", "binding plain", "binding kern.", "kernel",
                                                "photons/s")]
    for T, b in out["by_threads"].items():
        lines.append("%-8s %11.2f M/s %11.2f M/s %11.2f M/s %11.2f M/s %11.2f M/s"
                     % (T, b["embreex"] / 1e6, b["binding_plain"] / 1e6, b["binding_kernel"] / 1e6,
                        b["kernel"] / 1e6, b["photons_per_s"] / 1e6))
    lines.append("ratios kernel / raw, wall clock (target >= 0.8):")
    for T, b in out["by_threads"].items():
        lines.append("  %s thread(s): vs embreex %.2f, vs binding plain %.2f, vs binding on the kernel's scene %.2f"
                     "   (embreex run(): CPU/wall %.2f)"
                     % (T, b["kernel_vs_embreex"], b["kernel_vs_binding_plain"], b["kernel_vs_binding_kernel"],
                        b["embreex_cpu_per_wall"]))
    lines.append("the same per CPU-second of the process (steadier on a shared machine):")
    for T, b in out["by_threads"].items():
        c = b["per_cpu_second"]
        lines.append("  %s thread(s): embreex %.2f, binding plain %.2f, binding kernel %.2f, kernel %.2f M rays/CPU-s, "
                     "%.2f M photons/CPU-s; kernel / raw: %.2f, %.2f, %.2f"
                     % (T, c["embreex"] / 1e6, c["binding_plain"] / 1e6, c["binding_kernel"] / 1e6, c["kernel"] / 1e6,
                        c["photons_per_s"] / 1e6, b["cpu_kernel_vs_embreex"], b["cpu_kernel_vs_binding_plain"],
                        b["cpu_kernel_vs_binding_kernel"]))
    return "\n".join(lines)


# ---- each estimator's own rays, cast again ------------------------------------------------------
@njit(nogil=True, cache=False)
def cast_logged(scene, intersect_fn, occluded_fn, scratch, rows, kind, occluded):
    """Cast again the logged rays (``rows`` (n, 8) float32, :mod:`kernel.raylog`) of kind ``kind``, each as it
    was cast (origin, direction, tfar); ``occluded``: with rtcOccluded1, else rtcIntersect1.  Returns how many
    met something (so that nothing is optimised away)."""
    rh = scratch + RAYHIT
    args = scratch + ARGS
    fn = occluded_fn if occluded else intersect_fn
    met = 0
    for i in range(rows.shape[0]):
        if rows[i, 7] != kind:
            continue
        set_ray(scratch, rows[i, 0], rows[i, 1], rows[i, 2], rows[i, 3], rows[i, 4], rows[i, 5], rows[i, 6])
        call_ptr3(fn, scene, rh, args)
        if occluded:
            met += load_f32(rh + TFAR) < 0.0
        else:
            met += load_u32(rh + GEOM_ID) != INVALID_ID
    return met


class _SceneTap:
    """Keeps the triangles of every :class:`kernel.embree.EmbreeScene` built while it is on (the field's region is
    built, traced and released inside a step): ``scenes`` holds (one_sided, two_sided, sensors) per scene."""

    def __init__(self):
        self.scenes = []
        self._init = embree.EmbreeScene.__init__

    def __enter__(self):
        tap, init = self, self._init

        def keep(scene, one_sided=None, two_sided=None, sensors=None):
            tap.scenes.append((one_sided, two_sided, sensors))
            init(scene, one_sided, two_sided, sensors)

        embree.EmbreeScene.__init__ = keep
        return self

    def __exit__(self, *exc):
        embree.EmbreeScene.__init__ = self._init


def _rose_model(estimator, photons, seed=1):
    from lpy_light.plant.light import LightModel
    from rose import LEAF_MATERIAL, rose

    model = LightModel("angers-12bands", photons=int(photons), plant_unit="cm", estimator=estimator, threads=1,
                       targets=("Leaf", "Bud"), seed=seed,
                       organs={"Leaf": LEAF_MATERIAL, "Internode": LEAF_MATERIAL[0], "Bud": LEAF_MATERIAL[0]})
    plant = rose(4, 4)
    organs = model.organs_from_meshes({k: (m, mat, mod) for k, (m, mat, mod) in plant.items()})
    return model, organs


def step_of(case, photons):
    """``case`` (:data:`STEP_CASES`) made ready on one thread (compiled, its pilot and the field's first tracing
    done): ``step()`` runs one more step of it.  Its :class:`KernelScene` is ``step.kscene``."""
    if case in ("nee-rose", "field-rose"):
        model, organs = _rose_model(case.split("-")[0], photons)
        model.run(organs)                                  # compile, pilot, the field's first tracing
        ks = model.kscene

        def step():
            model.run(organs)
    else:
        estimator = case.split("-")[0]
        ks = simulate.KernelScene(load_scene(resolve_scene("angers")), estimator)
        if ks.settings.sensors:                            # as lpy-light run does
            ks.prune_next_events(threads=1)
        simulate.run(ks, 20000, seed=2, threads=1)

        def step():
            simulate.run(ks, int(photons), seed=1, threads=1)
    step.kscene = ks
    return step


def _run_case(case, photons):
    """Run one step of ``case`` on one thread with the ray log open.  Returns (CPU seconds of the step, rows of
    the log, rays cast, {kind: (two_sided triangles of a bare scene, EmbreeScene as the kernel traced)})."""
    from lpy_light.kernel import raylog

    step = step_of(case, photons)
    ks = step.kscene
    raylog.open_log(int(12 * photons) + 1_000_000)
    with _SceneTap() as tap:
        c0 = time.process_time()
        step()
        cpu = time.process_time() - c0
    rows, cast = raylog.close_log()
    kernel_tris = ks.tri_verts
    scenes = {k: (kernel_tris, ks.scene) for k in raylog.KINDS}
    if tap.scenes and case.startswith("field"):           # the scene of the field's region
        one, two, _ = tap.scenes[-1]
        tris = np.concatenate([t for t in (one, two) if t is not None])
        scenes[raylog.RAY_FIELD] = (tris, embree.EmbreeScene(one_sided=one, two_sided=two))
    return cpu, rows, cast, scenes


def measure_steps(cases, photons: float = 3e5, repeat: int = 3, verbose: bool = False) -> dict:
    """Each case's step against a bare loop on its own rays (see the module doc).  Returns {case: {...}}."""
    from lpy_light.kernel import raylog

    out = {}
    for case in cases:
        cpu, rows, cast, scenes = _run_case(case, photons)
        if len(rows) < cast:
            raise RuntimeError("the ray log held %d of %d rays: fewer --photons" % (len(rows), cast))
        scratch = embree.new_scratch()
        fn_i, fn_o = embree.intersect1_address(), embree.occluded1_address()
        kinds, bare_total, filt_total = {}, 0.0, 0.0
        for kind, name in raylog.KINDS.items():
            n = int(np.sum(rows[:, 7] == kind))
            if n == 0:
                continue
            tris, kernel_scene = scenes[kind]
            plain = embree.EmbreeScene(two_sided=tris)
            occl = kind in raylog.OCCLUDED
            cast_logged(plain.handle, fn_i, fn_o, scratch.ctypes.data, rows[:1000], kind, occl)   # compile, warm
            best = {}
            for label, handle in (("bare", plain.handle), ("filtered", kernel_scene.handle)):
                for _ in range(repeat):
                    c0 = time.process_time()
                    cast_logged(handle, fn_i, fn_o, scratch.ctypes.data, rows, kind, occl)
                    best[label] = min(best.get(label, math.inf), time.process_time() - c0)
            plain.close()
            kinds[name] = {"rays": n, "bare_cpu_s": best["bare"], "filtered_cpu_s": best["filtered"],
                           "bare_rate": n / best["bare"], "filtered_rate": n / best["filtered"]}
            bare_total += best["bare"]
            filt_total += best["filtered"]
        out[case] = {"photons": int(photons), "rays": int(cast), "step_cpu_s": cpu, "step_rate": cast / cpu,
                     "bare_cpu_s": bare_total, "bare_rate": cast / bare_total, "filtered_cpu_s": filt_total,
                     "ratio_vs_bare": bare_total / cpu, "embree_share": filt_total / cpu, "kinds": kinds}
        if verbose:
            print(report_steps({case: out[case]}), flush=True)
    return out


def report_steps(out) -> str:
    lines = []
    for case, r in out.items():
        lines.append("%s: %d photons, %d rays on one thread; step %.2f CPU s = %.2f M rays/CPU-s; the same rays in a "
                     "bare loop %.3f CPU s = %.2f M rays/CPU-s: step / bare %.2f (target >= 0.5); Embree as the kernel "
                     "calls it (filters, sensors) %.3f CPU s, %.0f %% of the step"
                     % (case, r["photons"], r["rays"], r["step_cpu_s"], r["step_rate"] / 1e6, r["bare_cpu_s"],
                        r["bare_rate"] / 1e6, r["ratio_vs_bare"], r["filtered_cpu_s"], 100 * r["embree_share"]))
        for name, k in r["kinds"].items():
            lines.append("    %-10s %9d rays  bare %6.2f M/CPU-s  filtered %6.2f M/CPU-s  (filters cost %.2fx)"
                         % (name, k["rays"], k["bare_rate"] / 1e6, k["filtered_rate"] / 1e6,
                            k["bare_rate"] / k["filtered_rate"]))
    return "\n".join(lines)


def main(argv=None):
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--threads", type=int, nargs="+", default=[1, 2])
    ap.add_argument("--rays", type=float, default=2e6)
    ap.add_argument("--photons", type=float, default=2e6)
    ap.add_argument("--repeat", type=int, default=5)
    ap.add_argument("--scene", default="angers")
    ap.add_argument("--plant", action="store_true",
                    help="add the procedural rose of benchmarks/rose.py (516 organs, ~21 000 triangles)")
    ap.add_argument("--json", default=None, help="also write the numbers to this file")
    ap.add_argument("--steps", action="store_true", help="each estimator's own rays against a bare loop")
    ap.add_argument("--cases", nargs="+", default=list(STEP_CASES), choices=STEP_CASES)
    args = ap.parse_args(argv)
    if args.steps:
        out = measure_steps(args.cases, args.photons if "--photons" in " ".join(argv or sys.argv) else 3e5,
                            args.repeat, verbose=True)
        if args.json:
            Path(args.json).parent.mkdir(parents=True, exist_ok=True)
            Path(args.json).write_text(json.dumps(out, indent=2, default=float) + "\n")
        return
    out = measure(tuple(args.threads), int(args.rays), int(args.photons), args.repeat, args.scene, verbose=True,
                  plant=args.plant)
    print(report(out))
    if args.json:
        Path(args.json).parent.mkdir(parents=True, exist_ok=True)
        Path(args.json).write_text(json.dumps(out, indent=2, default=float) + "\n")


if __name__ == "__main__":
    sys.exit(main())
