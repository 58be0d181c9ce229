"""The calibration's statistical model: a survey's readings as the lamps' light, with priors on what may differ
from the chamber as described, fitted by maximum a posteriori, and only what the survey identifies.

The light at site s in band b is linear in each lamp's output and, over a few millimetres or per cent, in the
physical parameters θ (a lamp's position, a wall's reflectance, a diffuser's spread)::

    f[s, b] = Σ_l c[l, b] · (X[l, s, b] + Σ_j (θ_j − θ⁰_j) · J[j, l, s, b])
    c[l, b] = exp(g_b + a_l + t_l · λ_b + e[l, b])

``X`` (L, S, B) is lamp l's light at site s in band b at θ⁰ (photons m⁻² per photon of the scene), ``J``
(P, L, S, B) its derivatives.  ``g_b`` is one scale per band, free: the chamber as described, its flux fitted
("before").  What may differ from the description has a prior (:data:`PRIOR`), centred on the description:
a lamp's output relative to the others ``a_l``, a spectral tilt ``t_l`` (``λ_b``: the band's centre, −½..½
over the bands' span), a free part per band ``e[l, b]``, and each θ_j.

The fit minimises ``‖W r‖² + Σ ((φ − φ⁰) / σ_prior)²``, ``r = (y − f) / y`` the relative residuals and W the
inverse square root of their covariance across one site's bands (``noise``: each band's rms and one
correlation between bands, estimated from the residuals: the bands of one reading share its errors, so twelve
bands do not tell a lamp's position twelve times).  The posterior covariance is the inverse of that sum's
Gauss-Newton Hessian.

**Fit only what the survey identifies** (:func:`solve`).  A parameter whose posterior σ is more than
:data:`IDENTIFIED` times its prior σ was not told by the survey: it is left at its nominal value (a lamp's
height from sites on one plane is told apart from its output only by the inverse-square law's curvature, and
most surveys cannot).  A parameter the fit pushes to its bound is a failed fit, not a result: left at its
nominal value too.  Both are reported, with the ratio.

**Honest scores** (:func:`cross_validated`): the whole procedure, the noise estimate and the choice of what is
identified included, is run again with each row of sites left out; the left-out row's prediction is the score.
Nothing is chosen by that score, so it is not optimistic.

**Uncertainty away from the survey** (:func:`predicted_sigma`): the light's σ anywhere the lamps were traced,
from the posterior of what was fitted and the prior of what was not.
"""
from __future__ import annotations

from dataclasses import dataclass

import numpy as np

#: prior σ of what may differ from the chamber as described (log of a factor: 0.3 is about 30 %): a lamp's
#: output relative to the others (lamps of one kind differ by age and dirt: Angers' survey finds 0.5-1.8), a
#: spectral tilt over the bands' span, a lamp's own band beyond those two; a wall's reflectance factor and a
#: diffuser's spread (the optical tables' uncertainty); a lamp's position, in metres (a drawing's few mm;
#: a third of the calibration's tolerance where that is less).  Chosen on survey-v split into fitted and
#: held-out sites (benchmarks/calibration_holdout.py, docs/calibration.md)
PRIOR = {"output": 0.3, "tilt": 0.2, "band": 0.1, "reflectance": 0.1, "spread": 0.2, "position": 0.005}
#: a parameter is fitted only if the survey shrinks its σ to at most this fraction of its prior σ
IDENTIFIED = 0.6
#: the correlation between one site's bands is kept within this range (a floor: bands share each reading)
CORRELATION = (0.0, 0.95)


@dataclass
class Layout:
    """Where each parameter sits in the vector φ: ``g`` (B,) band scales, ``a`` (L,), ``t`` (L,), ``e`` (L·B,)
    (t and e only with more than one band), ``theta`` (P,); their prior means ``mu`` and σ ``sigma`` (inf: no
    prior), bounds ``lower``/``upper``, names ``label`` and kinds ``kind``."""

    L: int
    B: int
    P: int
    lam: np.ndarray
    mu: np.ndarray
    sigma: np.ndarray
    lower: np.ndarray
    upper: np.ndarray
    label: list
    kind: list
    g: slice
    a: slice
    t: slice
    e: slice
    theta: slice

    @property
    def n(self) -> int:
        return len(self.mu)


