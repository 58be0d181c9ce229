"""A chamber fitted to its survey: ``lpy-light calibrate SCENE SURVEY.csv --out DIR``.

The light at a site is linear in each lamp's output, so the scene is traced once per lamp
(:class:`LampRuns`: ``x[l, s, b]``, sensor s's photon density per photon of lamp l, band b) and the survey
``y[s, b]`` (µmol m⁻² s⁻¹) is fitted by

    y[s, b] ≈ Σ_l c[l, b] · (x[l, s, b] + Σ_j θ_j · ∂x[l, s, b]/∂θ_j),

``c ≥ 0`` the lamps' outputs in µmol s⁻¹ (how free: :data:`OUTPUT_MODELS`), θ the physical parameters that
are not linear (:class:`Parameter`: a lamp's position, a diffuser's straight-through part, a wall's
reflectance), each bounded, their derivatives by finite differences with common random numbers (the same
seed and photons, so that a difference is the parameter's and not noise).  The fit minimises the relative
residuals ((y − f) / y)² (a reading's error grows with it).

Model no more than the survey shows: parameters enter one group at a time, each only if it lowers the
cross-validated rms (:func:`cross_validated`: whole rows of sites left out, not single sites, since
neighbours share their errors) by at least :data:`MIN_GAIN`; the report says which entered and by how
much.  Uncertainties are jackknife standard errors over the same rows.  After the selection the lamps are
traced again at the fitted parameters and the final residuals are those of that run, not of the linear
model.

Outputs (:func:`write_outputs`): ``scene.toml`` (the original scene plus ``[lamps.*]``,
``[materials.*]`` and ``lamp_flux``: :mod:`lpy_light.chamber.overrides`), ``calibration.json``, ``report.md``,
``sites.csv`` (each site and band, measured and simulated before and after) and, with matplotlib,
``rows.png``.
"""
from __future__ import annotations

import dataclasses
import sys
import time
from dataclasses import dataclass, field
from pathlib import Path

import numpy as np

from ..chamber import overrides as ov
from ..chamber.emitters import Emitters
from ..errors import InputError

#: linear models of the lamps' outputs, each nesting the one before: one µmol s⁻¹ scale per band for all the
#: lamps (the scene as described, its flux fitted: "before"); a factor per lamp; a factor and a spectral tilt
#: per lamp; a free output per lamp and band
OUTPUT_MODELS = ("band", "lamp", "lamp+tilt", "lamp×band")
#: a parameter group enters only if it lowers the cross-validated rms by this fraction of it
MIN_GAIN = 0.01
#: a lamp's output stays within this range of the lamps' common scale (factors of about their mean): more than
#: lamps of one kind differ by age or dirt; a fit pressing on it is warned about
OUTPUT_RANGE = (0.5, 2.0)
#: times the lamps are traced again at the fitted parameters and the model linearised there (Gauss-Newton with
#: the first derivatives kept: a lamp moved 2 cm is found within its σ where one linearisation falls short)
OUTER = 2
#: at most this many lamps are fitted one by one (each costs runs)
MAX_LAMPS = 16


@dataclass
class Parameter:
    """A physical parameter that is not linear in the light: its override (``table``, ``name``, ``key``;
    ``axis`` for a lamp's shift), value with nothing changed, finite-difference step, bounds, unit, and the
    lamps whose runs it changes (None: all)."""

    group: str
    table: str
    name: str
    key: str
    step: float
    lower: float
    upper: float
    unit: str
    axis: int = -1
    base: float = 0.0
    lamps: list | None = None

    @property
    def label(self) -> str:
        return "%s.%s%s" % (self.name, self.key, "xyz"[self.axis] if self.axis >= 0 else "")


@dataclass
class Fit:
    """A fitted model: ``outputs`` (the :data:`OUTPUT_MODELS` entry), ``params`` (Parameter), ``theta`` their
    values, ``c`` (L, B) lamp outputs (µmol s⁻¹ per unit of the lamp's sampled power), ``predicted`` (S, B)."""

    outputs: str
    params: list
    theta: np.ndarray
    c: np.ndarray
    predicted: np.ndarray


@dataclass
class Calibration:
    """What ``calibrate`` found; see :func:`calibrate`."""

    lamps: list
    bands: list
    survey: object
    before: Fit
    after: Fit
    final: np.ndarray                 # (S, B) predicted by the lamps traced again at the fitted parameters
    steps: list                       # the selection, one dict per candidate tried
    cv_before: np.ndarray             # (B,) cross-validated rms (relative) of "before"
    cv_after: np.ndarray
    rms_before: np.ndarray            # (B,) rms of the fits on all sites
    rms_after: np.ndarray
    rms_spectrum: np.ndarray | None   # (B,) the scene's own lamp spectrum, nothing fitted
    parameters: list                  # report rows: name, value, σ, bounds, unit, warnings
    output_factor: np.ndarray         # (L, B) each lamp's output relative to the scene's
    output_sigma: np.ndarray
    lamp_flux: np.ndarray             # (B,) µmol s⁻¹
    warnings: list
    photons: int
    seconds: float
    runs: int
    scene_overrides: dict = field(default_factory=dict)


