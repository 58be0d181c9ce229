"""``estimator="auto"``: the first lit step pilots the ``field`` against ``nee``, and the cheaper one lights the run.

A model with ``estimator="auto"`` starts as a ``field`` model.  Its first field is checked against ``nee`` as every
field is (:func:`lpy_light.plant.verify.field_self_check`: the same plant lit by ``nee`` at the field settings'
``check_photons``), and that check holds all a choice needs, at no extra cost: each read organ's σ from both
estimators, and the CPU seconds of both.  :func:`choose` then keeps

* ``nee``, where the field failed its self-check, or passed it but not auto's stricter bound (:func:`doubts`:
  each kind's bias within max(2σ, 1 % on leaves' PAR, 2 % on buds', 0.01 on R:FR)): its bias, not its cost,
  decides, and a field wrongly refused costs CPU where one wrongly taken costs its bias;
* else the estimator that reaches the precision asked for less CPU.  A precision asked of every read organ is
  reached when the hardest organs reach it, so an estimator's cost is its CPU seconds times the largest, over
  the quantities asked, of the organs' 90th-percentile (:data:`QUANTILE`) variance over the σ asked squared:
  PAR's relative variance, and R:FR's (absolute, or relative for a precision given as one number) where the
  model's ``precision`` asks for R:FR; PAR alone without a goal (:func:`asked`).  ``cpu_nee`` is the check's
  ``nee`` run, ``cpu_field`` the field's step plus its share of what each field costs once (its tracing and
  its check, spread over the ``renew`` steps it lights).  A run's variance falls as 1/its cost, so the ratio,
  the field's gain, holds at any precision; the field is kept where it is ≥ 1.

The choice is made again at each field's self-check (a field kept is renewed every ``renew`` steps, and each is
checked), and a plant lit by ``nee`` is piloted again once it has :data:`REPILOT` times the organs, or the organs'
area, it had at the last pilot: a seedling's few small organs do not choose for the grown plant, and a growth
run pays for a handful of pilots (each a field traced and checked).  Each choice is written in its step's
``extra["auto"]`` and ``summary.json``'s ``auto``: which, why, the gain, and per quantity and kind of organ, with
the CPU seconds behind it.  Each estimator keeps its own settings (``photons`` per step for ``nee``, the field's
``rays``) and, with a ``precision`` goal, stops where the goal is reached.  A field that fails its check lights
nothing.
"""
from __future__ import annotations

import math

import numpy as np

#: the name that asks for the choice (not a registered estimator: it picks one of ``field`` and ``nee``)
AUTO = "auto"
#: a plant lit by ``nee`` is piloted again once it has this many times the organs (or their area) of the last pilot
REPILOT = 2.0
#: the seeds of successive pilots' fields: the model's seed + this × the pilots before
PILOT_SEED = 104_729
#: the organs' quantile of variance that sets an estimator's cost to a precision (the hardest organs)
QUANTILE = 90
#: what a choice weighs without a precision goal: PAR's relative σ (a goal's quantities where it has one)
NO_GOAL = {"par": (1.0, True)}
#: auto lights a run by a field only where its check bounds each kind's bias within max(STRICT_SIGMAS σ, the
#: accuracy asked of a field: STRICT_TOLERANCE on PAR, relative; STRICT_RFR on R:FR) -- stricter than the
#: check's own max(4σ, 3-5 %): a field wrongly refused costs CPU, one wrongly taken costs its bias
STRICT_SIGMAS = 2.0
STRICT_TOLERANCE = {"leaves": 0.01, "buds": 0.02}
STRICT_TOLERANCE_OTHER = 0.02
STRICT_RFR = 0.01


