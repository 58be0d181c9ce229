"""A chamber fitted to its survey: ``lpy-light calibrate SCENE SURVEY.csv --out DIR [--check HELD.csv]``.

The light at a site is linear in each lamp's output, so the scene is traced once per lamp
(:class:`LampRuns`: ``X[l, s, b]``, site s's photon density per photon of lamp l, band b), and once more per
physical parameter that is not linear (:class:`Parameter`: a lamp's position, a diffuser's straight-through
part, a wall's reflectance) for its derivative, by finite differences with common random numbers (the same
seed and photons, so that a difference is the parameter's and not noise).  The survey ``y[s, b]``
(µmol m⁻² s⁻¹) is then fitted by the model of :mod:`lpy_light.calibration.model`: one scale per band, free,
and priors, centred on the chamber as described, on what may differ from it (each lamp's output and spectrum,
each θ).  Only what the survey identifies is fitted; the rest stays at its nominal value and the report says
why.  After the fit the lamps are traced again at the fitted θ and the model linearised there
(:data:`OUTER` times); the final residuals are those of that run, not of the linear model.

The same runs light sites that are never fitted: the survey's cross-validation folds (whole rows left out,
the whole fit repeated without them), ``check`` (a held-out survey: its rms before and after is what the fit
bought), and probes over the chamber (:func:`probe_sites`: the fitted light's σ away from the survey, from
every parameter's posterior).

Outputs (:func:`write_outputs`): ``scene.toml`` (the original scene plus ``[lamps.*]``, ``[materials.*]`` and
``lamp_flux``: :mod:`lpy_light.chamber.overrides`), ``calibration.json``, ``report.md``, ``sites.csv`` (each
site and band, measured and simulated before and after) and, with matplotlib, ``rows.png``.
"""
from __future__ import annotations

import dataclasses
import sys
import time
from dataclasses import dataclass, field
from pathlib import Path

import numpy as np

from . import model as mdl
from ..chamber import overrides as ov
from ..chamber.emitters import Emitters
from ..chamber.sensors import DISC, Sensors
from ..errors import InputError

#: times the lamps are traced again at the fitted parameters and the model linearised there (Gauss-Newton with
#: the first derivatives kept: a lamp moved 2 cm is found within its σ where one linearisation falls short)
OUTER = 2
#: at most this many lamps are fitted one by one (each costs runs)
MAX_LAMPS = 16
#: probes: a grid of this many points a side over the chamber's floor plan, at this many heights from the
#: survey's lowest site to :data:`HEADROOM` under the lowest lamp
PROBE_GRID, PROBE_LEVELS, HEADROOM = 4, 4, 0.3
#: the light above the survey is "constrained" where its σ is at most this many times its σ at the survey's
#: own sites; a height is warned about where its median σ is beyond that and beyond WARN_SIGMA (about a
#: reading's own scatter: below it the survey could not have told more)
CONSTRAINED, WARN_SIGMA = 2.0, 0.03


@dataclass
class Parameter:
    """A physical parameter that is not linear in the light: its override (``table``, ``name``, ``key``;
    ``axis`` for a lamp's shift), value with nothing changed ``base``, finite-difference step, bounds, prior σ
    (:data:`lpy_light.calibration.model.PRIOR`), unit, and the lamps whose runs it changes (None: all)."""

    group: str
    table: str
    name: str
    key: str
    step: float
    lower: float
    upper: float
    unit: str
    prior: float = 1.0
    axis: int = -1
    base: float = 0.0
    lamps: list | None = None

    @property
    def label(self) -> str:
        return "%s.%s%s" % (self.name, self.key, "xyz"[self.axis] if self.axis >= 0 else "")