# --- the runs ------------------------------------------------------------------------------------
class LampRuns:
    """Per-lamp photon densities of ``chamber`` at the survey's sites, cached by the overrides that change them.

    ``densities(lamps, materials)`` -> (L, S, B) photons per m² per emitted photon of each lamp (weighted by its
    output), every run with ``photons`` photons and seed ``seed`` (common random numbers)."""

    def __init__(self, chamber, survey, photons: int, seed: int, threads=None, say=None):
        self.chamber = dataclasses.replace(chamber, sensors=survey.sensors)
        self.lamps = list(dict.fromkeys(chamber.emitters.name))
        self.photons, self.seed, self.threads = photons, seed, threads
        self.area_m2 = survey.sensors.area * chamber.metres_per_unit ** 2
        self.say = say or (lambda text: None)
        self.cache, self.runs, self.seconds = {}, 0, 0.0

    def _scene(self, lamp, lamps, materials):
        ch = dataclasses.replace(self.chamber, materials=list(self.chamber.materials), overrides={})

        def err(msg, key=None):
            return InputError(msg)
        ov.apply_lamps(ch, lamps, err)
        ov.apply_materials(ch, materials, err)
        em = ch.emitters
        mine = np.array([n == lamp for n in em.name])
        sub = Emitters(em.kind[mine], em.data[mine], em.power[mine], [lamp] * int(mine.sum()),
                       None if em.output is None else em.output[mine])
        return dataclasses.replace(ch, emitters=sub)

    def density(self, lamp, lamps: dict, materials: dict) -> np.ndarray:
        from ..run import simulate

        key = (lamp, repr(sorted((k, sorted(v.items())) for k, v in lamps.items() if k == lamp)),
               repr(sorted((k, sorted(v.items())) for k, v in materials.items())))
        if key not in self.cache:
            ks = simulate.KernelScene(self._scene(lamp, lamps, materials), estimator="nee")
            simulate.compile_kernel(ks)
            ks.prune_next_events(threads=self.threads)
            t = time.perf_counter()
            r = simulate.run(ks, self.photons, seed=self.seed, threads=self.threads)
            self.seconds += time.perf_counter() - t
            self.runs += 1
            p, _ = r.sensors()
            self.cache[key] = p / self.area_m2[:, None] / r.photons
        return self.cache[key]

    def densities(self, lamps: dict | None = None, materials: dict | None = None) -> np.ndarray:
        return np.stack([self.density(lamp, lamps or {}, materials or {}) for lamp in self.lamps])


def _tables(params, theta) -> tuple:
    """The ``[lamps.*]`` and ``[materials.*]`` tables that set ``params`` to ``theta``."""
    lamps, materials = {}, {}
    for p, v in zip(params, theta):
        if v == p.base:                 # unchanged: not an override (and the run's cache key stays the same)
            continue
        if p.table == "lamps":
            shift = lamps.setdefault(p.name, {}).setdefault("shift", [0.0, 0.0, 0.0])
            shift[p.axis] = float(v)
        else:
            materials.setdefault(p.name, {})[p.key] = float(v)
    return lamps, materials


