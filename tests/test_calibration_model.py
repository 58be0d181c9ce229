"""The calibration's statistical model (lpy_light.calibration.model) on problems whose answer is known, without
tracing: lamps' light made up as smooth profiles over a line of sites, their derivatives exact.

* a parameter the sites tell is recovered within its stated σ;
* one they cannot tell (its derivative zero, or the same as a lamp's output) is left at its nominal value and
  said to be;
* a single lamp's output is the bands' scale, never a parameter;
* the cross-validated rms of the whole procedure is close to what held-out sites give."""
from __future__ import annotations

import numpy as np
import pytest

from lpy_light.calibration import model as mdl
from lpy_light.calibration.calibrate import Parameter


def line_of_sites(n=40, lamps=(0.2, 0.8), bands=3):
    """(X (L, S, B), dX/dx (L, S, B), dX/dh (L, S, B), x (S,)): lamps over a line of sites at x in 0..1, each an
    inverse-square profile of height 0.5; x the lamp's place along the line, h its height."""
    x = np.linspace(0.0, 1.0, n)
    spectrum = np.linspace(1.0, 2.0, bands)

    def profile(x0, h):
        return h / ((x[:, None] - x0) ** 2 + h ** 2) ** 1.5 * spectrum[None, :]

    eps = 1e-6
    X = np.stack([profile(x0, 0.5) for x0 in lamps])
    dx = np.stack([(profile(x0 + eps, 0.5) - profile(x0 - eps, 0.5)) / (2 * eps) for x0 in lamps])
    dh = np.stack([(profile(x0, 0.5 + eps) - profile(x0, 0.5 - eps)) / (2 * eps) for x0 in lamps])
    return X, dx, dh, x


def params_for(names, prior=0.01, bound=0.03):
    return [Parameter(n, "lamps", n, "shift", 0.003, -bound, bound, "m", prior=prior) for n in names]


def problem(truth_shift=0.01, truth_output=(1.0, 0.9), noise=0.005, seed=1, with_height=True, n=40):
    X, dx, dh, x = line_of_sites(n)
    names = ["lamp0 x", "lamp1 x"] + (["lamp1 h"] if with_height else [])
    J = np.zeros((len(names),) + X.shape)
    J[0, 0], J[1, 1] = dx[0], dx[1]
    if with_height:
        J[2, 1] = dh[1]
    c = np.array(truth_output)[:, None] * 100.0
    y = np.einsum("lb,lsb->sb", c, X + truth_shift * J[1])
    y = y * (1 + noise * np.random.default_rng(seed).standard_normal(y.shape))
    lay = mdl.layout(["lamp0", "lamp1"], ["b%d" % b for b in range(X.shape[2])], np.array([450.0, 550.0, 650.0]),
                     params_for(names))
    return lay, y, X, J, x


def test_a_shift_the_sites_tell_is_recovered_within_its_sigma():
    lay, y, X, J, _ = problem(with_height=False)
    sol = mdl.solve(lay, y, X, J)
    i = lay.theta.start + 1
    sigma = sol.sigma(lay)
    assert sol.free[i] and sigma[i] < 0.003
    assert abs(sol.phi[i] - 0.01) < 3 * sigma[i], (sol.phi[i], sigma[i])
    # the other lamp did not move: its shift is fitted too, and within 3σ of nothing
    j = lay.theta.start
    assert abs(sol.phi[j]) < 3 * sigma[j]
    # the lamps' outputs: 0.9 relative, within 3σ (the difference of two logs)
    a = sol.phi[lay.a]
    assert abs((a[1] - a[0]) - np.log(0.9)) < 3 * np.hypot(sigma[lay.a.start], sigma[lay.a.start + 1])


def test_a_parameter_the_sites_cannot_tell_stays_at_its_nominal_value():
    lay, y, X, J, _ = problem()
    J[2] = 0.0                                   # a height whose effect the sites do not see
    sol = mdl.solve(lay, y, X, J)
    i = lay.theta.start + 2
    assert not sol.free[i] and sol.phi[i] == 0.0 and "not identified" in sol.notes[i]
    assert sol.ratio[i] > mdl.IDENTIFIED
    # what is not fitted keeps its prior's σ: the light's σ where it would matter says so
    assert sol.sigma(lay)[i] == pytest.approx(lay.sigma[i])