def layout(lamps: list, bands: list, wavelengths: np.ndarray, params: list) -> Layout:
    """The parameter vector for ``lamps`` (names), ``bands`` (labels), their centres ``wavelengths`` (B,) and
    the physical ``params`` (:class:`lpy_light.calibration.calibrate.Parameter`)."""
    L, B, P = len(lamps), len(bands), len(params)
    spectral = B > 1
    lam = (wavelengths - 0.5 * (wavelengths.min() + wavelengths.max())) / max(np.ptp(wavelengths), 1e-9)
    sizes = [("g", B), ("a", L), ("t", L if spectral else 0), ("e", L * B if spectral else 0), ("theta", P)]
    slices, at = {}, 0
    for name, size in sizes:
        slices[name] = slice(at, at + size)
        at += size
    mu, sigma = np.zeros(at), np.full(at, np.inf)
    lower, upper = np.full(at, -np.inf), np.full(at, np.inf)
    label, kind = [None] * at, [None] * at
    for b, band in enumerate(bands):
        i = slices["g"].start + b
        label[i], kind[i] = "scale %s" % band, "scale"
    for li, lamp in enumerate(lamps):
        i = slices["a"].start + li
        label[i], kind[i], sigma[i] = "%s output" % lamp, "output", PRIOR["output"]
        if spectral:
            i = slices["t"].start + li
            label[i], kind[i], sigma[i] = "%s tilt" % lamp, "tilt", PRIOR["tilt"]
            for b, band in enumerate(bands):
                i = slices["e"].start + li * B + b
                label[i], kind[i], sigma[i] = "%s output %s" % (lamp, band), "band", PRIOR["band"]
    for j, p in enumerate(params):
        i = slices["theta"].start + j
        label[i], kind[i] = p.label, p.group
        mu[i], sigma[i], lower[i], upper[i] = p.base, p.prior, p.lower, p.upper
    return Layout(L, B, P, lam, mu, sigma, lower, upper, label, kind, **slices)


def outputs(lay: Layout, phi: np.ndarray) -> np.ndarray:
    """c (L, B): each lamp's output per band (photons of the scene per photon traced, µmol s⁻¹ scale)."""
    log_c = phi[lay.g][None, :] + phi[lay.a][:, None]
    if lay.t.stop > lay.t.start:
        log_c = log_c + phi[lay.t][:, None] * lay.lam[None, :] + phi[lay.e].reshape(lay.L, lay.B)
    return np.exp(log_c)


def light(lay: Layout, phi, X0, J, at) -> tuple:
    """``(f (S, B), c (L, B), X (L, S, B))``: the light the parameters φ predict at the sites of ``X0`` (L, S, B)
    traced at θ = ``at``, ``J`` (P, L, S, B) its derivatives."""
    X = X0 + np.einsum("j,jlsb->lsb", phi[lay.theta] - at, J) if lay.P else X0
    c = outputs(lay, phi)
    return np.einsum("lb,lsb->sb", c, X), c, X


def derivatives(lay: Layout, phi, X0, J, at) -> np.ndarray:
    """∂f/∂φ (S, B, n) at φ."""
    f, c, X = light(lay, phi, X0, J, at)
    S = X0.shape[1]
    D = np.zeros((S, lay.B, lay.n))
    D[:, np.arange(lay.B), lay.g.start + np.arange(lay.B)] = f
    cX = c[:, None, :] * X                                   # (L, S, B)
    D[:, :, lay.a] = cX.transpose(1, 2, 0)
    if lay.t.stop > lay.t.start:
        D[:, :, lay.t] = (cX * lay.lam[None, None, :]).transpose(1, 2, 0)
        e = D[:, :, lay.e].reshape(S, lay.B, lay.L, lay.B)
        for b in range(lay.B):
            e[:, b, :, b] = cX[:, :, b].T
        D[:, :, lay.e] = e.reshape(S, lay.B, -1)
    if lay.P:
        D[:, :, lay.theta] = np.einsum("lb,jlsb->sbj", c, J)
    return D