def candidate_parameters(chamber, lamps, tolerance: float) -> list:
    """The physical parameters a survey may fix, in groups: each lamp's position (x, y, z within
    ``tolerance`` scene units); each diffuser's straight-through part (materials transmitting >10 %, on
    average over bands); each wall's reflectance (the materials of the vertical surfaces, each covering at
    least 10 % of their area; mirrors excluded), a factor in 0.5..1.5 kept below 1 − T."""
    from ..chamber.materials import DIFFUSE_R, DIFFUSE_T, SPECULAR_R, SPECULAR_T

    params = []
    for lamp in lamps:
        for axis in range(3):
            params.append(Parameter("%s position" % lamp, "lamps", lamp, "shift", 0.3 * tolerance, -tolerance,
                                    tolerance, chamber.unit, axis=axis, lamps=[lamp]))
    used = np.unique(chamber.tri_material[:, 0])
    for m in used:
        mat = chamber.materials[m]
        T = mat.events[DIFFUSE_T] + mat.events[SPECULAR_T]
        if T.mean() > 0.1:
            ts = float((mat.events[SPECULAR_T] / np.where(T > 0, T, 1)).mean())
            params.append(Parameter("%s spread" % mat.name, "materials", mat.name, "specular_transmission",
                                    0.2 if ts < 0.5 else -0.2, 0.0, 1.0, "", base=ts))
    tri = chamber.triangles
    normal = np.cross(tri[:, 1] - tri[:, 0], tri[:, 2] - tri[:, 0])
    area = 0.5 * np.linalg.norm(normal, axis=1)
    vertical = np.abs(normal[:, 2]) < 0.05 * np.linalg.norm(normal, axis=1)
    by_mat = np.bincount(chamber.tri_material[vertical, 0], weights=area[vertical], minlength=len(chamber.materials))
    for m in np.flatnonzero(by_mat >= 0.1 * by_mat.sum()):
        mat = chamber.materials[m]
        R = mat.events[DIFFUSE_R] + mat.events[SPECULAR_R]
        if not R.max() > 0 or (mat.events[SPECULAR_R] > 0.5 * R).all():
            continue
        T = mat.events[DIFFUSE_T] + mat.events[SPECULAR_T]
        top = float(min(1.5, np.min((1 - T)[R > 0] / R[R > 0])))
        params.append(Parameter("%s reflectance" % mat.name, "materials", mat.name, "reflectance", -0.1, 0.5,
                                top, "×", base=1.0))
    return params


# --- the fit ---------------------------------------------------------------------------------------
def _box_ls(A, b, lower, upper, sweeps: int = 2000):
    """min ‖A x − b‖ with lower ≤ x ≤ upper, for small A (n, k): cyclic coordinate descent, exact on a convex
    quadratic with box constraints."""
    G, h = A.T @ A, A.T @ b
    x = np.clip(np.linalg.lstsq(A, b, rcond=None)[0], lower, upper)
    for _ in range(sweeps):
        old = x.copy()
        for i in range(len(x)):
            if G[i, i] > 0:
                x[i] = min(max(x[i] + (h[i] - G[i] @ x) / G[i, i], lower[i]), upper[i])
        if np.abs(x - old).max() <= 1e-13 * (1.0 + np.abs(x).max()):
            break
    return x


def _outputs(model, X, y, wavelengths):
    """Lamp outputs c (L, B) ≥ 0 of ``model`` fitted to y (S, B) over the sites of X (L, S, B), relative
    residuals.  NaN columns of y (bands not measured) keep the plain band scale."""
    L, S, B = X.shape
    Wy = 1.0 / y
    c = np.zeros((L, B))
    for b in range(B):                  # the scene's own outputs, one scale per band
        t = X[:, :, b].sum(0) * Wy[:, b]
        c[:, b] = (t @ np.ones(S)) / (t @ t)
    if model == "band":
        return c
    lo, hi = OUTPUT_RANGE
    if model == "lamp×band":            # each lamp within OUTPUT_RANGE of that scale
        for b in range(B):
            c[:, b] = _box_ls(X[:, :, b].T * Wy[:, b, None], np.ones(S), lo * c[:, b], hi * c[:, b])
        return c
    # a factor a_l (and tilt t_l) per lamp and a scale k_b per band: alternate the two linear problems
    lam = (wavelengths - wavelengths.mean()) / max(np.ptp(wavelengths), 1e-9)
    basis = np.stack([np.ones(B), lam]) if model == "lamp+tilt" else np.ones((1, B))
    g = np.zeros((L, len(basis)))
    g[:, 0] = 1.0
    for _ in range(60):
        shape = np.maximum(g @ basis, 1e-6)                             # (L, B) relative outputs
        k = np.array([((X[:, :, b].T @ shape[:, b]) * Wy[:, b]).sum() /
                      (((X[:, :, b].T @ shape[:, b]) * Wy[:, b]) ** 2).sum() for b in range(B)])
        A = np.concatenate([np.einsum("ls,q->slq", X[:, :, b] * k[b] * Wy[None, :, b], basis[:, b]).reshape(S, -1)
                            for b in range(B)])
        if len(basis) == 1:              # a factor per lamp, within OUTPUT_RANGE of their mean
            mean = g[:, 0].mean()
            g_new = _box_ls(A, np.ones(len(A)), np.full(L, lo * mean), np.full(L, hi * mean)).reshape(L, 1)
        else:
            g_new = np.linalg.lstsq(A, np.ones(len(A)), rcond=None)[0].reshape(L, len(basis))
            g_new *= len(g_new) / max(g_new[:, 0].sum(), 1e-300)
            shape = g_new @ basis           # a factor and tilt per lamp: each band's factor kept in range
            g_new = np.linalg.lstsq(basis.T, np.clip(shape, lo, hi).T, rcond=None)[0].T
        g_new /= g_new[:, 0].mean()
        if np.allclose(g_new, g, rtol=1e-9, atol=1e-12):
            g = g_new
            break
        g = g_new
    shape = np.maximum(g @ basis, 0.0)
    k = np.array([((X[:, :, b].T @ shape[:, b]) * Wy[:, b]).sum() /
                  max((((X[:, :, b].T @ shape[:, b]) * Wy[:, b]) ** 2).sum(), 1e-300) for b in range(B)])
    return shape * k