@dataclass
class Calibration:
    """What ``calibrate`` found; see :func:`calibrate`.  Arrays over the survey's S sites, its B measured bands,
    the L lamps; ``*_rms`` are relative rms per band (B,)."""

    lamps: list
    bands: list
    survey: object
    before: np.ndarray                # (S, B) the chamber as described, one scale per band
    final: np.ndarray                 # (S, B) the lamps traced again at the fitted parameters
    cv_before: np.ndarray             # (B,) cross-validated rms: each row predicted by the fit without it
    cv_after: np.ndarray
    rms_before: np.ndarray            # (B,) rms of the fits on all sites
    rms_after: np.ndarray
    rms_spectrum: np.ndarray | None   # (B,) the scene's own lamp spectrum, nothing fitted
    parameters: list                  # report rows: every candidate, fitted or not, and why
    output_factor: np.ndarray         # (L, B) each lamp's output relative to the scene's
    output_sigma: np.ndarray
    lamp_flux: np.ndarray             # (B,) µmol s⁻¹
    noise: dict                       # the readings' scatter the fit assumed
    probes: list                      # report rows: where the fitted light is how uncertain
    check: dict | None                # the held-out survey: its rms before and after
    warnings: list
    photons: int
    seconds: float
    runs: int
    scene_overrides: dict = field(default_factory=dict)
    cv_before_sigma: np.ndarray | None = None   # (B,) standard errors of cv_before, cv_after (jackknife over rows)
    cv_after_sigma: np.ndarray | None = None


# --- the runs ------------------------------------------------------------------------------------
class LampRuns:
    """Per-lamp photon densities of ``chamber`` at ``sensors``, cached by the overrides that change them.

    ``densities(lamps, materials)`` -> (L, S, B) photons per m² per emitted photon of each lamp (weighted by its
    output), every run with ``photons`` photons and seed ``seed`` (common random numbers)."""

    def __init__(self, chamber, sensors: Sensors, photons: int, seed: int, threads=None, say=None):
        self.chamber = dataclasses.replace(chamber, sensors=sensors)
        self.lamps = list(dict.fromkeys(chamber.emitters.name))
        self.photons, self.seed, self.threads = photons, seed, threads
        self.area_m2 = sensors.area * chamber.metres_per_unit ** 2
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

    @staticmethod
    def key(lamp, lamps: dict, materials: dict) -> tuple:
        return (lamp, repr(sorted((k, sorted(v.items())) for k, v in lamps.items() if k == lamp)),
                repr(sorted((k, sorted(v.items())) for k, v in materials.items())))

    def density(self, lamp, lamps: dict, materials: dict) -> np.ndarray:
        from ..run import simulate

        key = self.key(lamp, lamps, materials)
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
    """The physical parameters a survey may fix, in groups, each with its prior σ
    (:data:`lpy_light.calibration.model.PRIOR`): each lamp's position (x, y, z within ``tolerance`` scene
    units, prior σ :data:`~lpy_light.calibration.model.PRIOR`'s, at most a third of it); each diffuser's straight-through part (materials transmitting >10 %, on
    average over bands); each wall's reflectance (the materials of the vertical surfaces, each covering at
    least 10 % of their area; mirrors excluded), a factor in 0.5..1.5 kept below 1 − T."""
    from ..chamber.materials import DIFFUSE_R, DIFFUSE_T, SPECULAR_R, SPECULAR_T

    params = []
    position = min(mdl.PRIOR["position"] / chamber.metres_per_unit, tolerance / 3)
    for lamp in lamps:
        for axis in range(3):
            params.append(Parameter("%s position" % lamp, "lamps", lamp, "shift", 0.3 * tolerance, -tolerance,
                                    tolerance, chamber.unit, prior=position, axis=axis, lamps=[lamp]))
    used = np.unique(chamber.tri_material[:, 0])
    for m in used:
        mat = chamber.materials[m]
        T = mat.events[DIFFUSE_T] + mat.events[SPECULAR_T]
        if T.mean() > 0.1:
            ts = float((mat.events[SPECULAR_T] / np.where(T > 0, T, 1)).mean())
            params.append(Parameter("%s spread" % mat.name, "materials", mat.name, "specular_transmission",
                                    0.2 if ts < 0.5 else -0.2, 0.0, 1.0, "", prior=mdl.PRIOR["spread"], base=ts))
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
                                top, "×", prior=mdl.PRIOR["reflectance"], base=1.0))
    return params