@dataclass
class Noise:
    """The relative residuals' scatter: ``sigma`` (B,) each band's rms, ``rho`` one correlation between any two
    bands of a site.  The fit weighs each band by 1 / σ_b (``W``, diagonal); the correlation enters the
    parameters' covariance (``R``): twelve bands of one reading do not tell a lamp's position twelve times."""

    sigma: np.ndarray
    rho: float

    @property
    def W(self) -> np.ndarray:
        return np.diag(1.0 / self.sigma)

    @property
    def R(self) -> np.ndarray:
        B = len(self.sigma)
        return self.rho * np.ones((B, B)) + (1 - self.rho) * np.eye(B)


def noise_of(r: np.ndarray, dof: float = 0.0) -> Noise:
    """:class:`Noise` from residuals ``r`` (S, B), ``dof`` parameters fitted to them (a correction for the
    rms: residuals are smaller than the noise by what the fit took)."""
    S, B = r.shape
    n = S * B
    inflate = n / max(n - dof, 0.25 * n)
    sigma = np.sqrt(np.mean(r ** 2, axis=0) * inflate)
    sigma = np.maximum(sigma, 1e-4)
    rho = 0.0
    if B > 1 and S > 1:
        R = np.corrcoef(r.T)
        rho = float(np.nanmean(R[~np.eye(B, dtype=bool)]))
    return Noise(sigma, float(np.clip(np.nan_to_num(rho), *CORRELATION)))


@dataclass
class Solution:
    """A fit: ``phi`` (n,), ``free`` (n,) bool, ``cov`` (n, n) the fitted parameters' covariance (prior σ² where
    not free), ``joint`` (n, n) every parameter's posterior (:func:`posterior`), ``noise``, ``at`` (P,) the θ
    the runs were traced at, ``notes`` {index: why it was left at its nominal value}, ``ratio`` (n,) σ / prior σ
    when everything was free (0 without prior), ``residuals`` (S, B)."""

    phi: np.ndarray
    free: np.ndarray
    cov: np.ndarray
    joint: np.ndarray
    noise: Noise
    at: np.ndarray
    notes: dict
    ratio: np.ndarray
    residuals: np.ndarray

    def sigma(self, lay: Layout) -> np.ndarray:
        """(n,) posterior σ (lamps' outputs as differences from their mean: :func:`contrast_sigma`)."""
        return contrast_sigma(lay, self.cov)


def _whiten(noise: Noise, r, D):
    W = noise.W
    return np.einsum("cb,sb->sc", W, r).ravel(), np.einsum("cb,sbn->scn", W, D).reshape(r.size, D.shape[-1])


def _initial(lay: Layout, X0, y) -> np.ndarray:
    """φ at the priors' means with each band's scale fitted (relative least squares, closed form)."""
    phi = lay.mu.copy()
    f = np.einsum("lsb->sb", X0) * np.exp(phi[lay.a]).mean()
    t = f / y
    phi[lay.g] = np.log(np.maximum(t.sum(axis=0) / np.maximum((t * t).sum(axis=0), 1e-300), 1e-300))
    return phi