def fit(model, params, X0, J, y, wavelengths, sites=None, iterations: int = 40, at=None) -> Fit:
    """Fit ``model``'s outputs and ``params`` (their derivatives ``J`` (P, L, S, B) around ``X0`` (L, S, B)) to
    ``y`` (S, B) over ``sites`` (a mask; all by default), alternating the outputs (exact for given θ) and θ
    (linear least squares, clipped to the bounds).  ``X0`` is the light at ``at`` (the parameters' values; by
    default those of the scene).  Predictions are made at every site."""
    sites = np.ones(len(y), bool) if sites is None else sites
    theta = np.array([p.base for p in params] if at is None else at, float)
    base = theta.copy()
    lower = np.array([p.lower for p in params], float)
    upper = np.array([p.upper for p in params], float)
    Jp = J if len(params) else np.zeros((0,) + X0.shape)
    for _ in range(iterations if len(params) else 1):
        X = X0 + np.einsum("j,jlsb->lsb", theta - base, Jp)
        c = _outputs(model, X[:, sites], y[sites], wavelengths)
        if not len(params):
            break
        F0 = np.einsum("lb,lsb->sb", c, X0[:, sites])
        A = np.einsum("lb,jlsb->jsb", c, Jp[:, :, sites]) / y[sites]
        r = ((y[sites] - F0) / y[sites]).ravel()
        step = np.linalg.lstsq(A.reshape(len(params), -1).T, r, rcond=None)[0]
        new = np.clip(base + step, lower, upper)
        if np.allclose(new, theta, rtol=0, atol=1e-9 * (1 + np.abs(upper - lower)).max()):
            theta = new
            break
        theta = new
    X = X0 + np.einsum("j,jlsb->lsb", theta - base, Jp)
    c = _outputs(model, X[:, sites], y[sites], wavelengths)
    return Fit(model, list(params), theta, c, np.einsum("lb,lsb->sb", c, X))


def relative_rms(predicted, y) -> np.ndarray:
    """(B,) rms over sites of (predicted − y) / y."""
    return np.sqrt(np.mean(((predicted - y) / y) ** 2, axis=0))


def cross_validated(model, params, X0, J, y, rows, wavelengths, at=None):
    """Leave one row of sites out at a time: ``(rms (B,), fits)``, the rms of the left-out rows' predictions
    and each fold's :class:`Fit` (for jackknife errors)."""
    predicted = np.zeros_like(y)
    fits = []
    for r in np.unique(rows):
        out = rows == r
        f = fit(model, params, X0, J, y, wavelengths, sites=~out, at=at)
        predicted[out] = f.predicted[out]
        fits.append(f)
    return relative_rms(predicted, y), fits


def jackknife(values) -> np.ndarray:
    """Jackknife standard error over leave-one-row-out estimates ``values`` (n, ...)."""
    v = np.asarray(values, float)
    n = len(v)
    return np.sqrt((n - 1) / n * ((v - v.mean(axis=0)) ** 2).sum(axis=0))


# --- the whole job ---------------------------------------------------------------------------------
def _relative_outputs(c, runs_weight):
    """Lamp outputs c (L, B) (µmol s⁻¹ of the whole scene were every lamp like lamp l) → factors (L, B) relative
    to the scene's outputs, their mean weighted by the lamps' sampled powers ``runs_weight`` (L,) 1 in every
    band, and the lamps' flux (B,) µmol s⁻¹."""
    Q = runs_weight[:, None]
    flux = (c * Q).sum(axis=0) / Q.sum()
    return c / np.where(flux > 0, flux, 1.0), flux