def probe_sites(chamber, survey) -> tuple:
    """Where the report states the fitted light's σ: ``(sensors, level (N,) int, heights (levels,))``, upward
    discs of the survey's median radius on a :data:`PROBE_GRID` ² grid over the chamber's floor plan (its
    surfaces' extent, inset by a tenth), at :data:`PROBE_LEVELS` heights from the survey's lowest site to
    :data:`HEADROOM` m under the lowest lamp."""
    from ..chamber.overrides import _POINT_ROWS

    lo, hi = chamber.triangles.reshape(-1, 3).min(axis=0), chamber.triangles.reshape(-1, 3).max(axis=0)
    em = chamber.emitters
    lamp_z = min(float(em.data[e, :_POINT_ROWS[int(em.kind[e])], 2].min()) for e in range(len(em)))
    z0 = float(survey.sensors.center[:, 2].min())
    top = lamp_z - HEADROOM / chamber.metres_per_unit
    heights = np.linspace(z0, top, PROBE_LEVELS) if top > z0 else np.array([z0])
    inset = 0.1 * (hi - lo)
    xs = np.linspace(lo[0] + inset[0], hi[0] - inset[0], PROBE_GRID)
    ys = np.linspace(lo[1] + inset[1], hi[1] - inset[1], PROBE_GRID)
    pts = np.array([(x, y, z) for z in heights for y in ys for x in xs])
    level = np.repeat(np.arange(len(heights)), PROBE_GRID * PROBE_GRID)
    r = float(np.median(survey.sensors.radius)) if (survey.sensors.radius > 0).any() else \
        float(np.sqrt(np.median(survey.sensors.area) / np.pi))
    n = len(pts)
    sensors = Sensors(np.full(n, DISC, np.int32), pts, np.tile([0.0, 0.0, 1.0], (n, 1)), np.full(n, r),
                      np.zeros((n, 4, 3)), [("probe", i) for i in range(n)])
    return sensors, level, heights


# --- the whole job ---------------------------------------------------------------------------------
def _relative_outputs(c, runs_weight):
    """Lamp outputs c (L, B) (µmol s⁻¹ of the whole scene were every lamp like lamp l) → factors (L, B) relative
    to the scene's outputs, their mean weighted by the lamps' sampled powers ``runs_weight`` (L,) 1 in every
    band, and the lamps' flux (B,) µmol s⁻¹."""
    Q = runs_weight[:, None]
    flux = (c * Q).sum(axis=0) / Q.sum()
    return c / np.where(flux > 0, flux, 1.0), flux


def _output_sigma(lay, sol, weight, draws: int = 400) -> np.ndarray:
    """(L, B) σ of the lamps' relative outputs, from the posterior (draws of φ, a fixed seed)."""
    rng = np.random.default_rng(0)
    phis = rng.multivariate_normal(sol.phi, sol.cov, size=draws, method="eigh")
    factors = np.array([_relative_outputs(mdl.outputs(lay, p), weight)[0] for p in phis])
    return factors.std(axis=0)


def _parameter_rows(lay, sol, params) -> list:
    """report rows: each θ candidate, each lamp's output (relative to the lamps' mean) and tilt: value, σ, prior
    σ, σ / prior σ, fitted or why not."""
    sigma = sol.sigma(lay)
    rows = []
    for sl, kind in ((lay.theta, None), (lay.a, "output"), (lay.t, "tilt")):
        if sl.stop <= sl.start:
            continue
        centred = sol.phi[sl] - (0.0 if kind is None else sol.phi[sl].mean())
        for k, i in enumerate(range(sl.start, sl.stop)):
            p = params[k] if kind is None else None
            value = centred[k] if kind != "output" else np.exp(centred[k])
            rows.append({"parameter": lay.label[i], "group": p.group if p else "lamp %s" % kind,
                         "value": float(value), "sigma": float(sigma[i] * (value if kind == "output" else 1.0)),
                         "prior_sigma": float(lay.sigma[i]), "sigma_over_prior": float(sol.ratio[i]),
                         "lower": float(p.lower) if p else None, "upper": float(p.upper) if p else None,
                         "unit": p.unit if p else ("× the lamps' mean" if kind == "output" else
                                                   "log, over the bands' span"),
                         "fitted": bool(sol.free[i]), "notes": [sol.notes[i]] if i in sol.notes else []})
    return rows


