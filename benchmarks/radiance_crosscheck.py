"""lpy-light against Radiance's rtrace on a room both can simulate exactly.

A closed room (mm) with a Lambertian light panel in the ceiling, grey Lambertian walls, a darker
floor, a two-sided block top, a mirror on one wall and a diffusing ``trans`` sheet over half the
room; sensors facing up, down and sideways.  Radiance's semantics there are lpy-light's with
``[physics] one_sided = false`` (every surface seen from both sides) and ``materials = "radiance"``
(Radiance's split of ``trans`` parameters): ``plastic`` with specularity 0 is Lambertian with
reflectance = colour, ``mirror`` reflects specularly with reflectance = colour, ``trans`` with
specularity 0 and tspec 0 reflects C(1 − t) and transmits C·t diffusely, ``light`` emits Lambertian
from its front.

Reference: ``rtrace -I`` (irradiance at each sensor's centre along its normal) with
``-aa 0 -lr 0`` (no irradiance cache, no hard depth limit: Russian roulette on ``-lw``), jittered
source sampling, repeated ``--repeats`` times with different random sequences for a standard error.
Ours: the irradiance from the expected photon hits, E = photons / N · Φ / A_sensor, Φ = π L A_panel.

    .venv/bin/pip install pyradiance
    .venv/bin/python benchmarks/radiance_crosscheck.py [--photons 2e7] [--repeats 8]

Prints per sensor both irradiances, z = Δ / √(σ_ours² + σ_rad²), and the mean ratio.
"""
from __future__ import annotations

import argparse
import math
import tempfile
import time
from pathlib import Path

import numpy as np

ROOM = 1000.0                   # mm
PANEL = (400.0, 600.0, 990.0)   # panel x/y extent and height (faces down)
RADIANCE = 100.0                # panel radiance, W sr-1 m-2 (any unit: it cancels in E / L)
RADIUS = 5.0                    # sensor disc radius, mm

# (x, y, z, nx, ny, nz): up, down, sideways (towards the mirror and away), tilted
SENSORS = [(500, 500, 500, 0, 0, 1), (200, 200, 500, 0, 0, 1), (800, 300, 700, 0, 0, 1),
           (500, 500, 500, 0, 0, -1), (150, 800, 300, 0, 0, -1),
           (300, 500, 500, -1, 0, 0), (300, 500, 500, 1, 0, 0), (700, 700, 400, 0, 1, 0),
           (600, 200, 800, 1, 1, 1), (500, 500, 150, 0, 0, 1)]


def _poly(mat, name, pts):
    return "%s polygon %s\n0\n0\n%d\n%s\n\n" % (mat, name, 3 * len(pts),
                                              "\n".join("%g %g %g" % tuple(p) for p in pts))


def room_rad() -> str:
    """The room as Radiance text (every front faces into the room)."""
    L = ROOM
    out = ("void plastic wall\n0\n0\n5 0.5 0.5 0.5 0 0\n\n"
           "void plastic floor\n0\n0\n5 0.3 0.3 0.3 0 0\n\n"
           "void plastic ceiling\n0\n0\n5 0.7 0.7 0.7 0 0\n\n"
           "void plastic block\n0\n0\n5 0.4 0.4 0.4 0 0\n\n"
           "void mirror glass\n0\n0\n3 0.8 0.8 0.8\n\n"
           "void trans diffuser\n0\n0\n7 0.6 0.6 0.6 0 0 0.5 0\n\n"
           "void light panel\n0\n0\n3 %g %g %g\n\n" % (RADIANCE, RADIANCE, RADIANCE))
    out += _poly("floor", "floor", [(0, 0, 0), (L, 0, 0), (L, L, 0), (0, L, 0)])
    out += _poly("ceiling", "ceiling", [(0, 0, L), (0, L, L), (L, L, L), (L, 0, L)])
    out += _poly("wall", "wx0", [(0, 0, 0), (0, L, 0), (0, L, L), (0, 0, L)])
    out += _poly("wall", "wx1", [(L, 0, 0), (L, 0, L), (L, L, L), (L, L, 0)])
    out += _poly("wall", "wy0", [(0, 0, 0), (0, 0, L), (L, 0, L), (L, 0, 0)])
    out += _poly("wall", "wy1", [(0, L, 0), (L, L, 0), (L, L, L), (0, L, L)])
    a, b, z = PANEL
    out += _poly("panel", "panel", [(a, a, z), (a, b, z), (b, b, z), (b, a, z)])          # faces down
    out += _poly("block", "blocktop", [(350, 600, 250), (650, 600, 250), (650, 900, 250), (350, 900, 250)])
    out += _poly("glass", "mirror", [(1, 150, 200), (1, 850, 200), (1, 850, 850), (1, 150, 850)])  # faces +x
    out += _poly("diffuser", "sheet", [(500, 0, 750), (L, 0, 750), (L, L, 750), (500, L, 750)])  # half the room
    return out


