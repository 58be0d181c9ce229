"""Pictures of a run: false-colour maps of the sensors, one PNG per sensor plane.

Pure functions: arrays in, PNG paths out.  matplotlib is optional (extras
``plot``: ``pip install 'lpy-light[plot]'``); it is imported only when a picture
is drawn, and :func:`require_matplotlib` says clearly when it is missing.

Sensors are grouped by plane: same (rounded) normal and same offset along it —
for SEC2's horizontal discs, one plane per height z.  Each plane's sensors are
drawn in the plane's own axes (x, y for a horizontal plane), one panel per
quantity (each band, PAR, R:FR, or the difference to a reference in σ units),
each with its colour bar and unit.
"""
from __future__ import annotations

import re
from pathlib import Path

import numpy as np

from ..errors import LpyLightError

PPFD_UNIT = "µmol m⁻² s⁻¹"


def require_matplotlib():
    """Import matplotlib with a file-only backend; a clear error when it is not installed."""
    try:
        import matplotlib
    except ImportError:
        raise LpyLightError("pictures need matplotlib, which is not installed: "
                            "pip install 'lpy-light[plot]' (or pip install matplotlib)") from None
    matplotlib.use("Agg")
    import matplotlib.pyplot as plt
    return plt


def plane_groups(centers, normals, decimals: int = 3, unit: str = "") -> list:
    """Group sensors by plane.  Returns a list of dicts, largest first:

    ``index`` (k,) rows of the sensors, ``name`` (file-name tag, e.g. ``z1000``),
    ``title`` (e.g. ``z = 1000 mm, facing +z``), ``uv`` (k, 2) coordinates in the
    plane and ``axes`` (the two axis names)."""
    centers = np.asarray(centers, float)
    normals = np.asarray(normals, float)
    n = normals / np.linalg.norm(normals, axis=1)[:, None]
    scale = max(float(np.abs(centers).max()) if centers.size else 1.0, 1e-12)
    keys = {}
    for s in range(len(centers)):
        key = (tuple(np.round(n[s], decimals) + 0.0), round(float(centers[s] @ n[s]) / scale, decimals + 3))
        keys.setdefault(key, []).append(s)
    groups = []
    for (normal, _), index in keys.items():
        index = np.array(index)
        normal = np.array(normal)
        axis = int(np.argmax(np.abs(normal)))
        names = "xyz"
        if abs(normal[axis]) > 1 - 1e-6:      # an axis-aligned plane: use the two other axes
            u_ax, v_ax = [i for i in range(3) if i != axis]
            uv = centers[index][:, [u_ax, v_ax]]
            axes = (names[u_ax], names[v_ax])
            level = float(np.median(centers[index, axis]))
            tag = "%s%g" % (names[axis], level)
            title = "%s = %g%s, facing %s%s" % (names[axis], level, (" " + unit) if unit else "",
                                               "+" if normal[axis] > 0 else "-", names[axis])
        else:                                 # a tilted plane: an orthonormal basis in it
            helper = np.array([0.0, 0.0, 1.0]) if abs(normal[2]) < 0.9 else np.array([1.0, 0.0, 0.0])
            t = np.cross(helper, normal)
            t /= np.linalg.norm(t)
            b = np.cross(normal, t)
            uv = np.stack([centers[index] @ t, centers[index] @ b], axis=1)
            axes = ("u", "v")
            tag = "plane"
            title = "plane facing (%.2f, %.2f, %.2f)" % tuple(normal)
        groups.append({"index": index, "name": tag, "title": title, "uv": uv, "axes": axes})
    groups.sort(key=lambda g: (-len(g["index"]), g["name"]))
    seen = {}
    for g in groups:                          # unique, file-safe names
        base = re.sub(r"[^A-Za-z0-9_.+-]", "_", g["name"])
        seen[base] = seen.get(base, 0) + 1
        g["name"] = base if seen[base] == 1 else "%s_%d" % (base, seen[base])
    return groups