def calibrate(chamber, survey, photons: int = 2_000_000, seed: int = 1, threads=None, tolerance: float | None = None,
              say=None) -> Calibration:
    """Fit ``chamber`` to ``survey`` (:class:`lpy_light.calibration.survey.Survey`); see the module docstring.

    ``photons`` per lamp run (nee), ``tolerance`` how far a lamp may move (scene units; default 30 mm),
    ``say(text)`` progress lines."""
    say = say or (lambda text: None)
    t0 = time.perf_counter()
    lamps = list(dict.fromkeys(chamber.emitters.name))
    if len(lamps) > MAX_LAMPS:
        raise InputError("the scene has %d light sources; calibrate fits at most %d one by one"
                         % (len(lamps), MAX_LAMPS), chamber.source)
    measured = survey.columns
    y = survey.values[:, measured]
    B = int(measured.sum())
    wavelengths = np.array([0.5 * (a + b) for a, b in (chamber.bands or [(0.0, 1.0)])])[measured]
    tolerance = 0.03 / chamber.metres_per_unit if tolerance is None else float(tolerance)
    runs = LampRuns(chamber, survey, photons, seed, threads, say)
    say("tracing the %d lamps one at a time (%d photons each, seed %d)" % (len(lamps), photons, seed))
    weight = np.array([chamber.emitters.sampled_power[[n == lamp for n in chamber.emitters.name]].sum()
                       for lamp in lamps])
    share = (weight / weight.sum())[:, None, None]    # x[l]: lamp l's part of the scene's photons per photon
    X0 = runs.densities()[:, :, measured] * share
    params = candidate_parameters(chamber, lamps, tolerance)
    say("derivatives of %d parameters by common random numbers (%s)"
        % (len(params), ", ".join(sorted(set(p.group for p in params)))))
    J = np.zeros((len(params),) + X0.shape)
    for j, p in enumerate(params):
        theta = [q.base for q in params]
        theta[j] += p.step
        Xj = runs.densities(*_tables(params, theta))[:, :, measured] * share
        J[j] = (Xj - X0) / p.step
        say("  %s: %d runs so far, %.0f s" % (p.label, runs.runs, time.perf_counter() - t0))
    rows = survey.row

    def index(groups):
        return [j for j, p in enumerate(params) if p.group in groups]

    steps = []
    before_cv, _ = cross_validated("band", [], X0, J[:0], y, rows, wavelengths)
    model, best_cv, chosen = "band", before_cv, []
    for candidate in OUTPUT_MODELS[1:2] if B == 1 else OUTPUT_MODELS[1:]:    # one band: no spectral freedom
        cv, _ = cross_validated(candidate, [], X0, J[:0], y, rows, wavelengths)
        entered = cv.mean() < (1 - MIN_GAIN) * best_cv.mean()
        steps.append({"candidate": "lamp outputs: %s" % candidate, "cv_rms": float(cv.mean()),
                      "cv_rms_before": float(best_cv.mean()), "entered": bool(entered)})
        if entered:
            model, best_cv = candidate, cv
    groups = list(dict.fromkeys(p.group for p in params))
    while True:
        trial = {}
        for g in groups:
            if g in chosen:
                continue
            idx = index(chosen + [g])
            trial[g], _ = cross_validated(model, [params[i] for i in idx], X0, J[idx], y, rows, wavelengths)
        if not trial:
            break
        g = min(trial, key=lambda k: trial[k].mean())
        for k, cv in trial.items():
            steps.append({"candidate": k, "cv_rms": float(cv.mean()), "cv_rms_before": float(best_cv.mean()),
                          "entered": bool(k == g and cv.mean() < (1 - MIN_GAIN) * best_cv.mean())})
        if not trial[g].mean() < (1 - MIN_GAIN) * best_cv.mean():
            break
        chosen.append(g)
        best_cv = trial[g]
        say("  entered: %s (cross-validated rms %.2f %%)" % (g, 100 * best_cv.mean()))
    idx = index(chosen)
    sel = [params[i] for i in idx]
    before = fit("band", [], X0, J[:0], y, wavelengths)
    after = fit(model, sel, X0, J[idx], y, wavelengths)
    at, Xa = None, X0
    for _ in range(OUTER if sel else 0):   # the lamps traced again at the fit, the model linearised there
        at = after.theta
        Xa = runs.densities(*_tables(sel, at))[:, :, measured] * share
        after = fit(model, sel, Xa, J[idx], y, wavelengths, at=at)
        say("  re-linearised at the fit (%s): %d runs so far" % (
            ", ".join("%s %.4g" % (p.label, v) for p, v in zip(sel, after.theta)), runs.runs))
    _, folds = cross_validated(model, sel, Xa, J[idx], y, rows, wavelengths, at=at)
    # the lamps traced again where the fit put them: the final residuals are a run's, not the linear model's
    Xf = runs.densities(*_tables(sel, after.theta))[:, :, measured] * share if sel else X0
    final_c = _outputs(model, Xf, y, wavelengths)
    final = np.einsum("lb,lsb->sb", final_c, Xf)
    factor, flux = _relative_outputs(final_c, weight)
    fold_factor = np.array([_relative_outputs(f.c, weight)[0] for f in folds])
    factor_sigma = jackknife(fold_factor)
    theta_sigma = jackknife([f.theta for f in folds]) if sel else np.zeros(0)
    warnings, table = [], []
    for p, v, s in zip(sel, after.theta, theta_sigma):
        notes = []
        span = p.upper - p.lower
        if min(v - p.lower, p.upper - v) < 1e-3 * span:
            notes.append("at its bound")
        if s > 0.25 * span:
            notes.append("not identifiable (σ over a quarter of its range)")
        table.append({"parameter": p.label, "group": p.group, "value": float(v), "sigma": float(s),
                      "lower": p.lower, "upper": p.upper, "unit": p.unit, "notes": notes})
        warnings += ["%s = %.4g %s: %s" % (p.label, v, p.unit, n) for n in notes]
    for li, lamp in enumerate(lamps):
        if model != "band" and (factor_sigma[li] > 0.25 * np.maximum(factor[li], 1e-12)).any():
            warnings.append("%s's output: σ over 25 %% of its value in some band (not identifiable from this "
                            "survey)" % lamp)
        if model != "band" and (factor[li] < 1e-6).any():
            warnings.append("%s's output fitted to 0 in some band (at its bound)" % lamp)
        elif model != "band" and ((factor[li] < 1.01 * OUTPUT_RANGE[0]) | (factor[li] > 0.99 * OUTPUT_RANGE[1])).any():
            warnings.append("%s's output is %.2f-%.2f times the scene's, at or beyond its bounds %g-%g: more than "
                            "lamps of one kind differ; the fit may be absorbing an error of geometry (a lamp's place, "
                            "a reflector)" % (lamp, factor[li].min(), factor[li].max(), *OUTPUT_RANGE))
    rms_spectrum = None
    if chamber.spectrum is not None and chamber.bands is not None:
        from ..chamber.units import band_photon_flux
        M = band_photon_flux(chamber.spectrum, chamber.bands)[measured]
        tot = X0.sum(axis=0)
        rms_spectrum = relative_rms(tot * M / tot.mean(axis=0), y)
    after_cv, _ = cross_validated(model, sel, Xa, J[idx], y, rows, wavelengths, at=at)
    out = Calibration(lamps, [lab for lab, m in zip(chamber.band_labels, measured) if m], survey, before, after,
                      final, steps, before_cv, after_cv, relative_rms(before.predicted, y), relative_rms(final, y),
                      rms_spectrum, table, factor, factor_sigma, flux, warnings, photons,
                      time.perf_counter() - t0, runs.runs)
    out.scene_overrides = _scene_tables(chamber, lamps, measured, model, factor, sel, after.theta, flux)
    return out


