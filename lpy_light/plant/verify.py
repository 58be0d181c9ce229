"""An estimator checked against ``nee`` on the plant it lights: the ``field``'s self-check, and ``--verify``.

``nee`` is unbiased (``docs/physics.md``); ``field`` reads binned light and carries a bias of its own, which depends
on the chamber (issue 63).  Two checks compare an estimator's organs with ``nee``'s on the same plant, in the same
step:

* **The field's self-check** (:func:`field_self_check`): each time a field is traced or renewed, the plant it was
  traced with is also lit by ``nee`` at :attr:`lpy_light.estimators.field.FieldSettings.check_photons` photons
  (10⁵ by default), and the field's step is compared with that run, kind by kind (:func:`organ_kind`: leaves,
  buds, other organs).  A field whose bias on a kind is beyond :func:`bound` is not used: that step and the steps
  until the next field are lit by ``nee`` (:class:`lpy_light.plant.light.LightModel` does it, and warns once).
* **Verify** (``LightModel(verify=N)``, ``lpy-light grow --verify N``): the first N lit steps are also lit by an
  independent ``nee`` run at the model's photons per step, and every organ of them compared
  (``verify.csv``: :data:`VERIFY_COLUMNS`; ``summary.json``'s ``verify``).

What is compared: each read organ's PAR (µmol m⁻² s⁻¹; where the scene's bands do not give PAR, its ppfd summed
over the bands) and R:FR, without the lamps' flux σ (the same flux in both runs).  Per organ (``verify.csv``),
each run's own σ; ``within``: the share of organs whose PAR lies within max(4σ, 3 %) of ``nee``'s, R:FR within
max(4σ, 0.01).  Over the organs of a kind (the organs both runs read, ``nee``'s PAR above 0):

* PAR: the bias Σ estimate / Σ ``nee`` − 1 (a ratio of sums: a mean of ratios would carry +cv² from ``nee``'s
  noisy denominators);
* R:FR: the kind's R:FR, Σ red / Σ far red (ppfd 655-665 / 725-735 nm: the organs' R:FR weighted by their far
  red), estimate minus ``nee``.  Not the mean of the organs' own R:FR: at the self-check's 10⁵ photons, ``nee``'s
  buds' own R:FR read +0.04 to +0.06 (σ 0.01) against ``nee`` at 2·10⁶ on the procedural rose (a bud's far red too
  uncertain for the ratio's bias correction); a ratio of sums over a kind carries no such bias.

Their σ is that of a sum over organs, whose errors are not independent: a vertex's next events light several
organs, and a field's own error is common to every organ it lights.  Summing the organs' variances understated it
~2× on the procedural rose (leaves' R:FR at 10⁵ photons, six runs: spread / σ 2.3).  So the ``nee`` runs are made
in :data:`PARTS` independent parts (seeds ``seed`` … ``seed + PARTS − 1``, the photons split evenly), and the
field's step keeps its parts (each σ group of rays, each batch of the field: ``Result.extra["parts"]``): σ is
the spread of the kind's sums over the parts.  A ``nee`` estimate of one run takes the verifying run's spread
(scaled by their photons); any other estimate without parts, the organs' variances summed (``sigma_from``
says which).

A kind passes where |bias| ≤ max(4σ, tolerance): :data:`TOLERANCE` (3 % leaves, 5 % buds and other organs on PAR;
0.01 on R:FR).  A field passes where its own check passes and so do the checks of the last :data:`POOL` fields
pooled (this one's included: their sums added): one check's σ is wide at 10⁵ photons (0.05-0.1 on the buds' R:FR
of a young rose), and a bias that every field shares shows in the pool.
"""
from __future__ import annotations

import logging
import math
import time
from contextlib import contextmanager

import numpy as np

from .auto import gains_of

log = logging.getLogger("lpy_light")

#: relative tolerance on PAR of each kind of organ, and the absolute one on R:FR
TOLERANCE = {"leaves": 0.03, "buds": 0.05, "other organs": 0.05}
RFR_TOLERANCE = 0.01
#: an organ is "within" where |estimate − nee| ≤ max(SIGMAS · σ, WITHIN · nee) (R:FR: max(SIGMAS · σ, RFR_TOLERANCE))
SIGMAS = 4.0
WITHIN = 0.03
#: independent parts of a checking ``nee`` run (its σ over organs of a kind is their spread)
PARTS = 8
#: a field's self-check is also pooled with those of the fields traced before it, this many in all
POOL = 4
#: the seed of a field's self-check run: the field's seed + this; of a verifying run: the step's seed + VERIFY_SEED
CHECK_SEED = 1_000_003
VERIFY_SEED = 1 << 40
KINDS = ("leaves", "buds", "other organs")

