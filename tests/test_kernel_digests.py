"""The kernel's numbers, pinned bit for bit: a change meant to leave the physics alone (a refactor, a
faster loop) must leave every tally exactly as it was.

Each case traces a few photons with a fixed seed through a path of the kernel and digests the raw float64
arrays it returns (sums, sums of products between bands, counters, next-event statistics; for the rose,
each organ's numbers): sha256 of their bytes, so no float formatting is involved.  The cases cover the
Angers chamber with each estimator (``weighted``, ``nee`` with its pilot and the control variate, image and
zone events; ``analog``), the 12-band chamber (``nee``, and ``analog``: one path per band), a small room
with every emitter kind (line, point, polygon, cylinder, sphere), disc and quad sensors, a solid sensor,
a mirror and a Phong lobe, and the procedural rose of ``benchmarks/rose.py`` through
:class:`~lpy_light.light.LightModel` (organs from meshes, next events aimed at leaves and buds).

Results do not depend on the number of threads (by design), nor on the x86-64 machine: Embree's code path
is capped at AVX2 (``kernel.embree.DEVICE_CONFIG``), as its AVX-512 path rounds some hits differently.  What breaks this test:
any change to the arithmetic or to the order of random numbers in the kernel, or to how the scene is
turned into kernel arrays.  A change that is *meant* to alter the numbers updates the digests, printed by

    .venv/bin/python tests/test_kernel_digests.py
"""
from __future__ import annotations

import hashlib
import json
import os
import platform
import subprocess
import sys
from pathlib import Path

import numpy as np
import pytest

sys.path.insert(0, str(Path(__file__).parent))
sys.path.insert(0, str(Path(__file__).resolve().parents[1] / "benchmarks"))

from scenes import box, rad_polygon, write_scene  # noqa: E402

# a room that reaches every branch Angers does not: every emitter kind, quad sensors, a solid sensor
ROOM = ("void plastic grey\n0\n0\n5 0.5 0.5 0.5 0.3 0.1\n\n"
        "void mirror silver\n0\n0\n3 0.9 0.9 0.9\n\n"
        "void trans diffuser\n0\n0\n7 0.1 0.1 0.1 0 0 0.7 0.4\n\n"
        "void light lamp\n0\n0\n3 10 10 10\n\n"
        + box("grey", (0, 0, 0), (1000, 1000, 1100))
        + rad_polygon("silver", "mirror", [(990, 100, 100), (990, 100, 900), (990, 900, 900), (990, 900, 100)])
        + rad_polygon("diffuser", "sheet", [(200, 200, 950), (800, 200, 950), (800, 800, 950), (200, 800, 950)])
        + rad_polygon("lamp", "panel", [(100, 100, 1050), (100, 300, 1050), (300, 300, 1050), (300, 100, 1050)])
        + "lamp cylinder tube\n0\n0\n7 300 500 1020 700 500 1020 5\n\n"
        + "lamp sphere bulb\n0\n0\n4 800 800 1000 20\n\n")
SOLID = rad_polygon("grey", "block", [(600, 600, 300), (700, 600, 300), (700, 700, 300), (600, 700, 300)])
DISCS = "X,Y,Z,rayon_capteur,Xnorm,Ynorm,Znorm\n" + "".join(
    "%r,%r,%r,40.0,%r,%r,%r\n" % r for r in [(500.0, 500.0, 500.0, 0.0, 0.0, 1.0), (50.0, 500.0, 600.0, 1.0, 0.0, 0.0),
                                              (500.0, 960.0, 400.0, 0.0, 0.0, 1.0), (900.0, 500.0, 500.0, 1.0, 0.0, 0.0)])
QUADS = ("x0,y0,z0,x1,y1,z1,x2,y2,z2,x3,y3,z3\n"
         "200,200,200,300,200,200,300,300,200,200,300,200\n"
         "400,0.0,600,400,0.0,700,500,0.0,700,500,0.0,600\n")


def _room(folder: Path, lamps: str, specular: str) -> Path:
    write_scene(folder, ROOM)
    (folder / "discs.csv").write_text(DISCS)
    (folder / "quads.csv").write_text(QUADS)
    (folder / "solid.rad").write_text(SOLID)
    (folder / "scene.toml").write_text('geometry = "scene.rad"\nsensors = ["discs.csv", "quads.csv"]\n'
                                       'solid_sensors = "solid.rad"\n[physics]\nlamps = "%s"\nspecular = "%s"\n'
                                       % (lamps, specular))
    return folder / "scene.toml"


def _digest(arrays) -> str:
    h = hashlib.sha256()
    for a in arrays:
        a = np.ascontiguousarray(a)
        h.update(str((a.dtype.str, a.shape)).encode())
        h.update(a.tobytes())
    return h.hexdigest()