def _scene_tables(chamber, lamps, measured, model, factor, params, theta, flux) -> dict:
    """The keys the fitted scene adds: ``lamps``, ``materials``, ``lamp_flux`` (per scene band; a band the survey
    did not measure keeps the measured bands' mean factor and has no lamp_flux, so none is written then)."""
    lamp_tables, materials = _tables(params, theta)
    B = chamber.n_bands
    had = chamber.overrides       # a scene already fitted: its own tables are composed with the new ones
    for lamp, t in had.get("lamps", {}).items():
        if "shift" in t and lamp in lamp_tables and "shift" in lamp_tables[lamp]:
            lamp_tables[lamp]["shift"] = [a + b for a, b in zip(t["shift"], lamp_tables[lamp]["shift"])]
    for name, t in had.get("materials", {}).items():
        if "reflectance" in t and name in materials and "reflectance" in materials[name]:
            materials[name]["reflectance"] = (np.asarray(t["reflectance"], float) *
                                              materials[name]["reflectance"]).tolist()
    for li, lamp in enumerate(lamps):
        full = np.full(B, np.nan)
        full[measured] = factor[li]
        full[~measured] = np.nanmean(full) if measured.any() else 1.0
        t = lamp_tables.setdefault(lamp, {})
        if model == "band":
            continue
        if "output" in had.get("lamps", {}).get(lamp, {}):
            full = full * ov.per_band(had["lamps"][lamp]["output"], B, "output")
        t["output"] = float(full[0]) if np.allclose(full, full[0], rtol=1e-12) else [float(v) for v in full]
    tables = {"lamps": {k: v for k, v in lamp_tables.items() if v}, "materials": materials}
    if measured.all():
        tables["lamp_flux"] = [float(v) for v in flux]
    return tables