#: the columns of ``verify.csv``: one row per read organ and verified step (``quantity``: ``par``, or ``ppfd``
#: summed over the bands where they give no PAR; ``bias`` = estimate / nee − 1; ``within``: 1 where
#: |estimate − nee| ≤ max(4σ, 3 % of nee), σ the two runs' together; ``rfr_*`` the same on R:FR, absolute)
VERIFY_COLUMNS = ("step", "organ", "module", "kind", "quantity", "estimator", "estimate", "estimate_std", "nee",
                  "nee_std", "bias", "bias_std", "within", "rfr", "rfr_std", "nee_rfr", "nee_rfr_std", "rfr_diff",
                  "rfr_diff_std", "rfr_within")


def organ_kind(module) -> str:
    """``"leaves"`` for a module whose name says leaf (Leaf, leaf2, Feuille, ...), ``"buds"`` for one that says bud
    (Bud, bourgeon), else ``"other organs"``: the kinds the checks report apart (each its own tolerance)."""
    name = str(module or "").lower()
    if "leaf" in name or "feuille" in name or "leaves" in name:
        return "leaves"
    if "bud" in name or "bourgeon" in name:
        return "buds"
    return "other organs"


def bound(kind: str, sigma: float, rfr: bool = False) -> float:
    """The most |bias| a kind may show: max(4σ, its tolerance)."""
    tol = RFR_TOLERANCE if rfr else TOLERANCE.get(kind, TOLERANCE["other organs"])
    return max(SIGMAS * sigma, tol) if math.isfinite(sigma) else tol


@contextmanager
def _quiet():
    """The ``lpy_light`` logger silent within the block: a check's organ lights are not the step's, and what they
    would warn about (an organ the check's few photons missed, an R:FR not reported) is not the user's."""
    logger = logging.getLogger("lpy_light")
    before = logger.disabled
    logger.disabled = True
    try:
        yield
    finally:
        logger.disabled = before


def lights_for_check(model, result, organs, read) -> dict:
    """``{key: OrganLight}`` of ``result`` for ``organs`` without the lamps' flux σ (common to both runs compared)
    and without warnings."""
    from .organ_light import organ_lights
    with _quiet():
        return organ_lights(model.kscene, result, organs, model.flux, np.zeros_like(model.flux), model.chamber, read)


def _light(light):
    """(value, σ, quantity name) of an organ's light: PAR, else ppfd summed over the bands (σ summed: an upper
    bound, the bands travel together)."""
    if light.par is not None and math.isfinite(light.par):
        return float(light.par), float(light.par_std), "par"
    ppfd = np.asarray(light.ppfd, float)
    if not np.isfinite(ppfd).all():
        return math.nan, math.nan, "ppfd"
    return float(ppfd.sum()), float(np.sum(np.abs(light.ppfd_std))), "ppfd"


def compare(estimate: dict, reference: dict, organs, step: int, estimator: str) -> list:
    """Rows of :data:`VERIFY_COLUMNS`, one per organ that both runs read (``estimate``, ``reference``: ``{key:
    OrganLight}``; organs "shading only" in either are left out)."""
    rows = []
    for organ in organs:
        e, r = estimate.get(organ.key), reference.get(organ.key)
        if e is None or r is None or e.role == "shading only" or r.role == "shading only":
            continue
        x, sx, quantity = _light(e)
        y, sy, _ = _light(r)
        s = math.hypot(sx, sy)
        ok = math.isfinite(x) and math.isfinite(y) and y > 0
        rfr_ok = ok and all(math.isfinite(v) for v in (e.rfr, r.rfr, e.rfr_std, r.rfr_std))
        d, sd = (e.rfr - r.rfr, math.hypot(e.rfr_std, r.rfr_std)) if rfr_ok else (math.nan, math.nan)
        rows.append({"step": step, "organ": organ.key, "module": organ.module, "kind": organ_kind(organ.module),
                     "quantity": quantity, "estimator": estimator, "estimate": x, "estimate_std": sx, "nee": y,
                     "nee_std": sy, "bias": x / y - 1.0 if ok else math.nan, "bias_std": s / y if ok else math.nan,
                     "within": int(abs(x - y) <= max(SIGMAS * s, WITHIN * y)) if ok else "",
                     "rfr": e.rfr, "rfr_std": e.rfr_std, "nee_rfr": r.rfr, "nee_rfr_std": r.rfr_std, "rfr_diff": d,
                     "rfr_diff_std": sd,
                     "rfr_within": int(abs(d) <= max(SIGMAS * sd, RFR_TOLERANCE)) if rfr_ok else ""})
    return rows