def _run(scene, estimator, photons, seed=3, picks=None, prune=True):
    """Trace as ``lpy-light run`` does (with ``nee``: the pilot that switches off blind sources first)."""
    from lpy_light import simulate
    from lpy_light.cli import resolve_scene
    from lpy_light.scene import load_scene

    chamber = load_scene(resolve_scene(str(scene)))
    ks = simulate.KernelScene(chamber, estimator)
    if picks is not None:
        ks.configure(picks=picks)
    if estimator == "nee" and prune:
        ks.prune_next_events(threads=2)
    r = simulate.run(ks, photons, seed=seed, threads=2)
    return _digest([r.tally, r.tally_prod, r.counters, r.nee_stats])


def _rose(photons, stage=2, stages=4, cones=None):
    """The rose's organs' numbers.  R:FR is read as the plain ratio of the tallies (``ratios.uncorrected``),
    the formula these digests were recorded with: its bias correction (issue 45) is arithmetic on the
    kernel's tallies, not the kernel, and the digests are to pin the kernel."""
    from lpy_light import ratios
    from lpy_light.light import LightModel
    from rose import LEAF_MATERIAL, rose

    model = LightModel("angers-12bands", photons=photons, plant_unit="cm", estimator="nee", threads=2,
                       lamp_flux=np.linspace(1.0, 2.0, 12), targets=["Leaf", "Bud"],
                       organs={"Leaf": LEAF_MATERIAL, "Internode": LEAF_MATERIAL[0], "Bud": LEAF_MATERIAL[0]},
                       cone_rays=cones)
    out = []
    for s in (stage - 1, stage):
        with ratios.uncorrected():
            step = model.run(model.organs_from_meshes(rose(s, stages)))
        for light in step.organs.values():
            out += [light.photons, light.photons_std, light.ppfd, light.ppfd_std, light.absorbed, light.absorbed_std,
                    np.array([light.par, light.par_std, light.rfr, light.rfr_std])]
    return _digest(out)


def cases(tmp: Path) -> dict:
    """Every case's callable (name → () → digest)."""
    line = lambda: _room(tmp / "room-line", "line", "mirror")
    lamb = lambda: _room(tmp / "room-lambertian", "lambertian", "phong")
    return {
        "angers-weighted": lambda: _run("angers", "weighted", 200_000),
        "angers-nee": lambda: _run("angers", "nee", 200_000),
        "angers-analog": lambda: _run("angers", "analog", 200_000),
        "angers-12bands-nee": lambda: _run("angers-12bands", "nee", 50_000),
        "angers-12bands-analog": lambda: _run("angers-12bands", "analog", 20_000),
        "room-line-nee": lambda: _run(line(), "nee", 100_000),
        "room-line-nee-all": lambda: _run(line(), "nee", 50_000, picks=0, prune=False),
        "room-line-weighted": lambda: _run(line(), "weighted", 100_000),
        "room-lambertian-nee": lambda: _run(lamb(), "nee", 100_000),
        "room-lambertian-analog": lambda: _run(lamb(), "analog", 100_000),
        "rose-nee": lambda: _rose(50_000),
        "rose-cones": lambda: _rose(50_000, cones=4.0),
    }