def map_fit(lay: Layout, y, X0, J, at, free, noise: Noise, phi=None, iterations: int = 60):
    """Maximum a posteriori φ with only ``free`` (n,) varying (the rest at ``phi``'s values, by default the
    priors' means), θ kept within its bounds: ``(phi, cov of the free part (k, k), residuals (S, B))``.
    Levenberg-Marquardt on the stacked residuals [W r; (φ − μ) / σ]; the covariance is the sandwich
    H⁻¹ M H⁻¹ (H the Gauss-Newton Hessian, M the same with the bands' correlation R between one site's
    residuals), honest where the bands share their errors."""
    phi = _initial(lay, X0, y) if phi is None else phi.copy()
    k = np.flatnonzero(free)
    prior = np.isfinite(lay.sigma[k])
    inv_s = np.where(prior, 1.0 / np.where(prior, lay.sigma[k], 1.0), 0.0)

    def cost_of(p):
        f, _, _ = light(lay, p, X0, J, at)
        rw, _ = _whiten(noise, (y - f) / y, np.zeros(f.shape + (0,)))
        return rw @ rw + np.sum(((p[k] - lay.mu[k]) * inv_s) ** 2)

    damping, cost = 1e-3, cost_of(phi)
    for _ in range(iterations):
        f, _, _ = light(lay, phi, X0, J, at)
        D = derivatives(lay, phi, X0, J, at)[:, :, k]
        rw, Jw = _whiten(noise, (y - f) / y, -D / y[:, :, None])
        pr = (phi[k] - lay.mu[k]) * inv_s
        A = Jw.T @ Jw + np.diag(inv_s ** 2)
        grad = Jw.T @ rw + inv_s * pr
        improved = False
        for _ in range(12):
            step = np.linalg.solve(A + damping * np.diag(np.diag(A) + 1e-12), -grad)
            trial = phi.copy()
            trial[k] += step
            trial = np.clip(trial, lay.lower, lay.upper)
            new = cost_of(trial)
            if new <= cost:
                improved = abs(cost - new) > 1e-12 * max(cost, 1e-300)
                phi, cost, damping = trial, new, max(damping / 4, 1e-9)
                break
            damping *= 8
        if not improved:
            break
    f, _, _ = light(lay, phi, X0, J, at)
    D = derivatives(lay, phi, X0, J, at)[:, :, k]
    A = np.einsum("cb,sbn->scn", noise.W, -D / y[:, :, None])           # (S, B, k) weighted
    P = np.diag(inv_s ** 2)
    H_inv = np.linalg.pinv(np.einsum("sbn,sbm->nm", A, A) + P, hermitian=True)
    M = np.einsum("sbn,bc,scm->nm", A, noise.R, A) + P                  # the bands' shared errors
    return phi, H_inv @ M @ H_inv, (y - f) / y


def posterior(lay: Layout, y, X0, J, at, phi, noise: Noise) -> np.ndarray:
    """(n, n) the posterior covariance of every parameter, fitted or not, at φ: the survey's information with
    one site's bands correlated (R) plus the priors'.  What the light's σ away from the survey is drawn from:
    the survey constrains combinations of parameters it cannot tell apart one by one."""
    f, _, _ = light(lay, phi, X0, J, at)
    A = np.einsum("cb,sbn->scn", noise.W, -derivatives(lay, phi, X0, J, at) / y[:, :, None])
    R_inv = np.linalg.inv(noise.R)
    prior = np.where(np.isfinite(lay.sigma), 1.0 / np.where(np.isfinite(lay.sigma), lay.sigma, 1.0) ** 2, 0.0)
    return np.linalg.pinv(np.einsum("sbn,bc,scm->nm", A, R_inv, A) + np.diag(prior), hermitian=True)


def _effective_parameters(lay: Layout, k, cov_k) -> float:
    """How many parameters the data fitted: one per free parameter without prior, 1 − σ_post²/σ_prior² for
    each with one."""
    s = lay.sigma[k]
    prior = np.isfinite(s)
    return float((~prior).sum() + np.sum(1 - np.diag(cov_k)[prior] / s[prior] ** 2))


def _full_cov(lay: Layout, free, cov_k) -> np.ndarray:
    """(n, n): the posterior covariance of the free parameters, the prior's σ² for the others (flat ones: 0)."""
    cov = np.diag(np.where(np.isfinite(lay.sigma), lay.sigma, 0.0) ** 2)
    k = np.flatnonzero(free)
    cov[np.ix_(k, k)] = cov_k
    cov[np.ix_(k, np.flatnonzero(~free))] = 0.0
    cov[np.ix_(np.flatnonzero(~free), k)] = 0.0
    return cov