def _marker_size(uv, ax_width_pt: float) -> float:
    """Marker area (pt²) so that neighbouring sensors' squares nearly touch."""
    if len(uv) < 2:
        return 200.0
    d = np.sqrt(((uv[:, None, :] - uv[None, :, :]) ** 2).sum(-1))
    d[d == 0] = np.inf
    spacing = float(np.median(d.min(axis=1)))
    extent = float(np.ptp(uv, axis=0).max()) + spacing
    if not np.isfinite(spacing) or extent <= 0:
        return 200.0
    side = 0.9 * ax_width_pt * spacing / extent
    return float(np.clip(side, 2.0, 60.0) ** 2)


def sensor_maps(out_dir, centers, normals, panels, prefix: str = "map", title: str = "", unit: str = "",
                diverging: bool = False) -> list:
    """Write one PNG per sensor plane into ``out_dir``; return their paths.

    ``panels``: list of ``(name, values (S,), colour-bar label)``, one subplot each.
    ``diverging``: a blue-white-red map centred on 0 (for differences), else viridis.
    Sensors whose value is not finite are drawn as grey crosses.
    """
    plt = require_matplotlib()
    out_dir = Path(out_dir)
    out_dir.mkdir(parents=True, exist_ok=True)
    paths = []
    for g in plane_groups(centers, normals, unit=unit):
        idx, uv = g["index"], g["uv"]
        n = len(panels)
        cols = min(n, 4)
        rows = -(-n // cols)
        fig, axs = plt.subplots(rows, cols, figsize=(max(4.2 * cols, 6.5), 3.6 * rows + 0.8), squeeze=False)
        for k, (name, values, label) in enumerate(panels):
            ax = axs[k // cols][k % cols]
            v = np.asarray(values, float)[idx]
            ok = np.isfinite(v)
            kw = {"cmap": "viridis"}
            extend = "neither"
            if diverging:     # centred on 0; a few outliers do not wash out the rest
                a = np.abs(v[ok])
                lim = float(min(a.max(), max(4.0, np.percentile(a, 98)))) if ok.any() else 1.0
                lim = max(lim, 1e-12)
                kw = {"cmap": "RdBu_r", "vmin": -lim, "vmax": lim}
                if ok.any() and a.max() > lim:
                    extend = "both"
            size = _marker_size(uv, 72 * 3.0)
            sc = ax.scatter(uv[ok, 0], uv[ok, 1], c=v[ok], s=size, marker="s", linewidths=0, **kw)
            if (~ok).any():
                ax.scatter(uv[~ok, 0], uv[~ok, 1], c="0.6", s=size / 2, marker="x")
            ax.set_aspect("equal", adjustable="datalim")
            ax.set_title(name, fontsize=10)
            ax.set_xlabel("%s%s" % (g["axes"][0], " (%s)" % unit if unit else ""), fontsize=8)
            ax.set_ylabel("%s%s" % (g["axes"][1], " (%s)" % unit if unit else ""), fontsize=8)
            ax.tick_params(labelsize=7)
            if ok.any():
                cb = fig.colorbar(sc, ax=ax, shrink=0.85, extend=extend)
                cb.set_label(label, fontsize=8)
                cb.ax.tick_params(labelsize=7)
        for k in range(n, rows * cols):
            axs[k // cols][k % cols].axis("off")
        fig.suptitle(("%s\n" % title if title else "") + "%s (%d sensors)" % (g["title"], len(idx)), fontsize=10)
        fig.tight_layout()
        path = out_dir / ("%s_%s.png" % (prefix, g["name"]))
        fig.savefig(path, dpi=100)
        plt.close(fig)
        paths.append(path)
    return paths


def profile_plots(out_dir, rows, columns=(), title: str = "") -> list:
    """One PNG per sensor plane, ``profile_<plane>.png``: the ratio to a reference (mean 1) along the
    plane's rows and, when given, its columns, with ±1σ bars.  ``rows``, ``columns``: lists of
    :class:`~lpy_light.report.reference.Profile` (from :func:`~lpy_light.report.reference.row_profiles`); returns
    the paths."""
    plt = require_matplotlib()
    out_dir = Path(out_dir)
    out_dir.mkdir(parents=True, exist_ok=True)
    by_plane = {}
    for p in list(rows) + list(columns):
        by_plane.setdefault(p.plane, []).append(p)
    paths = []
    for plane, profiles in by_plane.items():
        fig, axs = plt.subplots(1, len(profiles), figsize=(5.2 * len(profiles), 3.8), squeeze=False)
        for ax, p in zip(axs[0], profiles):
            ax.axhline(1.0, color="0.5", linewidth=0.8)
            ax.errorbar(p.position, p.ratio, yerr=p.ratio_std, marker="o", markersize=4, capsize=2, linewidth=1)
            ax.set_xlabel(p.axis, fontsize=9)
            ax.set_ylabel("ours / reference (mean 1)", fontsize=9)
            ax.set_title("along %s: change %+.2f%% ± %.2f%%" % (p.axis, 100 * p.slope, 100 * p.slope_std), fontsize=9)
            ax.tick_params(labelsize=8)
            lo, hi = float(np.min(p.ratio - p.ratio_std)), float(np.max(p.ratio + p.ratio_std))
            pad = max(0.002, 0.1 * (hi - lo))
            ax.set_ylim(min(lo, 0.995) - pad, max(hi, 1.005) + pad)
        fig.suptitle(("%s\n" % title if title else "") + profiles[0].title, fontsize=10)
        fig.tight_layout()
        path = out_dir / ("profile_%s.png" % plane)
        fig.savefig(path, dpi=100)
        plt.close(fig)
        paths.append(path)
    return paths


def run_panels(labels, photons, ppfd=None, par=None, rfr=None) -> list:
    """The panels of a run's maps: each band's ppfd (µmol m⁻² s⁻¹) when known, else its photons; PAR, R:FR."""
    panels = []
    for b, label in enumerate(labels):
        if ppfd is not None:
            panels.append(("ppfd %s nm" % label if label != "rad" else "ppfd", ppfd[:, b], "ppfd (%s)" % PPFD_UNIT))
        else:
            panels.append(("photons %s" % label, photons[:, b], "photons (expected hits for the run's N)"))
    if par is not None:
        panels.append(("PAR 400-700 nm", par, "PAR (%s)" % PPFD_UNIT))
    if rfr is not None:
        panels.append(("R:FR (655-665 / 725-735)", rfr, "R:FR (ratio)"))
    return panels


def spectrum_bar(path, bands, values, stds=None, title: str = "", unit: str = PPFD_UNIT):
    """A bar chart of one sensor's light per band (widths = the bands); returns ``path``."""
    plt = require_matplotlib()
    bands = np.asarray(bands, float)
    values = np.asarray(values, float)
    fig, ax = plt.subplots(figsize=(7, 3.6))
    width = bands[:, 1] - bands[:, 0]
    per_nm = values / width
    err = None if stds is None else np.asarray(stds, float) / width
    colours = ["#7f00ff" if a < 450 else "#0040ff" if a < 500 else "#00a050" if a < 570 else "#e0c000" if a < 600
               else "#ff6000" if a < 655 else "#d00000" if a < 700 else "#700000" for a in bands[:, 0]]
    ax.bar(bands[:, 0], per_nm, width=width, align="edge", color=colours, edgecolor="k", linewidth=0.5,
           yerr=err, ecolor="0.3", capsize=2)
    ax.set_xlabel("wavelength (nm)")
    ax.set_ylabel("%s per nm" % unit)
    ax.set_title(title, fontsize=10)
    fig.tight_layout()
    fig.savefig(path, dpi=100)
    plt.close(fig)
    return Path(path)