# x86-64 (CI's kind of machine).  History: first recorded on the kernel before its records (issue 29) and
# unchanged by them; the Angers cases then changed with physics.repeated_names = "last" (a scene change:
# SEC2's reading of repeated identifiers) and the rose with next events by solid angle near meshes
# (issue 24) -- both checked identical on main before and after merging the records; then the nee cases
# with mesh targets (the room's solid sensor, the rose) with mesh targets' own next events near them; then all
# of them with Embree's code path capped at AVX2 (``kernel.embree.DEVICE_CONFIG``): before, an AVX-512 machine
# and an AVX2 one gave different digests for the same code (the rose's differed between this project's machines);
# then the nee cases with mesh targets with organs' own events averaged over 2 samples, picks among organs by
# importance over clusters and organ zone events (issue 24): Angers unchanged; "rose-cones" added with the cone rays
# (kernel.cones, thirteenth session; a plant's default is none, so rose-nee is unchanged by them); then the two
# rose cases with the organ zones' solid angles in one compiled loop (kernel.organ_zones.zone_measures,
# fourteenth session): numpy's einsum and arctan2 round differently; the rose's organs differ by ≤ 2e-16
# relative (≤ 4e-15 σ), 339 of 516 bitwise the same (3e5 photons, 5 steps); then the two rose cases with no
# BLAS call left on the way from meshes to numbers (fifteenth session: kernel.vectors, LightResult.combination,
# benchmarks/rose.py's rotations): before, numpy's BLAS kernel, which OpenBLAS picks by processor, changed the
# rose's digests between an AVX-512 Intel machine (SkylakeX) and an AMD one (Haswell kernel); then the two rose
# cases with points on closed meshes (the buds) drawn among the triangles facing the vertex (kernel.nee.facing_triangle),
# and with them the room's nee cases (its solid sensor is a one-sided mesh: the same points, its triangles' areas
# now from the targets' cumulative areas, which round differently); then the two rose cases with next events through
# a mirror to organs drawn by importance seen from the vertex's image, and cone rays from it, and organ zone events
# for the buds only, 0.25 per vertex, and (rose-cones) 0.1 events through a mirror where cone rays are on
# (sixteenth session); then angers-12bands-nee with a next event's weight summed over the bands before it is
# added to nee_stats, and rose-cones with a cone ray's coincident surfaces picked before asking whether the
# surface met is a target (as a photon picks: kernel.rays.first_hit; before, a non-target triangle with a
# coincident target ended the ray) (eighteenth session; a plant has no local rays by default, so rose-nee is
# as before); then rose-cones with a vertex's cone rays ∝ its photon's mean weight × the cones' share of its light,
# a quarter of that near a cluster (kernel.cones.ray_mean, nineteenth session; the kernel's other changes that
# session -- prefetched tally rows, loops over views -- left every digest as it was); then every case with two more
# counters (the organs' pick shares, kernel.tallies.C_PICK_SHARE: zero on sensors; the sensor cases' tallies are as
# before, their digests without the two counters as pinned before), and the rose's with picks as many as a vertex's
# pick share asks (kernel.nee.pick_share, twentieth session); then the two rose cases with the closed buds of
# translucent tissue (the rose's buds are a leaf's material) given their own surface in their organ zone
# (KernelScene._own_zones, twenty-third session: their inside light from every vertex)
PINNED = {
    "angers-weighted": "036eb93dbdf7e4cbb16323e070de78b414723ab9c0c43d82d1087d002a894081",
    "angers-nee": "6680107761b56e1d6a5c7ffcaf46aae7a662ac1d30b0991a8c4fa030a4c145ae",
    "angers-analog": "20fb0f87faf0a150769d74fed3444d5c55f3165c492aa217cf2592654ce74667",
    "angers-12bands-nee": "027916e6c30c7baa0eed16af815d8845b229d09c24b47c045e985942de34f8f1",
    "angers-12bands-analog": "62528eab1129ba12f4a72472b3b3b6cd989fd5befa3a3807577a88a7381fe7c1",
    "room-line-nee": "8131a63d9cd497533a5d26a1359228008b36e9240d8675b874ff7987eb80e4c5",
    "room-line-nee-all": "4f2c47bb00d9c7da87e4b9561ec345420a57a08ba8a92a367d69006275df8de0",
    "room-line-weighted": "78a8eb623f8896e764d6e179bbeac9a23296507a92da155db9eb19c91912f74c",
    "room-lambertian-nee": "3c595582268478ce82586a3f83ee069e4db2c27d60762cb72ef9c6b9eaa95a4d",
    "room-lambertian-analog": "cc89df8d5b9bd4290aa827d0fcfaab224ee1e242c05425dcd2f4942469039aff",
    "rose-nee": "2522a14427e588283226980e6f4c2a3bddf54acb0f128a1f6db144b3641a66ff",
    "rose-cones": "3e55b037d4ba4bda9d8920fac4461e2d89a0800b999ad14bac909a118438a2ea",
}


@pytest.mark.parametrize("case", list(cases(Path("."))))
def test_outputs_bitwise_as_pinned(case, tmp_path):
    assert cases(tmp_path)[case]() == PINNED.get(case), "%s: the kernel's numbers changed" % case


@pytest.mark.skipif(platform.machine().lower() not in ("x86_64", "amd64"), reason="OpenBLAS's x86-64 kernels")
@pytest.mark.parametrize("kernel", ["Prescott", "Nehalem"])
def test_outputs_the_same_under_another_blas_kernel(kernel):
    """The same numbers whichever BLAS kernel numpy runs: OpenBLAS picks its kernel by processor (Haswell,
    SkylakeX, Zen, ...), and they round a dot product differently.  The cases run again in a child process with
    a kernel forced (``OPENBLAS_CORETYPE``: two that every x86-64-v2 processor runs, and that rounded the rose
    differently); before the mesh path's BLAS calls were removed (``kernel.vectors``), the rose's digests
    differed between them.  (This holds for the numpy of ``.venv``; under numpy 1.26's OpenBLAS, in the L-Py
    venv, trimesh's own ``icosphere`` and ``cylinder``, which build the procedural rose, already differ by kernel.)"""
    env = dict(os.environ, OPENBLAS_CORETYPE=kernel)
    out = subprocess.run([sys.executable, __file__], env=env, capture_output=True, text=True, timeout=600)
    assert out.returncode == 0, out.stderr[-3000:]
    changed = {k for k, v in json.loads(out.stdout).items() if v != PINNED.get(k)}
    assert not changed, "numbers that depend on the BLAS kernel: %s" % sorted(changed)


if __name__ == "__main__":
    import tempfile
    import time

    with tempfile.TemporaryDirectory() as d:
        out = {}
        for name, fn in cases(Path(d)).items():
            t = time.perf_counter()
            out[name] = fn()
            print("%-24s %s  %.1f s" % (name, out[name], time.perf_counter() - t), file=sys.stderr)
        print(json.dumps(out, indent=4))