def _probe_rows(lay, sol, Xp, Jp, level, heights, sigma_survey, unit) -> tuple:
    """(rows, warnings): per probe height, the fitted light's relative σ (mean over bands) at the probes that see
    light: median and largest, and the share within :data:`CONSTRAINED` × the σ at the survey's sites."""
    f = mdl.predict(lay, sol, Xp, Jp)
    sig = mdl.predicted_sigma(lay, sol, Xp, Jp).mean(axis=1)
    lit = f.mean(axis=1) > 0.01 * np.median(f.mean(axis=1))        # a probe inside a bench or a pot reads nothing
    rows, warnings = [], []
    for k, h in enumerate(heights):
        at = lit & (level == k)
        if not at.any():
            continue
        s = sig[at]
        rows.append({"z": float(h), "unit": unit, "probes": int(at.sum()), "sigma_median": float(np.median(s)),
                     "sigma_max": float(s.max()),
                     "constrained_share": float(np.mean(s <= CONSTRAINED * sigma_survey))})
        if np.median(s) > max(CONSTRAINED * sigma_survey, WARN_SIGMA):
            warnings.append("at z = %g %s the fitted light's σ is %.1f %% (median over the chamber's plan), %.1f times "
                            "its σ at the survey's sites: the survey does not constrain the light there"
                            % (h, unit, 100 * np.median(s), np.median(s) / sigma_survey))
    return rows, warnings