# --- outputs -----------------------------------------------------------------------------------------
def _toml_value(v) -> str:
    if isinstance(v, list):
        return "[" + ", ".join(_toml_value(x) for x in v) + "]"
    if isinstance(v, float):
        return repr(v)
    return '"%s"' % str(v).replace("\\", "\\\\").replace('"', '\\"')


def scene_text(base: str, cal: Calibration, survey_path: str) -> str:
    """The fitted scene file: ``base`` plus the overrides, with a comment on where they come from."""
    t = cal.scene_overrides
    lines = ["# %s fitted to the survey %s by lpy-light calibrate" % (base, survey_path),
             "# (calibration.json and report.md beside this file say how; lpy_light.chamber.overrides what each key "
             "means)",
             "base = %s" % _toml_value(base)]
    if "lamp_flux" in t:
        lines.append("# µmol s-1 the lamps emit in each band (%s)" % ", ".join(cal.bands))
        lines.append("lamp_flux = %s" % _toml_value(t["lamp_flux"]))
    for table in ("lamps", "materials"):
        for name, keys in t.get(table, {}).items():
            lines.append("")
            lines.append("[%s.%s]" % (table, name))
            lines += ["%s = %s" % (k, _toml_value(v)) for k, v in keys.items()]
    return "\n".join(lines) + "\n"


def summary(cal: Calibration) -> dict:
    """calibration.json's content."""
    def per_band(a):
        return None if a is None else {b: float(v) for b, v in zip(cal.bands, a)}
    return {
        "survey": cal.survey.path, "sites": len(cal.survey), "rows": int(cal.survey.row.max() + 1),
        "lamps": cal.lamps, "bands": cal.bands,
        "photons_per_run": cal.photons, "runs": cal.runs, "seconds": cal.seconds,
        "rms_relative": {"spectrum_only": per_band(cal.rms_spectrum), "before": per_band(cal.rms_before),
                         "after": per_band(cal.rms_after)},
        "cv_rms_relative": {"before": per_band(cal.cv_before), "after": per_band(cal.cv_after),
                            "how": "leave one row of sites out; rows: %s" % cal.survey.row_source},
        "before": "the scene as described, one µmol s-1 scale per band fitted (lamp outputs as the scene has them)",
        "outputs_model": cal.after.outputs,
        "selection": cal.steps,
        "parameters": cal.parameters,
        "lamp_outputs": {lamp: {"factor": per_band(cal.output_factor[i]), "sigma": per_band(cal.output_sigma[i])}
                         for i, lamp in enumerate(cal.lamps)},
        "lamp_flux": per_band(cal.lamp_flux),
        "uncertainty": "jackknife over the rows of sites (leave one row out); the lamp runs' own noise, "
                       "common to every fold, is not in it",
        "warnings": cal.warnings,
        "scene": cal.scene_overrides,
    }


def report_text(cal: Calibration, scene_name: str) -> str:
    """report.md: rms per band before and after, cross-validated; the selection; the parameters."""
    pct = lambda a: "%.1f" % (100 * a)   # noqa: E731
    lines = ["# %s fitted to %s" % (scene_name, cal.survey.path), "",
             "%d sites in %d rows, %d lamps, %d bands; %d runs of %d photons, %.0f s." % (
                 len(cal.survey), cal.survey.row.max() + 1, len(cal.lamps), len(cal.bands), cal.runs, cal.photons,
                 cal.seconds), "",
             "## Relative rms (measured − simulated) / measured, % per band", "",
             "| band | %s |" % " | ".join(cal.bands), "|---|%s" % ("---|" * len(cal.bands))]
    if cal.rms_spectrum is not None:
        lines.append("| lamp spectrum, nothing fitted | %s |" % " | ".join(map(pct, cal.rms_spectrum)))
    lines += ["| before (one scale per band) | %s |" % " | ".join(map(pct, cal.rms_before)),
              "| before, cross-validated | %s |" % " | ".join(map(pct, cal.cv_before)),
              "| after | %s |" % " | ".join(map(pct, cal.rms_after)),
              "| after, cross-validated | %s |" % " | ".join(map(pct, cal.cv_after)),
              "| after / before, cross-validated | %s |" % " | ".join(
                  "%.2f" % r for r in cal.cv_after / cal.cv_before), "",
              "## What entered", "",
              "The output models in turn, then rounds over the parameter groups: each round takes the group that "
              "lowers the mean cross-validated rms most, if by at least %g %% of it." % (100 * MIN_GAIN),
              "", "| candidate | cv rms before, % | with it, % | entered |", "|---|---|---|---|"]
    lines += ["| %s | %s | %s | %s |" % (s["candidate"], pct(s["cv_rms_before"]), pct(s["cv_rms"]),
                                         "yes" if s["entered"] else "no") for s in cal.steps]
    lines += ["", "## Parameters (σ: jackknife over rows)", "", "| parameter | value | σ | bounds | notes |",
              "|---|---|---|---|---|"]
    lines += ["| %s | %.4g %s | %.2g | %g .. %g | %s |" % (p["parameter"], p["value"], p["unit"], p["sigma"],
                                                           p["lower"], p["upper"], "; ".join(p["notes"]))
              for p in cal.parameters]
    lines += ["", "Lamp outputs relative to the scene's (power-weighted mean 1 per band), ± σ:", "",
              "| lamp | %s |" % " | ".join(cal.bands), "|---|%s" % ("---|" * len(cal.bands))]
    lines += ["| %s | %s |" % (lamp, " | ".join("%.3f ± %.3f" % (f, s) for f, s in zip(cal.output_factor[i],
                                                                                          cal.output_sigma[i])))
              for i, lamp in enumerate(cal.lamps)]
    lines += ["", "Lamp flux, µmol s⁻¹: %s" % ", ".join("%s %.4g" % (b, f) for b, f in zip(cal.bands, cal.lamp_flux))]
    if cal.warnings:
        lines += ["", "## Warnings", ""] + ["* " + w for w in cal.warnings]
    return "\n".join(lines) + "\n"