# -- sums over a kind of organs ----------------------------------------------------------------------------------
def _weights(model, photons, organs):
    """(organs, 3, B): what turns an organ's incident tallies (a run of ``photons``) into its light (PAR, else ppfd
    summed over the bands), its red and its far-red ppfd (µmol m⁻² s⁻¹); red and far red 0 where the bands hold
    none."""
    from ..chamber import units
    ch = model.chamber
    B = ch.n_bands
    scale = model.flux[None, :] / photons / (np.array([o.area for o in organs], float) * ch.metres_per_unit ** 2)[:, None]
    w = np.zeros((len(organs), 3, B))
    cols = units.par_columns(ch.bands)
    w[:, 0, :] = scale if cols is None else 0.0
    if cols is not None:
        w[:, 0, cols] = scale[:, cols]
    r, f = units.band_index(ch.bands, units.RED), units.band_index(ch.bands, units.FAR_RED)
    if r is not None and f is not None:
        w[:, 1, r], w[:, 2, f] = scale[:, r], scale[:, f]
    return w


def kind_sums(model, result, organs, chosen: dict, parts=None, like=None) -> dict:
    """Per kind (``chosen``: kind → the organs' indices): the sums over its organs of (light, red, far red) of
    ``result`` (3,), their covariance (3, 3) and where it came from: the spread of ``parts`` (a list of (K,
    organs, B) arrays of the organs' incident tallies, each row an independent estimate of the whole run's: the
    field's groups and batches, ``nee``'s parts); else ``like``'s (another run's ``kind_sums`` by the same
    estimator) scaled by their photons; else the organs' covariances summed (independent organs)."""
    rows = result.n_sensors + model.kscene.n_chamber_receivers + np.arange(len(organs))
    w = _weights(model, result.photons, organs)
    out = {}
    for kind, idx in chosen.items():
        idx = np.asarray(idx, np.int64)
        value = np.einsum("iqb,ib->q", w[idx], result.tally[rows[idx]])
        if parts:
            cov, how = np.zeros((3, 3)), "parts"
            for p in parts:
                a = np.einsum("iqb,kib->kq", w[idx], np.asarray(p)[:, idx])
                cov += np.cov(a, rowvar=False, ddof=1) / len(a)
        elif like is not None and kind in like:
            cov, how = like[kind]["cov"] * like[kind]["photons"] / result.photons, "scaled from nee's parts"
        else:
            c = np.nan_to_num(result.covariance(rows[idx]))
            cov, how = np.einsum("iqb,ibc,ipc->qp", w[idx], c, w[idx]), "organs independent"
        out[kind] = {"value": value, "cov": cov, "photons": result.photons, "sigma_from": how}
    return out


def compare_runs(model, estimate, reference, organs, read, step: int, ref_parts=None):
    """Two runs' Results of ``organs`` (``read``: the organs whose light is estimated) compared: (rows of
    :data:`VERIFY_COLUMNS`, per kind the sums of both (:func:`kind_sums`) over the organs of the rows whose PAR
    both runs give, ``nee``'s above 0)."""
    rows = compare(lights_for_check(model, estimate, organs, read), lights_for_check(model, reference, organs, read),
                   organs, step, estimate.estimator)
    index = {o.key: i for i, o in enumerate(organs)}
    chosen = {}
    for row in rows:
        if row["within"] != "":
            chosen.setdefault(row["kind"], []).append(index[row["organ"]])
    ref = kind_sums(model, reference, organs, chosen, ref_parts)
    est = kind_sums(model, estimate, organs, chosen, estimate.extra.get("parts"),
                    ref if estimate.estimator == "nee" else None)
    return rows, {kind: (est[kind], ref[kind]) for kind in chosen}