def calibrate(chamber, survey, photons: int = 2_000_000, seed: int = 1, threads=None, tolerance: float | None = None,
              say=None, check=None, runs=None) -> Calibration:
    """Fit ``chamber`` to ``survey`` (:class:`lpy_light.calibration.survey.Survey`); see the module docstring.

    ``photons`` per lamp run (nee), ``tolerance`` how far a lamp may move (scene units; default 30 mm),
    ``check`` a held-out survey (never fitted: its rms before and after), ``say(text)`` progress lines.
    ``runs``: a :class:`LampRuns` over the survey's sites, then the check's, then :func:`probe_sites`'s (to share
    runs between fits; made here by default)."""
    say = say or (lambda text: None)
    t0 = time.perf_counter()
    lamps = list(dict.fromkeys(chamber.emitters.name))
    if len(lamps) > MAX_LAMPS:
        raise InputError("the scene has %d light sources; calibrate fits at most %d one by one"
                         % (len(lamps), MAX_LAMPS), chamber.source)
    measured = survey.columns
    y = survey.values[:, measured]
    bands = [lab for lab, m in zip(chamber.band_labels, measured) if m]
    wavelengths = np.array([0.5 * (a + b) for a, b in (chamber.bands or [(0.0, 1.0)])])[measured]
    tolerance = 0.03 / chamber.metres_per_unit if tolerance is None else float(tolerance)
    probes, level, heights = probe_sites(chamber, survey)
    S, H = len(survey), 0 if check is None else len(check)
    fit_i, check_i, probe_i = np.arange(S), np.arange(S, S + H), np.arange(S + H, S + H + len(probes))
    if runs is None:
        parts = [survey.sensors] + ([] if check is None else [check.sensors]) + [probes]
        runs = LampRuns(chamber, Sensors.concat(parts), photons, seed, threads, say)
    say("tracing the %d lamps one at a time (%d photons each, seed %d; %d survey sites, %d held out, %d probes)"
        % (len(lamps), photons, seed, S, H, len(probes)))
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
    lay = mdl.layout(lamps, bands, wavelengths, params)
    def on(X, idx):
        return X[:, idx]

    def J_on(idx):
        return J[:, :, idx]

    sol = mdl.solve(lay, y, on(X0, fit_i), J_on(fit_i))
    at, Xa = lay.mu[lay.theta].copy(), X0
    for _ in range(OUTER if (sol.phi[lay.theta] != at).any() else 0):   # traced again at the fit, linearised there
        at = sol.phi[lay.theta].copy()
        Xa = runs.densities(*_tables(params, at))[:, :, measured] * share
        sol = mdl.solve(lay, y, on(Xa, fit_i), J_on(fit_i), at)
        say("  re-linearised at the fit (%s): %d runs so far" % (
            ", ".join("%s %.4g" % (p.label, v) for p, v, free in zip(params, sol.phi[lay.theta], sol.free[lay.theta])
                      if free) or "no position or material fitted", runs.runs))
    say("cross-validating: the whole fit again without each of %d rows of sites" % len(np.unique(survey.row)))
    cv_errors = mdl.cross_validated_errors(lay, y, on(Xa, fit_i), J_on(fit_i), survey.row, at)
    cv_errors_before = mdl.cross_validated_scales_errors(lay, y, on(X0, fit_i), J_on(fit_i), survey.row)
    cv_after, cv_before = (np.sqrt(np.mean(e ** 2, axis=0)) for e in (cv_errors, cv_errors_before))
    # the lamps traced again where the fit put them: the final residuals are a run's, not the linear model's
    theta = sol.phi[lay.theta].copy()
    Xf = runs.densities(*_tables(params, theta))[:, :, measured] * share if (theta != at).any() else Xa
    fitted = dataclasses.replace(sol, at=theta)
    final = mdl.predict(lay, fitted, on(Xf, fit_i), J_on(fit_i))
    phi_b = mdl.band_only(lay, y, on(X0, fit_i), J_on(fit_i))
    before = mdl.light(lay, phi_b, on(X0, fit_i), J_on(fit_i), lay.mu[lay.theta])[0]
    factor, flux = _relative_outputs(mdl.outputs(lay, sol.phi), weight)
    factor_sigma = _output_sigma(lay, sol, weight)
    table = _parameter_rows(lay, sol, params)
    warnings = ["%s: %s" % (lay.label[i], why) for i, why in sorted(sol.notes.items())
                if "bound" in why]
    sigma_survey = float(np.median(mdl.predicted_sigma(lay, fitted, on(Xf, fit_i), J_on(fit_i)).mean(axis=1)))
    probe_rows, probe_warnings = _probe_rows(lay, fitted, on(Xf, probe_i), J_on(probe_i), level, heights,
                                             sigma_survey, chamber.unit)
    warnings += probe_warnings
    held = None
    if check is not None:
        both = check.columns[measured]
        yc = check.values[:, measured]
        pb = mdl.light(lay, phi_b, on(X0, check_i), J_on(check_i), lay.mu[lay.theta])[0]
        pa = mdl.predict(lay, fitted, on(Xf, check_i), J_on(check_i))
        rb, ra = np.full(len(bands), np.nan), np.full(len(bands), np.nan)
        rb[both] = mdl.relative_rms(pb[:, both], yc[:, both])
        ra[both] = mdl.relative_rms(pa[:, both], yc[:, both])
        sb, sa = np.full(len(bands), np.nan), np.full(len(bands), np.nan)
        sb[both] = mdl.rms_sigma((pb[:, both] - yc[:, both]) / yc[:, both], check.row)
        sa[both] = mdl.rms_sigma((pa[:, both] - yc[:, both]) / yc[:, both], check.row)
        held = {"survey": check.path, "held": check, "sites": H, "rms_before": rb, "rms_after": ra, "before": pb,
                "after": pa, "rms_before_sigma": sb, "rms_after_sigma": sa}
        worse = [b for b, r in zip(bands, ra / rb) if r > 1.1]
        if worse:
            warnings.append("at the held-out sites of %s the fitted chamber is more than 1.1 times worse than the "
                            "unfitted one in %d band(s) (%s)" % (check.path, len(worse), ", ".join(worse)))
    rms_spectrum = None
    if chamber.spectrum is not None and chamber.bands is not None:
        from ..chamber.units import band_photon_flux
        M = band_photon_flux(chamber.spectrum, chamber.bands)[measured]
        tot = on(X0, fit_i).sum(axis=0)
        rms_spectrum = mdl.relative_rms(tot * M / tot.mean(axis=0), y)
    fitted_outputs = bool(sol.free[lay.a].any() or sol.free[lay.t].any() or sol.free[lay.e].any())
    out = Calibration(lamps, bands, survey, before, final, cv_before, cv_after, mdl.relative_rms(before, y),
                      mdl.relative_rms(final, y), rms_spectrum, table, factor, factor_sigma, flux,
                      {"sigma": sol.noise.sigma, "rho": sol.noise.rho}, probe_rows, held, warnings, runs.photons,
                      time.perf_counter() - t0, runs.runs)
    out.cv_before_sigma = mdl.rms_sigma(cv_errors_before, survey.row)
    out.cv_after_sigma = mdl.rms_sigma(cv_errors, survey.row)
    out.scene_overrides = _scene_tables(chamber, lamps, measured, fitted_outputs, factor, params, theta, flux)
    out.scene_overrides["surveyed"] = _surveyed(survey, probe_rows)
    return out


