"""Writing a run's results: ``sensors.csv``, ``receivers.csv``, ``summary.json``.

Files are written to a temporary name and renamed into place, so a reader never
sees a half-written file and a failed run leaves no results file behind.
"""
from __future__ import annotations

import csv
import io
import json
import math
import os
import tempfile
from pathlib import Path

import numpy as np

from ..chamber import units
from ..errors import InputError


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
    read = {Path(p).resolve() for p in inputs}
    for name in RESULT_FILES:
        target = (Path(out) / name).resolve()
        if target in read:
            raise InputError("--out would overwrite the input file %s with this run's %s: choose another folder"
                             % (target, name), out)


def _temporary_beside(path: Path):
    """``(fd, name)`` of a new file in ``path``'s folder, with the usual 0666 & ~umask permissions."""
    fd, tmp = tempfile.mkstemp(prefix="." + path.name + ".", dir=path.parent)
    umask = os.umask(0o022)      # mkstemp makes 0600 files: give results the usual 0666 & ~umask
    os.umask(umask)
    os.chmod(tmp, 0o666 & ~umask)
    return fd, tmp


def atomic_write(path: Path, text: str):
    path = Path(path)
    fd, tmp = _temporary_beside(path)
    try:
        with os.fdopen(fd, "w", newline="", encoding="utf-8") as fh:
            fh.write(text)
        os.replace(tmp, path)
    except BaseException:
        if os.path.exists(tmp):
            os.unlink(tmp)
        raise


class CsvStream:
    """A csv written row block by row block, each flushed to disk, and renamed into place at :meth:`close`:
    a long growth run holds one step's rows in memory, not all of them, and a reader never sees a half-written
    ``path`` (until then the rows are in a hidden ``.NAME.*`` file beside it).

    ``columns``: the header, written before the first rows (or alone, if no row ever comes).  Cells as
    :func:`csv_text` writes them (an undefined number is an empty cell).  Use as a context manager: leaving the
    block by an exception removes the temporary file and leaves ``path`` as it was.
    """

    def __init__(self, path, columns):
        self.path = Path(path)
        self.columns = list(columns)
        self.rows = 0
        fd, self._tmp = _temporary_beside(self.path)
        self._fh = os.fdopen(fd, "w", newline="", encoding="utf-8")
        self._writer = csv.DictWriter(self._fh, fieldnames=self.columns, lineterminator="\n")
        self._writer.writeheader()

    def write(self, rows):
        """Append ``rows`` (dicts keyed by ``columns``) and flush them to disk."""
        for row in rows:
            self._writer.writerow({k: _cell(v) for k, v in row.items()})
        self.rows += len(rows)
        self._fh.flush()

    def close(self):
        """Rename the rows written into place at ``path``."""
        self._fh.close()
        os.replace(self._tmp, self.path)

    def discard(self):
        self._fh.close()
        if os.path.exists(self._tmp):
            os.unlink(self._tmp)

    def __enter__(self):
        return self

    def __exit__(self, kind, value, tb):
        if kind is None:
            self.close()
        else:
            self.discard()


#: rounding allowed per photon in the energy closure's residual (photons): far below any physical effect
CLOSURE_ROUNDING = 1e-10


def energy_closure(chamber, result) -> dict:
    """Per band: emitted = absorbed (per material) + escaped + cut + lost, with the residual's σ."""
    N = result.photons
    names = result.materials or [m.name for m in chamber.materials]
    out = {}
    fate = result.fate
    accounted, accounted_std = result.closure
    M = len(names)
    for b, label in enumerate(chamber.band_labels):
        absorbed = {}
        for m, name in enumerate(names):
            if fate[m, b] > 0:
                absorbed[name] = absorbed.get(name, 0.0) + float(fate[m, b])
        total = float(accounted[b])
        out[label] = {
            "emitted": N, "absorbed": absorbed, "absorbed_total": float(fate[:M, b].sum()),
            "escaped": float(fate[M, b]), "cut_at_max_depth": float(fate[M + 1, b]),
            "lost": float(fate[M + 2, b]), "accounted": total, "residual": N - total,
            # the residual is a sum of per-photon (1 - total deposit) terms: zero for the analog
            # estimator (but for rounding), zero within residual_std otherwise; residual_std adds
            # 1e-10 per photon for the rounding (the event tables' 1e-12 guard, float64 sums)
            "residual_std": math.hypot(float(accounted_std[b]), CLOSURE_ROUNDING * N),
        }
    return out