def _contrast_groups(lay: Layout) -> list:
    """Index arrays of the lamps' output parameters of one kind (and band): only their differences between lamps
    are told apart from the bands' free scales."""
    groups = [np.arange(lay.a.start, lay.a.stop)]
    if lay.t.stop > lay.t.start:
        groups.append(np.arange(lay.t.start, lay.t.stop))
        groups += [lay.e.start + np.arange(lay.L) * lay.B + b for b in range(lay.B)]
    return groups


def contrast_sigma(lay: Layout, cov: np.ndarray) -> np.ndarray:
    """(n,) posterior σ of each parameter: θ as they are; a lamp's output, tilt and band as its difference from
    the lamps' mean (the mean goes with the bands' scales, which nothing constrains but the survey)."""
    sd = np.sqrt(np.maximum(np.diag(cov), 0.0))
    for idx in _contrast_groups(lay):
        P = np.eye(len(idx)) - 1.0 / len(idx)
        sd[idx] = np.sqrt(np.maximum(np.diag(P @ cov[np.ix_(idx, idx)] @ P), 0.0))
    return sd


def identified_ratio(lay: Layout, cov: np.ndarray) -> np.ndarray:
    """(n,) :func:`contrast_sigma` over the prior's σ of the same (1 for a single lamp's output: it is the bands'
    scale); 0 for the parameters without a prior."""
    prior = np.where(np.isfinite(lay.sigma), lay.sigma, np.inf)
    for idx in _contrast_groups(lay):
        prior[idx] = prior[idx] * np.sqrt(1 - 1.0 / len(idx)) if len(idx) > 1 else 0.0
    with np.errstate(divide="ignore", invalid="ignore"):
        ratio = contrast_sigma(lay, cov) / prior
    return np.where(np.isfinite(prior) & (prior > 0), ratio, np.where(prior == 0, 1.0, 0.0))


def solve(lay: Layout, y, X0, J, at=None) -> Solution:
    """The whole fit on the sites of ``y`` (S, B): the bands' scales alone, the noise from their residuals;
    everything free, the noise again; then only what the survey identifies (posterior σ ≤ :data:`IDENTIFIED` ×
    prior σ) and does not push to a bound, the noise once more, and the final fit."""
    at = lay.mu[lay.theta].copy() if at is None else np.asarray(at, float)
    scales = np.zeros(lay.n, bool)
    scales[lay.g] = True
    everything = np.ones(lay.n, bool)
    noise = Noise(np.full(lay.B, 0.05), 0.5)
    phi, cov, r = map_fit(lay, y, X0, J, at, scales, noise)
    noise = noise_of(r, lay.B)
    phi, cov, r = map_fit(lay, y, X0, J, at, everything, noise, phi)
    noise = noise_of(r, _effective_parameters(lay, np.arange(lay.n), cov))
    phi, cov, r = map_fit(lay, y, X0, J, at, everything, noise, phi)
    ratio = identified_ratio(lay, cov)
    free = ~(ratio > IDENTIFIED)
    notes = {int(i): "not identified by the survey (its σ from the survey %.2f of the prior's)" % ratio[i]
             for i in np.flatnonzero(~free)}
    for _ in range(lay.P + 1):
        start = _initial(lay, X0, y)
        start[free] = phi[free]
        phi, cov_k, r = map_fit(lay, y, X0, J, at, free, noise, start)
        span = lay.upper - lay.lower
        bound = free & np.isfinite(span) & (np.minimum(phi - lay.lower, lay.upper - phi) < 1e-3 * span)
        if not bound.any():
            break
        for i in np.flatnonzero(bound):
            notes[int(i)] = "pushed to its bound (%.4g): a failed fit, left at its nominal value" % phi[i]
        free &= ~bound
    k = np.flatnonzero(free)
    noise = noise_of(r, _effective_parameters(lay, k, cov_k))
    phi, cov_k, r = map_fit(lay, y, X0, J, at, free, noise, phi)
    return Solution(phi, free, _full_cov(lay, free, cov_k), posterior(lay, y, X0, J, at, phi, noise), noise, at,
                    notes, ratio, r)


def predict(lay: Layout, sol: Solution, X0, J) -> np.ndarray:
    """f (S, B) at the sites of ``X0`` (L, S, B) (traced at ``sol.at``)."""
    return light(lay, sol.phi, X0, J, sol.at)[0]