def test_a_height_confounded_with_the_lamps_output_is_not_fitted():
    """A height change that only scales a lamp's light is its output again: the sites cannot tell the two."""
    lay, y, X, J, _ = problem()
    J[2] = 0.0
    J[2, 1] = -2.0 * X[1]                        # pure scale of lamp 1's light
    sol = mdl.solve(lay, y, X, J)
    i = lay.theta.start + 2
    assert not sol.free[i] and sol.phi[i] == 0.0


def test_a_single_lamps_output_is_the_bands_scale():
    X, dx, _, _ = line_of_sites(lamps=(0.5,))
    y = 50.0 * X[0] * (1 + 0.003 * np.random.default_rng(2).standard_normal(X[0].shape))
    lay = mdl.layout(["lamp"], ["b0", "b1", "b2"], np.array([450.0, 550.0, 650.0]), params_for(["lamp x"]))
    sol = mdl.solve(lay, y, X, dx[None])
    assert not sol.free[lay.a].any() and not sol.free[lay.t].any() and not sol.free[lay.e].any()
    assert np.allclose(mdl.outputs(lay, sol.phi), 50.0, rtol=0.01)


def test_the_cross_validated_rms_is_what_held_out_sites_give():
    """Fit every other site; the report's leave-one-row-out rms against the other sites' actual rms (rows that
    span the line, as a survey's rows span the table; 500 sites a side: the rms's own scatter is ~3 %)."""
    lay, y, X, J, x = problem(noise=0.02, seed=4, n=1000)
    fit, held = np.arange(len(x)) % 2 == 0, np.arange(len(x)) % 2 == 1
    rows = np.arange(fit.sum()) % 5
    cv = mdl.cross_validated(lay, y[fit], X[:, fit], J[:, :, fit], rows)
    sol = mdl.solve(lay, y[fit], X[:, fit], J[:, :, fit])
    actual = mdl.relative_rms(mdl.predict(lay, sol, X[:, held], J[:, :, held]), y[held])
    assert np.all(np.abs(cv / actual - 1) < 0.15), (cv, actual)


def test_the_fitted_light_is_more_certain_at_the_sites_than_far_from_them():
    lay, y, X, J, x = problem()
    near = x < 0.5
    sol = mdl.solve(lay, y[near], X[:, near], J[:, :, near])
    sigma = mdl.predicted_sigma(lay, sol, X, J).mean(axis=1)
    assert np.median(sigma[~near]) > np.median(sigma[near])


@pytest.mark.parametrize("row_share", [0.0, 0.5])
def test_the_rms_standard_error_is_the_spread_of_the_rms_over_surveys(row_share):
    """Relative errors of 120 sites in 12 rows, each a row's common part (``row_share`` of its variance: residuals
    correlate along a row) plus the site's own: over 400 made-up surveys, the jackknife σ of the rms (mean) against
    the rms's actual spread.  A σ that took the sites as independent would be ~0.6x the spread with correlated rows."""
    rng = np.random.default_rng(7)
    rows = np.repeat(np.arange(12), 10)
    rms, sigma = [], []
    for _ in range(400):
        common = rng.standard_normal((12, 2))[rows]
        e = 0.03 * (np.sqrt(row_share) * common + np.sqrt(1 - row_share) * rng.standard_normal((120, 2)))
        rms.append(np.sqrt(np.mean(e ** 2, axis=0)))
        sigma.append(mdl.rms_sigma(e, rows))
    ratio = np.mean(sigma, axis=0) / np.std(rms, axis=0, ddof=1)
    assert np.all((ratio > 0.8) & (ratio < 1.25)), ratio
    assert np.all(np.isnan(mdl.rms_sigma(np.ones((5, 2)), np.zeros(5))))