#: the columns of ``sensors.csv`` (then ``ppfd``, ``ppfd_std`` when the lamps are calibrated)
SENSOR_COLUMNS = ("sensor", "band", "photons", "photons_std", "x", "y", "z", "area_m2")
#: the files a run or a grow writes in ``--out``: a run that fails on bad input leaves none of them there
RESULT_FILES = ("sensors.csv", "sensors_derived.csv", "receivers.csv", "summary.json", "organs.csv", "plant.png")


def sensor_table(chamber, result, norm=None) -> list:
    """Rows of ``sensors.csv``: one per sensor and band."""
    photons, std = result.sensors()
    S = len(chamber.sensors)
    if S == 0:
        return []
    area_m2 = chamber.sensors.area * chamber.metres_per_unit ** 2
    value = vstd = None
    if norm is not None:
        value, vstd = units.ppfd(photons, std, area_m2, norm)
    rows = []
    for s in range(S):
        c = chamber.sensors.center[s]
        for b, label in enumerate(chamber.band_labels):
            row = {"sensor": s, "band": label, "photons": photons[s, b], "photons_std": std[s, b],
                   "x": c[0], "y": c[1], "z": c[2], "area_m2": area_m2[s]}
            if value is not None:
                row["ppfd"] = value[s, b]
                row["ppfd_std"] = vstd[s, b]
            rows.append(row)
    return rows


def derived_table(chamber, result, norm) -> list:
    """Per sensor: PAR and R:FR (µmol m⁻² s⁻¹, ratio) when the bands allow them; σ with the bands' covariance."""
    if norm is None or chamber.bands is None:
        return []
    S = len(chamber.sensors)
    area_m2 = chamber.sensors.area * chamber.metres_per_unit ** 2
    scale = norm.scale[None, :] / area_m2[:, None]
    scale_std = norm.scale_std[None, :] / area_m2[:, None]
    rows_idx = np.arange(S)
    par, par_std, rfr, rfr_std = units.par_and_rfr(result.tally[rows_idx], result.covariance(rows_idx), scale,
                                                   scale_std, chamber.bands)
    if par is None and rfr is None:
        return []
    rows = []
    for s in range(S):
        row = {"sensor": s}
        if par is not None:
            row["par"] = par[s]
            row["par_std"] = par_std[s]
        if rfr is not None:
            row["r_fr"] = rfr[s]
            row["r_fr_std"] = rfr_std[s]
        rows.append(row)
    return rows


def sigma_summary(chamber, result) -> dict | None:
    """Relative σ of every sensor and band (σ / value, where the value is > 0): its median and where it is
    largest -- the tally that a ``--precision`` run waits for.  None without sensors or without light."""
    if not len(chamber.sensors):
        return None
    value, std = result.sensors()                      # (S, B) each
    lit = value > 0
    if not lit.any():
        return None
    rel = np.where(lit, std / np.where(lit, value, 1.0), -1.0)
    s, b = np.unravel_index(int(np.argmax(rel)), rel.shape)
    return {"median": float(np.median(rel[lit])), "max": float(rel[s, b]),
            "max_at": {"sensor": int(s), "band": chamber.band_labels[b],
                       "position": [float(x) for x in chamber.sensors.center[s]]},
            "unlit": int((~lit).sum())}


def receiver_table(chamber, result) -> list:
    inc, inc_std = result.receivers_incident()
    ab, ab_std = result.receivers_absorbed()
    rows = []
    for r, name in enumerate(chamber.receivers):
        for b, label in enumerate(chamber.band_labels):
            rows.append({"receiver": r, "name": name, "band": label, "incident": inc[r, b],
                         "incident_std": inc_std[r, b], "absorbed": ab[r, b], "absorbed_std": ab_std[r, b],
                         "area_m2": chamber.receiver_area[r] * chamber.metres_per_unit ** 2})
    return rows