class Totals:
    """Sums over :func:`compare_runs` (any number of steps), kind by kind; :meth:`summary` the biases."""

    def __init__(self):
        self.kinds = {}

    def add(self, rows, sums=None) -> "Totals":
        """``rows`` (per organ) and ``sums`` (per kind: the estimate's and ``nee``'s :func:`kind_sums`; steps are
        independent: their sums and covariances add)."""
        for row in rows:
            t = self._kind(row["kind"], row["quantity"])
            if row["within"] != "":
                t["n"] += 1
                t["within"] += row["within"]
            if row["rfr_within"] != "":
                t["k"] += 1
                t["rfr_within"] += row["rfr_within"]
        for kind, (est, ref) in (sums or {}).items():
            t = self.kinds[kind]
            t["est"] += est["value"]
            t["est_cov"] += est["cov"]
            t["ref"] += ref["value"]
            t["ref_cov"] += ref["cov"]
            t["sigma_from"].add(est["sigma_from"])
        return self

    def _kind(self, kind, quantity):
        return self.kinds.setdefault(kind, dict(n=0, within=0, k=0, rfr_within=0, quantity=quantity,
                                                est=np.zeros(3), est_cov=np.zeros((3, 3)), ref=np.zeros(3),
                                                ref_cov=np.zeros((3, 3)), sigma_from=set()))

    def summary(self) -> dict:
        """Per kind: ``organs`` (organ-steps compared), ``{quantity: {bias, sigma, bound, ok}}`` (PAR, or ppfd:
        relative), ``rfr`` (the kind's Σ red / Σ far red: ``{estimate, nee, bias, sigma, bound, ok}``, absolute),
        ``within`` (the share of organs within max(4σ, 3 %)), ``rfr_within`` (of those whose R:FR both runs
        report, within max(4σ, 0.01)), ``sigma_from`` (the estimate's σ, :func:`kind_sums`); ``all``: every kind
        together (``within``, ``rfr_within``); ``passed``: every kind within its bounds."""
        out, n_all, w_all, k_all, rw_all = {}, 0, 0, 0, 0
        passed = True
        for kind in KINDS:
            t = self.kinds.get(kind)
            if t is None or t["n"] == 0:
                continue
            entry = {"organs": t["n"]}
            (le, re_, fe), (ln, rn, fn) = t["est"], t["ref"]
            if ln > 0:
                b = le / ln - 1.0
                s = (le / ln) * math.sqrt(max(t["est_cov"][0, 0], 0.0) / max(le, 1e-300) ** 2
                                          + max(t["ref_cov"][0, 0], 0.0) / ln ** 2)
                lim = bound(kind, s)
                ok = bool(math.isfinite(b) and abs(b) <= lim)
                entry[t["quantity"]] = {"bias": float(b), "sigma": float(s), "bound": float(lim), "ok": ok}
                passed &= ok
            entry["within"] = t["within"] / t["n"]
            if fe > 0 and fn > 0:
                (xe, ve), (xn, vn) = _ratio(t["est"], t["est_cov"]), _ratio(t["ref"], t["ref_cov"])
                d, s = xe - xn, math.sqrt(ve + vn)
                lim = bound(kind, s, rfr=True)
                ok = bool(abs(d) <= lim)
                entry["rfr"] = {"estimate": float(xe), "nee": float(xn), "bias": float(d), "sigma": float(s),
                                "bound": float(lim), "ok": ok}
                passed &= ok
            if t["k"]:
                entry["rfr_within"] = t["rfr_within"] / t["k"]
            if t["sigma_from"]:
                entry["sigma_from"] = ", ".join(sorted(t["sigma_from"]))
            out[kind] = entry
            n_all, w_all, k_all, rw_all = n_all + t["n"], w_all + t["within"], k_all + t["k"], rw_all + t["rfr_within"]
        out["all"] = {"organs": n_all, "within": w_all / n_all if n_all else math.nan,
                      "rfr_organs": k_all, "rfr_within": rw_all / k_all if k_all else math.nan}
        out["passed"] = bool(passed and n_all > 0)
        return out


def _ratio(value, cov):
    """Red / far red of sums (light, red, far red) and its variance (first order, their covariance included)."""
    r, f = value[1], value[2]
    x = r / f
    return x, max(0.0, (cov[1, 1] - 2 * x * cov[1, 2] + x * x * cov[2, 2]) / (f * f))