def _surveyed(survey, probe_rows) -> dict:
    """The fitted scene's ``[surveyed]`` table: the box of the survey's sites, a margin of their median spacing
    (nearest neighbour), and the fitted light's σ over the chamber at each probe height."""
    c = survey.sensors.center
    d = np.linalg.norm(c[:, None, :] - c[None, :, :], axis=2)
    np.fill_diagonal(d, np.inf)
    margin = float(np.median(d.min(axis=1))) if len(c) > 1 else 0.0
    return {"lower": [float(v) for v in c.min(axis=0)], "upper": [float(v) for v in c.max(axis=0)],
            "margin": margin, "sigma": [[float(r["z"]), float(r["sigma_median"])] for r in probe_rows]}


def _scene_tables(chamber, lamps, measured, fitted_outputs, factor, params, theta, flux) -> dict:
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
        if not fitted_outputs:
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
    if "surveyed" in t:
        lines += ["", "# where the survey constrains the light (its sites' box, a margin, scene units) and the fitted",
                  "# light's relative σ over the chamber at each height: a plant beyond it is warned about",
                  "[surveyed]"] + ["%s = %s" % (k, _toml_value(v)) for k, v in t["surveyed"].items()]
    return "\n".join(lines) + "\n"


def summary(cal: Calibration) -> dict:
    """calibration.json's content."""
    def per_band(a):
        return None if a is None else {b: (None if not np.isfinite(v) else float(v)) for b, v in zip(cal.bands, a)}
    check = None
    if cal.check is not None:
        c = cal.check
        check = {"survey": c["survey"], "sites": c["sites"], "rms_before": per_band(c["rms_before"]),
                 "rms_after": per_band(c["rms_after"]), "after_over_before": per_band(c["rms_after"] / c["rms_before"]),
                 "rms_before_sigma": per_band(c["rms_before_sigma"]), "rms_after_sigma": per_band(c["rms_after_sigma"]),
                 "before": "the chamber as described, one scale per band fitted on the survey (not on these sites)"}
    return {
        "survey": cal.survey.path, "sites": len(cal.survey), "rows": int(cal.survey.row.max() + 1),
        "lamps": cal.lamps, "bands": cal.bands,
        "photons_per_run": cal.photons, "runs": cal.runs, "seconds": cal.seconds,
        "rms_relative": {"spectrum_only": per_band(cal.rms_spectrum), "before": per_band(cal.rms_before),
                         "after": per_band(cal.rms_after)},
        "cv_rms_relative": {"before": per_band(cal.cv_before), "after": per_band(cal.cv_after),
                            "before_sigma": per_band(cal.cv_before_sigma), "after_sigma": per_band(cal.cv_after_sigma),
                            "how": "leave one row of sites out, the whole fit (what is identified included) on the "
                                   "others; rows: %s; sigma: the rms's standard error, jackknife over the rows"
                                   % cal.survey.row_source},
        "check": check,
        "before": "the scene as described, one µmol s-1 scale per band fitted (lamp outputs as the scene has them)",
        "model": "maximum a posteriori, priors centred on the scene as described (lpy_light.calibration.model); "
                 "only parameters whose posterior σ is at most %g of their prior σ are fitted" % mdl.IDENTIFIED,
        "priors": dict(mdl.PRIOR, position_unit="m"),
        "noise": {"sigma": per_band(cal.noise["sigma"]), "band_correlation": cal.noise["rho"]},
        "parameters": cal.parameters,
        "lamp_outputs": {lamp: {"factor": per_band(cal.output_factor[i]), "sigma": per_band(cal.output_sigma[i])}
                         for i, lamp in enumerate(cal.lamps)},
        "lamp_flux": per_band(cal.lamp_flux),
        "away_from_the_survey": {"probes": cal.probes,
                                 "how": "relative σ of the fitted light (mean over bands) on a grid over the chamber's "
                                        "plan at each height, from every parameter's posterior (readings' scatter "
                                        "not included); constrained: at most %g times its median at the survey's "
                                        "sites" % CONSTRAINED},
        "uncertainty": "posterior σ (the model's Gauss-Newton Hessian, readings' scatter estimated from the "
                       "residuals); the lamp runs' own noise is not in it",
        "warnings": cal.warnings,
        "scene": cal.scene_overrides,
    }