def _finite(value):
    """``value`` with every NaN or infinite number made None (JSON null), recursively: a number that is not
    defined (a ratio over zero light, R² of one point) is written as absent, never as a non-JSON token."""
    if isinstance(value, dict):
        return {k: _finite(v) for k, v in value.items()}
    if isinstance(value, (list, tuple)):
        return [_finite(v) for v in value]
    if isinstance(value, np.ndarray):
        return _finite(value.tolist())
    if isinstance(value, (float, np.floating)):
        return float(value) if math.isfinite(value) else None
    if isinstance(value, np.integer):
        return int(value)
    return value


def json_text(obj) -> str:
    """Strict JSON of a summary (NaN and infinities as null), indented, with a final newline."""
    return json.dumps(_finite(obj), indent=2, allow_nan=False, default=float) + "\n"


def _cell(v):
    """A csv cell: floats in full precision (repr), an undefined one (NaN, inf) empty."""
    if isinstance(v, (float, np.floating)):
        return repr(float(v)) if math.isfinite(v) else ""
    return v


def csv_text(rows, columns=None) -> str:
    """CSV of ``rows`` (dicts); with no rows, the header of ``columns`` alone (if given).  A value that is not
    defined (NaN or infinite: ppfd where no photon reached any reference sensor) is an empty cell."""
    buf = io.StringIO()
    if not rows and columns:
        return ",".join(columns) + "\n"
    if rows:
        writer = csv.DictWriter(buf, fieldnames=list(rows[0].keys()), lineterminator="\n")
        writer.writeheader()
        for row in rows:
            writer.writerow({k: _cell(v) for k, v in row.items()})
    return buf.getvalue()


def machine() -> dict:
    """Where the numbers were computed, as far as their bits depend on it: the arithmetic fingerprint, the
    processor and the versions (:mod:`lpy_light.kernel.fingerprint`; docs/physics.md, "What is reproducible")."""
    from ..kernel.fingerprint import describe

    return describe()


def write_run(out_dir, chamber, result, norm=None, extra=None) -> dict:
    """Write every results file of a run into ``out_dir``; return the summary dict."""
    out = Path(out_dir)
    out.mkdir(parents=True, exist_ok=True)
    summary = {
        "scene": chamber.source, "bands": chamber.band_labels, "unit": chamber.unit,
        "photons": result.photons, "seed": result.seed, "threads": result.threads,
        "seconds": result.seconds, "photons_per_second": result.photons / result.seconds if result.seconds else None,
        "rays": result.rays, "rays_per_second": result.rays / result.seconds if result.seconds else None,
        "estimator": result.estimator, "partial": result.partial, "sensors": len(chamber.sensors), "receivers": len(chamber.receivers),
        "triangles": int(len(chamber.triangles)), "emitters": int(len(chamber.emitters)),
        "physics": vars(chamber.physics), "skipped": chamber.skipped,
        "energy_closure": energy_closure(chamber, result),
        "counters": {"candidate_overflows": int(result.counters[1]), "scratch_flushes": int(result.counters[2]),
                     "lost": int(result.counters[3])},
    }
    summary["machine"] = machine()
    sigma = sigma_summary(chamber, result)
    if sigma is not None:
        summary["relative_sigma"] = sigma
    if getattr(chamber, "overrides", None):      # what the scene's [lamps.*] / [materials.*] tables changed
        summary["scene_overrides"] = chamber.overrides
    if norm is not None:
        summary["normalisation"] = {"how": norm.how, "assumption": getattr(norm, "assumption", None),
                                    "scale": norm.scale.tolist(), "scale_std": norm.scale_std.tolist()}
    summary.update(result.extra)
    if extra:
        summary.update(extra)
    files = {"sensors.csv": csv_text(sensor_table(chamber, result, norm), SENSOR_COLUMNS)}
    derived = derived_table(chamber, result, norm)
    if derived:
        files["sensors_derived.csv"] = csv_text(derived)
        summary["derived"] = {"file": "sensors_derived.csv", **units.derived_description(chamber.bands)}
    if chamber.receivers:
        files["receivers.csv"] = csv_text(receiver_table(chamber, result))
    for name, text in files.items():
        atomic_write(out / name, text)
    atomic_write(out / "summary.json", json_text(summary))
    return summary