class Chooser:
    """What ``estimator="auto"`` chose so far: ``choices`` (each :func:`choose`'s record, ``summary.json``'s
    ``auto``), ``field`` the field settings given to the model (a mapping or None), the organs at the last pilot."""

    def __init__(self, field=None):
        self.field = field
        self.choices: list = []
        self.organs_at_pilot = 0
        self.area_at_pilot = 0.0

    @property
    def current(self) -> str:
        """The estimator now chosen (``field`` while the first pilot runs)."""
        return self.choices[-1]["estimator"] if self.choices else "field"

    def repilot(self, organs: int, area: float) -> bool:
        """Whether a plant of ``organs`` and ``area`` (its organs' area, any unit) lit by ``nee`` is to be piloted
        again: it has :data:`REPILOT` times the organs or the area it had at the last pilot."""
        return self.current == "nee" and (organs >= REPILOT * max(self.organs_at_pilot, 1)
                                          or area >= REPILOT * self.area_at_pilot > 0)

    def decide(self, check: dict, renew: int, step: int, organs: int, area: float = 0.0, goal=None) -> dict:
        """:func:`choose` on a field's self-check at ``step`` (``organs`` lit, of ``area``; the model's precision
        ``goal``), recorded."""
        choice = dict(choose(check, renew, goal), at_step=int(step), organs_lit=int(organs))
        self.choices.append(choice)
        self.organs_at_pilot, self.area_at_pilot = organs, float(area)
        return choice


def _finite(*values) -> bool:
    return all(math.isfinite(v) and v > 0 for v in values)


def variances(rows) -> dict:
    """{quantity: {kind: (organs, 2)}}: each organ's variance in the field's step and in ``nee``'s check run, from
    :func:`lpy_light.plant.verify.compare`'s ``rows``: ``par`` relative, (σ / nee's PAR)² (PAR, else ppfd summed
    over the bands); ``rfr`` absolute, σ² of R:FR; ``rfr_relative``, (σ / nee's R:FR)².  Organs whose σ is not
    finite and > 0 in both runs are left out of that quantity; ``"all"``: every kind."""
    out: dict = {}

    def add(quantity, kind, pair):
        for k in ("all", kind):
            out.setdefault(quantity, {}).setdefault(k, []).append(pair)

    for row in rows:
        y, sf, sn = row["nee"], row["estimate_std"], row["nee_std"]
        if _finite(y, sf, sn):
            add("par", row["kind"], ((sf / y) ** 2, (sn / y) ** 2))
        r, rf, rn = row["nee_rfr"], row["rfr_std"], row["nee_rfr_std"]
        if _finite(r, rf, rn):
            add("rfr", row["kind"], (rf ** 2, rn ** 2))
            add("rfr_relative", row["kind"], ((rf / r) ** 2, (rn / r) ** 2))
    return {q: {k: np.asarray(v, float) for k, v in kinds.items()} for q, kinds in out.items()}


def field_cost(check: dict, renew: int) -> float:
    """CPU s a field step costs in a run: the step's own plus its share of the field's tracing and its
    self-check (each field lights ``renew`` steps; 0: one field for the whole run, counted over 10)."""
    steps = renew if renew and renew > 0 else 10
    return check["step_cpu_s"] + (check["field_cpu_s"] + check["cpu_s"]) / steps


def gains_of(rows, check: dict, renew: int) -> dict:
    """{quantity: {kind: {"gain", "organs", "field_var", "nee_var"}}} (quantities of :func:`variances`): the
    :data:`QUANTILE` th percentile of the organs' variance in the field's step and in ``nee``'s check run, and how
    many times cheaper the field brings it to a given value: (cpu_nee · q(var_nee)) / (cpu_field · q(var_field)),
    ``cpu_field`` :func:`field_cost` (a run's variance falls as 1/its cost)."""
    cpu_field = field_cost(check, renew)
    out: dict = {}
    for quantity, kinds in variances(rows).items():
        for kind, v in kinds.items():
            qf, qn = np.percentile(v, QUANTILE, axis=0)
            out.setdefault(quantity, {})[kind] = {
                "gain": round(float(qn * check["nee_cpu_s"] / (qf * cpu_field)), 4), "organs": int(len(v)),
                "field_var": float(qf), "nee_var": float(qn)}
    return out


def asked(goal) -> dict:
    """{quantity of :func:`variances`: σ asked} from a precision goal (:class:`lpy_light.plant.precision.Goal`,
    ``{quantity: (σ, relative)}``; None: :data:`NO_GOAL`): PAR and R:FR (a band's ppfd is weighed as PAR)."""
    terms = {}
    for quantity, (sigma, relative) in (goal or NO_GOAL).items():
        if quantity == "rfr":
            terms["rfr_relative" if relative else "rfr"] = float(sigma)
        else:
            terms["par"] = min(float(sigma), terms.get("par", math.inf))
    return terms