def summary_line(summary: dict) -> str:
    """One line of a :meth:`Totals.summary`: each kind's bias ± σ on PAR (and R:FR), and the share within."""
    parts = []
    for kind in KINDS:
        entry = summary.get(kind)
        if not entry:
            continue
        for q in ("par", "ppfd"):
            if q in entry:
                e = entry[q]
                parts.append("%s %s %+.2f ± %.2f %%%s" % (kind, q.upper() if q == "par" else "ppfd",
                                                          100 * e["bias"], 100 * e["sigma"], "" if e["ok"] else " (!)"))
        if "rfr" in entry:
            e = entry["rfr"]
            parts.append("%s R:FR %+.3f ± %.3f%s" % (kind, e["bias"], e["sigma"], "" if e["ok"] else " (!)"))
    a = summary["all"]
    within = "%.1f %% of %d organ-steps within max(4σ, 3 %%)" % (100 * a["within"], a["organs"]) if a["organs"] else \
        "no organ compared"
    return "; ".join(parts + [within])


# -- the nee runs ------------------------------------------------------------------------------------------------
def nee_run(model, photons: int, seed: int, parts: int = PARTS):
    """``nee`` on the organs now in the model's kernel scene (every organ a target where the model's estimator is
    a stored one), ``photons`` in all, in ``parts`` independent runs (seeds ``seed`` …): the Result of them all (as
    one run of their photons) and the organs' incident tallies of each part, scaled to the whole's photons
    ((parts, organs, B): :func:`kind_sums`'s parts)."""
    from ..estimators.result import Result
    from ..run import simulate
    ks = model.kscene
    ks.configure(images=model._mirror_events())
    ks.size_pilots(photons)
    parts = max(1, min(int(parts), int(photons)))
    each = [photons // parts + (k < photons % parts) for k in range(parts)]
    try:
        runs = [simulate.run(ks, n, seed=int(seed) + k, threads=model.threads) for k, n in enumerate(each)]
    finally:
        ks.size_pilots(model.photons)
    first = runs[0]
    n_all = sum(r.photons for r in runs)
    whole = Result(n_all, sum(r.tally for r in runs), sum(r.tally_prod for r in runs),
                   sum(r.counters for r in runs), sum(r.seconds for r in runs), first.threads, int(seed),
                   first.n_sensors, first.n_receivers, estimator=first.estimator, materials=first.materials,
                   nee_stats=None if first.nee_stats is None else sum(r.nee_stats for r in runs))
    rows = first.n_sensors + ks.n_chamber_receivers + np.arange(len(ks.organs))
    return whole, [np.stack([r.tally[rows] * (n_all / r.photons) for r in runs])]


def field_self_check(model, organs, read):
    """The check a :class:`~lpy_light.estimators.field.FieldKeeper` calls on each field it traces
    (``check(field, result)``, ``result`` the field's step of ``organs``): the same plant lit by ``nee`` at the
    field settings' ``check_photons``, compared kind by kind; returns the verdict (:meth:`Totals.summary`, with
    the photons and the CPU seconds of the check and of the field's tracing)."""
    keeper = model.keeper
    photons = keeper.settings.check_photons

    def check(field, result):
        c0, w0 = time.process_time(), time.perf_counter()
        nee, parts = nee_run(model, photons, field.seed + CHECK_SEED)
        nee_cpu = time.process_time() - c0
        compared = compare_runs(model, result, nee, organs, read, model.step, parts)
        verdict = Totals().add(*compared).summary()
        pool = keeper.pool                  # the last POOL fields' comparisons
        pool[:] = (pool + [compared])[-POOL:]
        pooled = Totals()
        for c in pool:
            pooled.add(*c)
        verdict["own_passed"] = verdict["passed"]
        verdict["pooled"] = dict(pooled.summary(), fields=len(pool))
        verdict["passed"] = bool(verdict["own_passed"] and verdict["pooled"]["passed"])
        cpu = time.process_time() - c0
        field_cpu = float(getattr(field, "cpu_seconds", 0.0) or 0.0)
        verdict.update({"field": field.name, "traced_at_step": model.step, "photons": int(photons), "parts": PARTS,
                        "seed": int(field.seed + CHECK_SEED), "cpu_s": round(cpu, 3),
                        "wall_s": round(time.perf_counter() - w0, 3), "field_cpu_s": round(field_cpu, 3),
                        "share_of_field": round(cpu / field_cpu, 3) if field_cpu > 0 else None,
                        "nee_cpu_s": round(nee_cpu, 3), "step_cpu_s": round(float(result.extra.get("cpu_s", 0.0)), 3)})
        verdict["gain"] = gains_of(compared[0], verdict, keeper.settings.renew)     # what estimator="auto" reads
        return verdict

    return check


def warn_failed(verdict: dict):
    """Once per model (a growth run): a field failed its self-check, its steps are lit by ``nee``."""
    bad = []
    for which, v in (("", verdict), ("pooled with the fields before it: ", verdict.get("pooled") or {})):
        for kind in KINDS:
            entry = v.get(kind) or {}
            for q in ("par", "ppfd", "rfr"):
                e = entry.get(q)
                if e and not e["ok"]:
                    bad.append("%s%s %s %+.3g (bound %.3g)" % (which, kind, "R:FR" if q == "rfr" else q.upper(),
                                                               e["bias"], e["bound"]))
    log.warning("the light field traced at step %s failed its self-check against nee at %d photons (%s): that step "
                "and those until the field is renewed are lit by nee, at the model's photons per step "
                "(summary.json: each field's check in 'field_checks', each step's estimator in 'lit_by')",
                verdict.get("traced_at_step"), verdict.get("photons", 0), ", ".join(bad) or "no organ compared")


def verify_step(model, result, organs, read):
    """One step's comparison: ``result`` (what lit the step) against an independent ``nee`` run of the same organs
    at the model's photons per step (:func:`compare_runs`'s rows and sums)."""
    nee, parts = nee_run(model, model.photons, model.seed + model.step + VERIFY_SEED)
    return compare_runs(model, result, nee, organs, read, model.step, parts)


def verify_count(n) -> int:
    """``verify=``: the number of lit steps to verify, a whole number ≥ 0."""
    from ..errors import InputError
    try:
        value = float(n)
    except (TypeError, ValueError):
        value = math.nan
    if isinstance(n, bool) or not (value >= 0 and value == int(value)):
        raise InputError("verify must be a whole number of steps >= 0, got %r" % (n,))
    return int(value)


class Verification:
    """What ``LightModel(verify=N)`` compared so far: ``steps`` verified, their :class:`Totals`, the CPU seconds
    of the ``nee`` runs, ``lit_by``: the verified steps by the estimator that lit them (a field that failed its
    self-check leaves its steps to ``nee``)."""

    def __init__(self):
        self.steps = 0
        self.totals = Totals()
        self.cpu_s = 0.0
        self.lit_by: dict = {}

    def summary(self, model) -> dict:
        """``summary.json``'s ``verify``: what was compared, and :meth:`Totals.summary` over every verified step."""
        return {"steps": self.steps, "asked": model.verify, "estimator": model.estimator, "lit_by": self.lit_by,
                "nee_photons": model.photons, "nee_parts": PARTS, "nee_cpu_s": round(self.cpu_s, 3),
                **self.totals.summary()}

    def label(self, model) -> str:
        """What the verified steps' light was: the model's estimator, or which lit how many steps."""
        if set(self.lit_by) <= {model.estimator}:
            return model.estimator
        return "%s (its steps lit by %s)" % (model.estimator, ", ".join(
            "%s: %d" % kv for kv in sorted(self.lit_by.items())))


def after_step(model, step, result, organs, read, checks_before: int):
    """What a step adds to its :class:`~lpy_light.plant.organ_light.StepResult` once it is lit: with the ``field``
    estimator, the self-check of a field traced at this step (``field_check``; a warning where it failed) and
    what lit the step (``lit_by``); while ``model.verify`` steps are not yet verified, this step against ``nee``
    (``comparison``, ``verify``)."""
    keeper = model.keeper
    if model.estimator == "field" and keeper is not None:
        checks = getattr(keeper, "checks", [])
        if len(checks) > checks_before:
            step.extra["field_check"] = checks[-1]
            if not checks[-1].get("passed"):
                warn_failed(checks[-1])
        if result.estimator == "field":
            step.extra["lit_by"] = "field"
        else:                       # the field kept (renewed as ever) but not used: it failed its self-check
            step.extra["lit_by"] = "nee (field %s failed its self-check)" % (keeper.verdict or {}).get("field", "?")
            if keeper.field is not None:
                step.extra["store"] = dict(keeper.field.describe(), why=keeper.why, steps_from_it=keeper.steps)
    if model.verify > model.verification.steps and np.any(read):
        c0, w0 = time.process_time(), time.perf_counter()
        rows, sums = verify_step(model, result, organs, read)
        v = model.verification
        v.steps += 1
        v.lit_by[result.estimator] = v.lit_by.get(result.estimator, 0) + 1
        v.totals.add(rows, sums)
        v.cpu_s += time.process_time() - c0
        step.comparison = rows
        step.extra["verify"] = Totals().add(rows, sums).summary()
        step.extra["verify_seconds"] = time.perf_counter() - w0