def write_scene(folder: Path) -> Path:
    folder.mkdir(parents=True, exist_ok=True)
    (folder / "room.rad").write_text(room_rad())
    rows = ["X,Y,Z,rayon_capteur,Xnorm,Ynorm,Znorm"] + [
        "%g,%g,%g,%g,%g,%g,%g" % (x, y, z, RADIUS, nx, ny, nz) for x, y, z, nx, ny, nz in SENSORS]
    (folder / "sensors.csv").write_text("\n".join(rows) + "\n")
    (folder / "room.toml").write_text('geometry = "room.rad"\nsensors = "sensors.csv"\nunit = "mm"\n\n'
                                      "[physics]\none_sided = false     # Radiance's semantics\n"
                                      'materials = "radiance"    # trans split as Radiance does\n')
    return folder / "room.toml"


def panel_flux() -> float:
    a, b, _ = PANEL
    return math.pi * RADIANCE * (b - a) ** 2


def ours(toml: Path, photons: int, seed: int = 1, threads=None, estimator: str = "nee"):
    """(E, σ_E, seconds): irradiance per sensor (Radiance's units) from lpy-light."""
    from lpy_light.run import simulate
    from lpy_light.chamber.scene import load_scene

    chamber = load_scene(toml)
    ks = simulate.KernelScene(chamber, estimator)
    if estimator == "nee":
        ks.prune_next_events(threads=threads)
    res = simulate.run(ks, int(photons), seed=seed, threads=threads)
    p, s = res.sensors()
    area = math.pi * RADIUS ** 2
    k = panel_flux() / res.photons / area
    return p[:, 0] * k, s[:, 0] * k, res.seconds


def radiance(folder: Path, repeats: int = 8, ad: int = 2048):
    """(E, σ_E, seconds): rtrace -I, mean and standard error over ``repeats`` uncorrelated passes."""
    import pyradiance as pr

    oct_path = folder / "room.oct"
    oct_path.write_bytes(pr.oconv(str(folder / "room.rad")))
    rays = "".join("%g %g %g %g %g %g\n" % (x, y, z, *(np.array([nx, ny, nz]) / np.linalg.norm([nx, ny, nz])))
                   for x, y, z, nx, ny, nz in SENSORS) * repeats
    params = ["-aa", "0", "-lr", "0", "-lw", "1e-5", "-ab", "100", "-ad", str(ad), "-as", "0",
              "-dj", "1", "-ds", "0.05", "-dt", "0", "-dc", "1", "-dr", "3", "-dp", "0", "-st", "0", "-ss", "0"]
    t = time.perf_counter()
    out = pr.rtrace(rays.encode(), oct_path, header=False, irradiance=True, outspec="v", uncorrelated=True,
                    params=params)
    seconds = time.perf_counter() - t
    v = np.array([float(x) for x in out.split()]).reshape(repeats, len(SENSORS), 3).mean(axis=2)
    return v.mean(axis=0), v.std(axis=0, ddof=1) / math.sqrt(repeats), seconds


def compare(photons=2e7, repeats=8, ad=2048, threads=None, folder=None, verbose=True) -> dict:
    folder = Path(folder or tempfile.mkdtemp(prefix="lpy-light-rtrace-"))
    toml = write_scene(folder)
    e, se, t_ours = ours(toml, photons, threads=threads)
    r, sr, t_rad = radiance(folder, repeats, ad)
    z = (e - r) / np.sqrt(se ** 2 + sr ** 2)
    ratio = e / r
    w = 1 / ((se / r) ** 2 + (sr / r) ** 2)
    mean_ratio = float(np.sum(w * ratio) / np.sum(w))
    mean_ratio_std = float(1 / math.sqrt(np.sum(w)))
    if verbose:
        print("sensor  position            normal        lpy-light E         rtrace E            ratio      z")
        for i, (x, y, zz, nx, ny, nz) in enumerate(SENSORS):
            print("%5d  (%4g %4g %4g)  (%2g %2g %2g)  %8.4f ± %6.4f  %8.4f ± %6.4f  %7.4f  %+5.2f"
                  % (i, x, y, zz, nx, ny, nz, e[i], se[i], r[i], sr[i], ratio[i], z[i]))
        print("lpy-light %.3g photons (nee) %.1f s; rtrace %d x -ad %d %.1f s" % (photons, t_ours, repeats, ad, t_rad))
        print("mean ratio lpy-light / rtrace %.4f ± %.4f; max |z| %.2f" % (mean_ratio, mean_ratio_std,
                                                                           np.abs(z).max()))
    return {"ours": e, "ours_std": se, "radiance": r, "radiance_std": sr, "z": z, "ratio": ratio,
            "mean_ratio": mean_ratio, "mean_ratio_std": mean_ratio_std, "seconds_ours": t_ours,
            "seconds_radiance": t_rad}


def main():
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--photons", type=float, default=2e7)
    ap.add_argument("--repeats", type=int, default=8)
    ap.add_argument("--ad", type=int, default=2048, help="rtrace ambient divisions per pass")
    ap.add_argument("--threads", type=int, default=None)
    ap.add_argument("--keep", default=None, help="folder for the scene files (default: a temporary one)")
    args = ap.parse_args()
    compare(args.photons, args.repeats, args.ad, args.threads, args.keep)


if __name__ == "__main__":
    main()
