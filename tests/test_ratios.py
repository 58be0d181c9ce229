"""R:FR without the bias of a ratio of two noisy estimates (issue 45): the formula on synthetic tallies, then a
bud behind a leaf lit at a low photon budget over many seeds, against the same photons pooled."""
import math
from pathlib import Path

import numpy as np
import pytest
import trimesh

from lpy_light.chamber import ratios, units
from lpy_light.plant.light import LightModel
from scenes import box, lamp_rectangle, write_scene

OPTICAL = Path(__file__).resolve().parents[1] / "lpy_light" / "data" / "angers-chamber" / "optical"
LEAF = ("FeuilleVieille_Sup", "FeuilleVieille_Inf")      # red: R 0.05, T 0.01; far red: R 0.39-0.42, T 0.40-0.44
GREY_ROOM = ("void plastic grey\n0\n0\n5 0.3 0.3 0.3 0 0\n\nvoid light lamp\n0\n0\n3 10 10 10\n\n"
             + box("grey", (0, 0, 0), (1000, 1000, 1100)) + lamp_rectangle("lamp", (500, 500), 100, 1000))


def _synthetic(rng, n_photons, replicates, mean, cov):
    """``replicates`` runs of ``n_photons`` photons, each photon's (red, far red) drawn from a bivariate
    normal: the runs' totals (K, 2) and their estimated covariances (K, 2, 2), as the kernel estimates them."""
    x = rng.multivariate_normal(mean, cov, size=(replicates, n_photons))
    t = x.sum(axis=1)
    centred = x - x.mean(axis=1, keepdims=True)
    c = n_photons * np.einsum("kni,knj->kij", centred, centred) / (n_photons - 1)
    return t, c


def test_the_correction_removes_the_ratio_bias_on_synthetic_tallies():
    """Totals with known means (ratio 0.8), each with a CV of 0.12 and a correlation 0.5 between the bands, in
    units whose factors differ (a_red / a_far = 2, with 5 % σ on the far red's): over 50,000 runs the plain
    ratio reads high by the delta method's CV_f² − ρ CV_r CV_f + CV²(a_f) (+0.97 %, ~17σ), the corrected one
    does not."""
    rng = np.random.default_rng(45)
    n, K, cv, rho = 40, 50_000, 0.12, 0.5
    mean = np.array([0.4, 1.0])                               # per photon: T_r / T_f = 0.4
    sd = mean * cv * math.sqrt(n)                             # each total's CV = 0.12
    cov = np.array([[sd[0] ** 2, rho * sd[0] * sd[1]], [rho * sd[0] * sd[1], sd[1] ** 2]])
    t, c = _synthetic(rng, n, K, mean, cov)
    a_r, a_f, cv_af = 2.0, 1.0, 0.05
    a_f_hat = a_f * (1 + cv_af * rng.standard_normal(K))     # the normalisation's own noise, independent
    truth = a_r * mean[0] / (a_f * mean[1])
    fixed, fixed_std, den_cv = ratios.corrected_ratio(t[:, 0], t[:, 1], c[:, 0, 0], c[:, 1, 1], c[:, 0, 1],
                                                      a_r, a_f_hat, 0.0, cv_af ** 2)
    plain, _ = ratios.plain_ratio(t[:, 0], t[:, 1], c[:, 0, 0], c[:, 1, 1], c[:, 0, 1], a_r, a_f_hat, 0.0,
                                  cv_af * a_f_hat)
    assert np.all(np.isfinite(fixed)) and np.median(den_cv) == pytest.approx(math.hypot(cv, cv_af), rel=0.05)
    se = fixed.std(ddof=1) / math.sqrt(K)
    assert abs(fixed.mean() - truth) < 4 * se, (fixed.mean(), truth, se)
    predicted = truth * (cv ** 2 - rho * cv * cv + cv_af ** 2)
    assert plain.mean() - truth == pytest.approx(predicted, rel=0.25)
    assert plain.mean() - truth > 8 * se
    # σ: the spread of the corrected ratio over the runs (to first order)
    assert np.median(fixed_std) == pytest.approx(fixed.std(ddof=1), rel=0.05)


def test_a_denominator_too_uncertain_or_zero_gives_no_number():
    """Far red within one σ of zero (relative σ above MAX_DENOMINATOR_CV, 1), or no far red: NaN (an empty
    cell), not a number whose bias the expansion cannot remove; below it a number, with σ = |R̃| × the plain
    relative σ."""
    assert ratios.MAX_DENOMINATOR_CV == 1.0
    num, den = np.array([1.0, 1.0, 1.0, 0.0]), np.array([2.0, 2.0, 0.0, 2.0])
    c_dd = np.array([(0.5 * 2.0) ** 2, (1.01 * 2.0) ** 2, 0.0, 0.01])
    c_nn, c_nd = np.array([0.01, 0.01, 0.0, 0.0]), np.zeros(4)
    value, std, den_cv = ratios.corrected_ratio(num, den, c_nn, c_dd, c_nd)
    assert np.isfinite(value[0]) and np.isnan(value[1]) and np.isnan(value[2]) and np.isnan(std[1:3]).all()
    assert value[0] == pytest.approx(0.5 * (1 - 0.25)) and den_cv[1] == pytest.approx(1.01)
    assert std[0] == pytest.approx(value[0] * math.sqrt(0.01 / 1.0 + 0.25))
    assert value[3] == 0 and std[3] == 0           # no red, some far red: R:FR is 0 ± 0
    with ratios.uncorrected():                      # the plain ratio: a number even where it means nothing
        _, _, rfr, _ = units.par_and_rfr(np.c_[num, den], np.zeros((4, 2, 2)), np.ones((4, 2)), np.zeros((4, 2)),
                                         [(655.0, 665.0), (725.0, 735.0)])
    assert rfr[1] == 0.5