def doubts(check: dict) -> list:
    """What of a field's self-check (:meth:`lpy_light.plant.verify.Totals.summary`, and its ``pooled`` one) lies
    beyond auto's stricter bound (:data:`STRICT_SIGMAS`, :data:`STRICT_TOLERANCE`, :data:`STRICT_RFR`): one text
    per kind and quantity ("leaves PAR -4.0 ± 1.6 % (bound 3.2 %)"); empty where auto may take the field."""
    out = []
    for which, verdict in (("", check), ("pooled ", check.get("pooled") or {})):
        for kind, entry in verdict.items():
            if kind == "all" or not isinstance(entry, dict) or "organs" not in entry:
                continue
            for quantity, e in entry.items():
                if not isinstance(e, dict) or "bias" not in e:
                    continue
                rfr = quantity == "rfr"
                tol = STRICT_RFR if rfr else STRICT_TOLERANCE.get(kind, STRICT_TOLERANCE_OTHER)
                limit = max(STRICT_SIGMAS * e["sigma"], tol) if math.isfinite(e["sigma"]) else tol
                if not abs(e["bias"]) <= limit:
                    scale, unit = (1.0, "") if rfr else (100.0, " %")
                    out.append("%s%s %s %+.3g ± %.2g%s (bound %.2g%s)" % (
                        which, kind, "R:FR" if rfr else quantity.upper(), scale * e["bias"], scale * e["sigma"],
                        unit, scale * limit, unit))
    return out


def choose(check: dict, renew: int, goal=None) -> dict:
    """The choice from a field's self-check (:func:`lpy_light.plant.verify.field_self_check`'s verdict, with its
    ``gain``: :func:`gains_of`) for a precision ``goal`` (None: PAR): ``{"asked": "auto", "estimator": "field" |
    "nee", "why": text, "gain": the field's over all read organs, "per_quantity": {quantity: {kind: gain}},
    "cpu_s": {...}}``.  Each estimator's cost to the goal is its CPU s times the largest, over the quantities
    asked, of the organs' 90th-percentile variance over the σ asked squared; the field where it passed its check
    and costs no more than ``nee``."""
    stats = check.get("gain") or {}
    terms = {q: g for q, g in asked(goal).items() if "all" in stats.get(q, {})}
    cpu_field = field_cost(check, renew)
    decision = {"asked": AUTO, "goal": asked(goal),
                "per_quantity": {q: {k: v["gain"] for k, v in kinds.items()} for q, kinds in stats.items()},
                "cpu_s": {"nee_check": check["nee_cpu_s"], "nee_check_photons": check["photons"],
                          "field_step": check["step_cpu_s"], "field_trace": check["field_cpu_s"],
                          "field_check": check["cpu_s"], "field_per_step": round(cpu_field, 3), "renew": renew}}
    if not check.get("passed"):
        return dict(decision, estimator="nee", gain=None,
                    why="the field failed its self-check against nee: its bias decides")
    doubt = doubts(check)
    if doubt:
        return dict(decision, estimator="nee", gain=None, why="the field passed its self-check but not auto's "
                    "stricter bound, max(%g σ, %g %% leaves, %g %% buds, %g on R:FR): %s" % (
                        STRICT_SIGMAS, 100 * STRICT_TOLERANCE["leaves"], 100 * STRICT_TOLERANCE["buds"], STRICT_RFR,
                        "; ".join(doubt)))
    if not terms:
        return dict(decision, estimator="nee", gain=None, why="no organ both estimators gave a σ for: nee, unbiased")
    cost_nee = check["nee_cpu_s"] * max(stats[q]["all"]["nee_var"] / g ** 2 for q, g in terms.items())
    cost_field = cpu_field * max(stats[q]["all"]["field_var"] / g ** 2 for q, g in terms.items())
    gain = cost_nee / cost_field
    text = "%.2fx on %s over the read organs (%s)" % (gain, " and ".join(terms), "; ".join(
        "%s: %s" % (q, ", ".join("%s %.2fx" % (k, stats[q][k]["gain"]) for k in sorted(stats[q]) if k != "all"))
        for q in terms))
    if gain < 1.0:
        return dict(decision, estimator="nee", gain=round(gain, 4), why="nee is cheaper to the precision asked at the "
                    "organs' %dth percentile: the field's gain %s" % (QUANTILE, text))
    return dict(decision, estimator="field", gain=round(gain, 4), why="the field passed its self-check and is "
                "cheaper to the precision asked at the organs' %dth percentile: its gain %s" % (QUANTILE, text))
