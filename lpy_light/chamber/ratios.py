"""A ratio of two Monte Carlo estimates without its first-order bias: R:FR of an organ or a sensor.

The kernel estimates totals T_n (numerator band, red) and T_d (denominator band, far red) from the same
photons, with their covariance C (``LightResult.covariance``).  The plain ratio of the estimates is biased:
with x = T̂_n/T_n − 1 and y = T̂_d/T_d − 1 (zero mean, O(N^-1/2)),

    T̂_n / T̂_d = q (1 + x)(1 − y + y² − …),   E[T̂_n / T̂_d] = q (1 + CV_d² − ρ CV_n CV_d) + O(N⁻²)

(q = T_n/T_d, CV = σ/T, ρ the bands' correlation) -- the bias shrinks as 1/N, so it changes with the
photon budget.  The delta method removes its first-order term with the estimated moments:

    q̃ = q̂ (1 − C_dd/T̂_d²) + C_nd/T̂_d²                     (= q̂ (1 − C_dd/T̂_d² + C_nd/(T̂_n T̂_d)))

whose bias is O(N⁻²): ~3 CV_d⁴ for Gaussian tallies (0.5 % at CV_d = 0.2, 2.4 % at 0.3) plus the tallies'
third moments, which are not tallied.  Each total is turned into µmol m⁻² s⁻¹ by a factor a (the lamps'
flux, σ(a) from an independent normalisation): R = (a_n/a_d) q, and E[1/â_d] = (1 + CV²(a_d))/a_d adds
CV²(a_d) to the bias, removed the same way.

The σ of the corrected estimate is the delta method's first-order σ of the ratio (every first-order term
of q̃ is q̂'s), at the corrected value:

    (σ/R)² = (C_nn − 2 q̂ C_nd + q̂² C_dd) / T̂_n² + CV²(a_n) + CV²(a_d)   (σ = that × |R̃|).

**Where it breaks** (:data:`MAX_DENOMINATOR_CV`): the expansion in y converges only while the denominator
is away from zero; where the far red is within one σ of zero (CV_d = σ(far red)/far red above 1: the
ratio is then unbounded), where the corrected value is not positive, or without any far red, no number is
reported: the ratio is NaN (an empty cell in the csv files), as is its σ.  Between CV_d 0.3 and 1 the next
terms exceed ~2 % of the ratio, but the value is kept: leaving out the organs whose far red *estimate* is
uncertain leaves out the runs that met a rare large far-red deposit, and biases the rest high (on the rose of
``benchmarks/rose.py`` at 10⁶ photons a threshold of 0.3 dropped 41 % of the buds and left the others +0.20
above the same buds at 4·10⁶ photons; with 1, none is dropped and the difference is +0.055 to +0.078,
against +0.078 to +0.098 for the plain ratio: ``docs/performance.md``, "Unbiased R:FR").
"""
from __future__ import annotations

from contextlib import contextmanager

import numpy as np

#: above this relative σ of the denominator (far red, normalisation included) the ratio is not reported (NaN):
#: the far red is then within one σ of zero
MAX_DENOMINATOR_CV = 1.0

_correct = [True]      # switched off by :func:`uncorrected` only (benchmarks, tests: the bias it removes)


@contextmanager
def uncorrected():
    """Within the block, R:FR is the plain ratio of the estimates (:func:`plain_ratio`: biased, and reported
    whatever its far red's σ), as before the correction: for benchmarks and tests that measure the bias the
    correction removes, and for the kernel's digests (which pin those numbers bit for bit), not for results."""
    _correct.append(False)
    try:
        yield
    finally:
        _correct.pop()


def correcting() -> bool:
    """Whether ratios are corrected (always, but inside :func:`uncorrected`)."""
    return _correct[-1]


def plain_ratio(num, den, c_nn, c_dd, c_nd, a_num, a_den, s_num, s_den):
    """The plain ratio (a_num T_num) / (a_den T_den) and its first-order σ, each (S,): biased by
    ~CV_den² − ρ CV_num CV_den (see the module).  ``s_num``, ``s_den``: σ of ``a_num``, ``a_den``.  The
    formula R:FR had before the correction, kept to measure that bias (:func:`uncorrected`)."""
    with np.errstate(divide="ignore", invalid="ignore"):
        ratio = (num * a_num) / (den * a_den)
        rel2 = (c_nn / num ** 2 + c_dd / den ** 2 - 2 * c_nd / (num * den)
                + (s_num / a_num) ** 2 + (s_den / a_den) ** 2)
        return ratio, np.abs(ratio) * np.sqrt(np.maximum(rel2, 0.0))


def corrected_ratio(num, den, c_nn, c_dd, c_nd, a_num=1.0, a_den=1.0, cv2_a_num=0.0, cv2_a_den=0.0):
    """R = (a_num T_num) / (a_den T_den) without its first-order bias, its σ, and the denominator's CV.

    ``num``, ``den`` (S,): estimated totals; ``c_nn``, ``c_dd``, ``c_nd`` (S,): their variances and
    covariance; ``a_num``, ``a_den`` (S,) or scalars: the factors turning each total into its unit (the
    ratio of the two is what matters), ``cv2_a_num``, ``cv2_a_den``: those factors' squared relative σ
    (independent of the totals).  Returns ``(ratio, ratio_std, den_cv)``, each (S,): NaN ratio and σ where
    ``den_cv`` (the far red's relative σ, normalisation included) exceeds :data:`MAX_DENOMINATOR_CV` or the
    denominator is not > 0 (see the module's docstring).
    """
    num, den = np.asarray(num, float), np.asarray(den, float)
    c_nn, c_dd, c_nd = (np.asarray(c, float) for c in (c_nn, c_dd, c_nd))
    k = np.asarray(a_num, float) / np.asarray(a_den, float)
    with np.errstate(divide="ignore", invalid="ignore"):
        positive = den > 0
        d = np.where(positive, den, 1.0)
        q = num / d
        v_d = c_dd / d ** 2
        den_cv = np.where(positive, np.sqrt(np.maximum(v_d, 0.0) + cv2_a_den), np.nan)
        plain = k * q
        rel2_scale = np.asarray(cv2_a_num, float) + cv2_a_den
        var = k ** 2 * np.maximum(c_nn - 2 * q * c_nd + q ** 2 * c_dd, 0.0) / d ** 2 + plain ** 2 * rel2_scale
        ratio = plain * (1.0 - v_d - cv2_a_den) + k * c_nd / d ** 2
        std = np.sqrt(var) * np.where(plain != 0, np.abs(ratio / np.where(plain != 0, plain, 1.0)), 1.0)
    bad = ~(den_cv <= MAX_DENOMINATOR_CV) | ~np.isfinite(ratio) | ((ratio <= 0) & (plain > 0))
    return np.where(bad, np.nan, ratio), np.where(bad, np.nan, std), den_cv