def predicted_sigma(lay: Layout, sol: Solution, X0, J) -> np.ndarray:
    """(S, B) the relative σ of the predicted light at the sites of ``X0``, from every parameter's posterior
    (:func:`posterior`: a lamp's height the survey cannot tell counts with nearly its prior σ where it matters,
    above the survey, and little at the survey's sites, whose light it fits in combination with the rest)."""
    f, _, _ = light(lay, sol.phi, X0, J, sol.at)
    D = derivatives(lay, sol.phi, X0, J, sol.at)
    var = np.einsum("sbi,ij,sbj->sb", D, sol.joint, D)
    return np.sqrt(np.maximum(var, 0.0)) / np.where(f > 0, f, np.inf)


def relative_rms(predicted, y) -> np.ndarray:
    """(B,) rms over sites of (predicted − y) / y."""
    return np.sqrt(np.mean(((predicted - y) / y) ** 2, axis=0))


def band_only(lay: Layout, y, X0, J, at=None) -> np.ndarray:
    """φ of the chamber as described (θ nominal, ``X0`` traced at ``at``) with one scale per band fitted: what
    "before" means."""
    scales = np.zeros(lay.n, bool)
    scales[lay.g] = True
    at = lay.mu[lay.theta] if at is None else at
    return map_fit(lay, y, X0, J, at, scales, Noise(np.full(lay.B, 0.05), 0.0))[0]


def rms_sigma(errors, rows) -> np.ndarray:
    """(B,) the standard error of the rms over sites of ``errors`` (S, B: relative errors) by the delete-a-row
    jackknife over ``rows`` (S,): residuals correlate along a row, so a row, not a site, is the independent unit.
    NaN with fewer than two rows."""
    e2 = np.asarray(errors, float) ** 2
    rows = np.asarray(rows)
    names = np.unique(rows)
    if len(names) < 2:
        return np.full(e2.shape[1], np.nan)
    total, n = e2.sum(axis=0), len(e2)
    rms = np.array([np.sqrt((total - e2[rows == r].sum(axis=0)) / (n - np.count_nonzero(rows == r)))
                    for r in names])
    k = len(names)
    return np.sqrt((k - 1) / k * ((rms - rms.mean(axis=0)) ** 2).sum(axis=0))


def cross_validated_errors(lay: Layout, y, X0, J, rows, at=None) -> np.ndarray:
    """(S, B) each site's relative error (predicted − y) / y, predicted by the whole :func:`solve` on the other
    rows."""
    after = np.zeros_like(y)
    for row in np.unique(rows):
        out = rows == row
        sol = solve(lay, y[~out], X0[:, ~out], J[:, :, ~out], at)
        after[out] = predict(lay, sol, X0[:, out], J[:, :, out])
    return (after - y) / y


def cross_validated(lay: Layout, y, X0, J, rows, at=None) -> np.ndarray:
    """(B,) the rms of each row's prediction by the whole :func:`solve` on the other rows (its σ:
    :func:`rms_sigma` of :func:`cross_validated_errors`)."""
    return np.sqrt(np.mean(cross_validated_errors(lay, y, X0, J, rows, at) ** 2, axis=0))


def cross_validated_scales_errors(lay: Layout, y, X0, J, rows) -> np.ndarray:
    """(S, B) the same for the chamber as described (``X0`` at the nominal θ), one scale per band."""
    before = np.zeros_like(y)
    at = lay.mu[lay.theta]
    for row in np.unique(rows):
        out = rows == row
        phi = band_only(lay, y[~out], X0[:, ~out], J[:, :, ~out])
        before[out] = light(lay, phi, X0[:, out], J[:, :, out], at)[0]
    return (before - y) / y


def cross_validated_scales(lay: Layout, y, X0, J, rows) -> np.ndarray:
    """(B,) the rms of :func:`cross_validated_scales_errors`."""
    return np.sqrt(np.mean(cross_validated_scales_errors(lay, y, X0, J, rows) ** 2, axis=0))