def _bud_behind_a_leaf(folder, photons, seed):
    """A grey room (R = 0.3), a lamp panel above; a leaf (Angers tables, 60 mm radius) at 500 mm, and 100 mm
    under it a 1 mm bud, shaded from the lamp: its light comes from the walls and through the leaf, whose
    far red (T 0.44) passes and red (T 0.01) does not.  Bands: red and far red only."""
    scene = write_scene(folder, GREY_ROOM, toml_extra='bands = [[655, 665], [725, 735]]\noptical = "%s"\n'
                        % OPTICAL.as_posix())
    a = np.linspace(0, 2 * np.pi, 24, endpoint=False)
    v = np.vstack([[0, 0, 500], np.c_[60 * np.cos(a), 60 * np.sin(a), np.full(24, 500.0)]])
    leaf = trimesh.Trimesh(v, [[0, 1 + i, 1 + (i + 1) % 24] for i in range(24)], process=False)
    bud = trimesh.creation.icosphere(subdivisions=1, radius=1.0)
    bud.apply_translation((0, 0, 400))
    model = LightModel(scene, organs={"Leaf": LEAF, "Bud": LEAF[0]}, lamp_flux=[1.0, 1.0], plant_unit="mm",
                       position=(500, 500, 0), photons=photons, seed=seed, threads=1, targets=["Bud", "Leaf"])
    return model, model.organs_from_meshes({0: (leaf, LEAF, "Leaf"), 1: (bud, LEAF[0], "Bud")})


def _buds_over_seeds(folder, photons, seeds, seed=1):
    """The bud's light in ``seeds`` runs (seeds ``seed``, ``seed`` + 1, ...): R:FR as reported, its σ, and
    the ppfd (µmol m⁻² s⁻¹) and σ of red and far red, each (seeds,)."""
    model, organs = _bud_behind_a_leaf(folder, photons, seed)
    rows = []
    for _ in range(seeds):                              # each step traces with the model's seed + step
        bud = model.run(organs).organs[1]
        rows.append((bud.rfr, bud.rfr_std, *bud.ppfd, *bud.ppfd_std))
    return np.array(rows).T


def _against_the_pooled_photons(rfr, red, far):
    """Mean of the runs' R:FR minus the R:FR of all their photons pooled (seeds × photons, whose bias is
    1/seeds of one run's), and that difference's standard error.  The σ comes from the spread of each run's
    R:FR around its linearisation about the pooled tallies, R·(1 + r_i/r̄ − f_i/f̄), whose mean over the
    runs is R exactly: the runs' first-order noise (unbiased) cancels, the bias of a ratio (second order)
    stays, seen with ~7x fewer seeds than against an independent reference."""
    pooled = red.mean() / far.mean()
    d = rfr - pooled * (1 + red / red.mean() - far / far.mean())
    return d.mean(), d.std(ddof=1) / math.sqrt(len(d))


def test_a_bud_behind_a_leaf_reads_the_same_r_fr_at_a_low_budget(tmp_path):
    """At 1,000 photons a run, the bud's far red has a relative σ of ~0.1 (its red ~0.03): the plain ratio
    reads ~1 % high (+0.0065 on 0.65), as CV_f² predicts.  Over 200 seeds, the reported (corrected) R:FR's
    mean agrees with the R:FR of the 2e5 photons pooled within 4σ; the plain ratio of the same runs' ppfd
    does not (it is > 4σ high: without the correction this test fails)."""
    rfr, rfr_std, red, far, red_std, far_std = _buds_over_seeds(tmp_path, 1_000, 200)
    assert np.all(np.isfinite(rfr))
    cv_far = np.median(far_std / far)
    assert 0.07 < cv_far < 0.15 and far.std(ddof=1) / far.mean() == pytest.approx(cv_far, rel=0.2)  # honest σ
    assert np.median(rfr_std) == pytest.approx(rfr.std(ddof=1), rel=0.2)
    delta, se = _against_the_pooled_photons(rfr, red, far)
    assert abs(delta) < 4 * se, (delta, se)
    plain_delta, plain_se = _against_the_pooled_photons(red / far, red, far)
    assert plain_delta > 4 * plain_se, (plain_delta, plain_se)


@pytest.mark.slow
def test_a_bud_behind_a_leaf_at_a_lower_budget(tmp_path):
    """The same at 300 photons a run (far red's σ ~0.19: the plain ratio ~3 % high) over 1,000 seeds."""
    rfr, _, red, far, _, far_std = _buds_over_seeds(tmp_path, 300, 1_000)
    assert np.all(np.isfinite(rfr)) and 0.15 < np.median(far_std / far) < 0.25
    delta, se = _against_the_pooled_photons(rfr, red, far)
    assert abs(delta) < 4 * se, (delta, se)
    plain_delta, plain_se = _against_the_pooled_photons(red / far, red, far)
    assert plain_delta > 4 * plain_se, (plain_delta, plain_se)