def report_text(cal: Calibration, scene_name: str) -> str:
    """report.md: rms per band before and after, cross-validated and on held-out sites; what was fitted and what
    was not, and why; the σ of the fitted light away from the survey."""
    pct = lambda a: "—" if not np.isfinite(a) else "%.1f" % (100 * a)   # noqa: E731

    def pm(values, sigmas):         # "5.3 ± 0.4" (%): an rms and its standard error
        if sigmas is None:
            return " | ".join(map(pct, values))
        return " | ".join(pct(v) if not np.isfinite(e) else "%s ± %.1f" % (pct(v), 100 * e)
                          for v, e in zip(values, sigmas))
    lines = ["# %s fitted to %s" % (scene_name, cal.survey.path), "",
             "%d sites in %d rows, %d lamps, %d bands; %d runs of %d photons, %.0f s." % (
                 len(cal.survey), cal.survey.row.max() + 1, len(cal.lamps), len(cal.bands), cal.runs, cal.photons,
                 cal.seconds), "",
             "## Relative rms (measured − simulated) / measured, % per band", "",
             "| band | %s |" % " | ".join(cal.bands), "|---|%s" % ("---|" * len(cal.bands))]
    if cal.rms_spectrum is not None:
        lines.append("| lamp spectrum, nothing fitted | %s |" % " | ".join(map(pct, cal.rms_spectrum)))
    lines += ["| before (one scale per band) | %s |" % " | ".join(map(pct, cal.rms_before)),
              "| before, cross-validated | %s |" % pm(cal.cv_before, cal.cv_before_sigma),
              "| after | %s |" % " | ".join(map(pct, cal.rms_after)),
              "| after, cross-validated | %s |" % pm(cal.cv_after, cal.cv_after_sigma),
              "| after / before, cross-validated | %s |" % " | ".join(
                  "%.2f" % r for r in cal.cv_after / cal.cv_before)]
    if cal.check is not None:
        c = cal.check
        lines += ["| held out (%d sites), before | %s |" % (c["sites"], pm(c["rms_before"], c["rms_before_sigma"])),
                  "| held out, after | %s |" % pm(c["rms_after"], c["rms_after_sigma"]),
                  "| held out, after / before | %s |" % " | ".join(
                      "—" if not np.isfinite(r) else "%.2f" % r for r in c["rms_after"] / c["rms_before"])]
    lines += ["", "Cross-validated: each row of sites predicted by the whole fit made without it; ± its standard "
              "error (jackknife over the rows: a survey of few rows tells its rms only so well, and another set of "
              "sites of the same chamber may give an rms that far off).  The readings' "
              "scatter the fit assumed: %s %% per band, correlation %.2f between one site's bands."
              % ("-".join(pct(v) for v in (cal.noise["sigma"].min(), cal.noise["sigma"].max())), cal.noise["rho"]),
              "", "## What was fitted", "",
              "Each parameter has a prior centred on the scene as described; it is fitted only if the survey shrinks "
              "its σ to %g of the prior's or less, and left at its nominal value if the fit pushes it to a bound."
              % mdl.IDENTIFIED, "",
              "| parameter | value | σ | prior σ | σ / prior σ | fitted | why not |", "|---|---|---|---|---|---|---|"]
    lines += ["| %s | %.4g %s | %.2g | %.2g | %.2f | %s | %s |" % (
        p["parameter"], p["value"], p["unit"], p["sigma"], p["prior_sigma"], p["sigma_over_prior"],
        "yes" if p["fitted"] else "no", "; ".join(p["notes"])) for p in cal.parameters]
    lines += ["", "Lamp outputs relative to the scene's (power-weighted mean 1 per band), ± σ:", "",
              "| lamp | %s |" % " | ".join(cal.bands), "|---|%s" % ("---|" * len(cal.bands))]
    lines += ["| %s | %s |" % (lamp, " | ".join("%.3f ± %.3f" % (f, s) for f, s in zip(cal.output_factor[i],
                                                                                          cal.output_sigma[i])))
              for i, lamp in enumerate(cal.lamps)]
    lines += ["", "Lamp flux, µmol s⁻¹: %s" % ", ".join("%s %.4g" % (b, f) for b, f in zip(cal.bands, cal.lamp_flux))]
    if cal.probes:
        lines += ["", "## The fitted light away from the survey", "",
                  "Relative σ of the fitted light (mean over bands) on a %d × %d grid over the chamber's plan, at each "
                  "height, from every parameter's posterior (what the survey cannot tell keeps about its prior σ); "
                  "the readings' own scatter is not in it.  Constrained: σ at most %g times its median at the "
                  "survey's sites." % (PROBE_GRID, PROBE_GRID, CONSTRAINED), "",
                  "| z | probes | σ median, % | σ max, % | constrained |", "|---|---|---|---|---|"]
        lines += ["| %g %s | %d | %s | %s | %.0f %% |" % (r["z"], r["unit"], r["probes"], pct(r["sigma_median"]),
                                                       pct(r["sigma_max"]), 100 * r["constrained_share"])
                  for r in cal.probes]
    if cal.warnings:
        lines += ["", "## Warnings", ""] + ["* " + w for w in cal.warnings]
    return "\n".join(lines) + "\n"


def site_rows(cal: Calibration) -> list:
    """sites.csv: one row per site and band (the held-out survey's too, ``fitted`` false)."""
    out = []
    parts = [(cal.survey, cal.before, cal.final, True)]
    if cal.check is not None:
        parts.append((cal.check["held"], cal.check["before"], cal.check["after"], False))
    for s, before, after, fitted in parts:
        measured = s.values[:, cal.survey.columns]
        for i in range(len(s)):
            for b, band in enumerate(cal.bands):
                out.append({"survey": s.path, "fitted": fitted, "line": int(s.line[i]), "row": int(s.row[i]),
                            "x": s.sensors.center[i, 0], "y": s.sensors.center[i, 1], "z": s.sensors.center[i, 2],
                            "band": band, "measured": measured[i, b], "before": before[i, b], "after": after[i, b]})
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
                ax.plot(x, y[k, b] / cal.before[k, b], color="0.6", lw=0.8)
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


__all__ = ["calibrate", "LampRuns", "Parameter", "Calibration", "candidate_parameters", "probe_sites", "write_outputs",
           "scene_text", "summary", "report_text"]