def site_rows(cal: Calibration) -> list:
    """sites.csv: one row per site and band."""
    s = cal.survey
    out = []
    measured = s.values[:, s.columns]
    for i in range(len(s)):
        for b, band in enumerate(cal.bands):
            out.append({"line": int(s.line[i]), "row": int(s.row[i]), "x": s.sensors.center[i, 0],
                        "y": s.sensors.center[i, 1], "z": s.sensors.center[i, 2], "band": band,
                        "measured": measured[i, b], "before": cal.before.predicted[i, b], "after": cal.final[i, b]})
    return out


def rows_picture(path, cal: Calibration, bands=None) -> None:
    """measured / simulated along each row of sites, before and after, for up to three bands (matplotlib)."""
    from ..report.plots import require_matplotlib

    plt = require_matplotlib()
    s = cal.survey
    picks = bands or sorted({0, len(cal.bands) // 2, len(cal.bands) - 1})
    heights = np.unique(np.round(s.sensors.center[:, 2], 6))
    fig, axes = plt.subplots(len(picks), len(heights), figsize=(5 * len(heights), 3.2 * len(picks)), squeeze=False)
    y = s.values[:, s.columns]
    for i, b in enumerate(picks):
        for j, h in enumerate(heights):
            ax = axes[i, j]
            at = np.isclose(s.sensors.center[:, 2], h)
            for r in np.unique(s.row[at]):
                k = np.flatnonzero(at & (s.row == r))
                k = k[np.argsort(s.sensors.center[k, 0])]
                x = s.sensors.center[k, 0] + 0.0
                ax.plot(x, y[k, b] / cal.before.predicted[k, b], color="0.6", lw=0.8)
                ax.plot(x, y[k, b] / cal.final[k, b], color="C3", lw=0.8)
            ax.axhline(1, color="k", lw=0.5)
            ax.set_title("%s nm, z = %g: measured / simulated (grey before, red after)" % (cal.bands[b], h), fontsize=8)
            ax.set_xlabel("x along each row")
    fig.tight_layout()
    fig.savefig(path, dpi=110)
    plt.close(fig)


def write_outputs(out, cal: Calibration, base: str, scene_name: str, plot: bool = True) -> list:
    """Write the fitted scene, calibration.json, report.md, sites.csv (and rows.png when matplotlib is there)."""
    from ..run.results import atomic_write, csv_text, json_text

    out = Path(out)
    out.mkdir(parents=True, exist_ok=True)
    written = []
    for name, text in (("scene.toml", scene_text(base, cal, cal.survey.path)),
                       ("calibration.json", json_text(summary(cal))),
                       ("report.md", report_text(cal, scene_name)),
                       ("sites.csv", csv_text(site_rows(cal)))):
        atomic_write(out / name, text)
        written.append(out / name)
    if plot:
        try:
            rows_picture(out / "rows.png", cal)
            written.append(out / "rows.png")
        except Exception as exc:    # no matplotlib: the numbers are written, the picture is not
            print("lpy-light: rows.png not drawn (%s)" % exc, file=sys.stderr)
    return written


__all__ = ["calibrate", "LampRuns", "Parameter", "Fit", "Calibration", "OUTPUT_MODELS", "candidate_parameters",
           "fit", "cross_validated", "jackknife", "write_outputs", "scene_text", "summary"]
