"""``estimator="auto"``: the first lit step pilots the ``field`` against ``nee``, and the cheaper one lights the run.

A model with ``estimator="auto"`` starts as a ``field`` model.  Its first field is checked against ``nee`` as every
field is (:func:`lpy_light.plant.verify.field_self_check`: the same plant lit by ``nee`` at the field settings'
``check_photons``), and that check holds all a choice needs, at no extra cost: each read organ's σ from both
estimators, and the CPU seconds of both.  :func:`choose` then keeps

* ``nee``, where the field failed its self-check (its bias, not its cost, decides);
* else the estimator that brings the organs read to a given σ for less CPU.  A precision asked of every read
  organ is reached when the hardest organs reach it, so each estimator's cost is its CPU seconds times the
  90th percentile (:data:`QUANTILE`) of the organs' relative variance (PAR, else ppfd summed over the bands),
  and the field is kept where ``gain = (cpu_nee · q(σ_nee²)) / (cpu_field · q(σ_field²)) ≥ 1``:
  ``cpu_nee`` is the check's ``nee`` run, ``cpu_field`` the field's step plus its share of what each field
  costs once (its tracing and its check, spread over the ``renew`` steps it lights).  A run's variance falls
  as 1/its cost, so the gain holds at any precision.

The choice is made again at each field's self-check (a field kept is renewed every ``renew`` steps, and each is
checked), and a plant lit by ``nee`` is piloted again once it has :data:`REPILOT` times the organs, or the organs'
area, it had at the last pilot: a seedling's few small organs do not choose for the grown plant, and a growth run pays for a handful of
pilots (each a field traced and checked).  Each choice is written in its step's ``extra["auto"]`` and
``summary.json``'s ``auto``: which, why, the gain over all read organs and per kind, with the σ and CPU seconds behind it.  Each
estimator keeps its own settings (``photons`` per step for ``nee``, the field's ``rays``) and, with a
``precision`` goal, stops where the goal is reached.  A field that fails its check lights nothing.
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

    def decide(self, check: dict, renew: int, step: int, organs: int, area: float = 0.0) -> dict:
        """:func:`choose` on a field's self-check at ``step`` (``organs`` lit, of ``area``), recorded."""
        choice = dict(choose(check, renew), at_step=int(step), organs_lit=int(organs))
        self.choices.append(choice)
        self.organs_at_pilot, self.area_at_pilot = organs, float(area)
        return choice


#: the organs' quantile of relative variance that sets an estimator's cost to a precision (the hardest organs)
QUANTILE = 90


def relative_variances(rows) -> dict:
    """{kind: (organs, 2)}: each organ's (σ_field / nee)², (σ_nee / nee)² from
    :func:`lpy_light.plant.verify.compare`'s ``rows`` (PAR, else ppfd summed over the bands; organs whose σ is
    not finite and > 0 in both runs, or whose ``nee`` light is not > 0, are left out); ``"all"`` every kind."""
    out: dict = {}
    for row in rows:
        sf, sn, y = row["estimate_std"], row["nee_std"], row["nee"]
        if not all(math.isfinite(v) and v > 0 for v in (sf, sn, y)):
            continue
        for kind in ("all", row["kind"]):
            out.setdefault(kind, []).append(((sf / y) ** 2, (sn / y) ** 2))
    return {kind: np.asarray(v, float) for kind, v in out.items()}


def field_cost(check: dict, renew: int) -> float:
    """CPU s a field step costs in a run: the step's own plus its share of the field's tracing and its
    self-check (each field lights ``renew`` steps; 0: one field for the whole run, counted over 10)."""
    steps = renew if renew and renew > 0 else 10
    return check["step_cpu_s"] + (check["field_cpu_s"] + check["cpu_s"]) / steps


def gains_of(rows, check: dict, renew: int) -> dict:
    """{kind: {"gain", "organs", "field_sigma", "nee_sigma"}}: how many times cheaper the field brings the
    :data:`QUANTILE` th percentile of the organs' relative σ to a given value than ``nee`` does, over all read
    organs (``"all"``) and per kind; the two σ are those percentiles (the field's step, ``nee`` at the check's
    photons).  A run's variance falls as 1/its cost: gain = (cpu_nee · q(σ_nee²)) / (cpu_field · q(σ_field²)),
    ``cpu_field`` :func:`field_cost`."""
    cpu_field = field_cost(check, renew)
    out = {}
    for kind, v in relative_variances(rows).items():
        qf, qn = np.percentile(v, QUANTILE, axis=0)
        out[kind] = {"gain": round(float(qn * check["nee_cpu_s"] / (qf * cpu_field)), 4), "organs": int(len(v)),
                     "field_sigma": round(float(np.sqrt(qf)), 5), "nee_sigma": round(float(np.sqrt(qn)), 5)}
    return out


def choose(check: dict, renew: int) -> dict:
    """The choice from a field's self-check (:func:`lpy_light.plant.verify.field_self_check`'s verdict, with its
    ``gain``: :func:`gains_of`): ``{"asked": "auto", "estimator": "field" | "nee", "why": text, "gain": {kind:
    gain}, "cpu_s": {...}}``.  The field where it passed its check and its gain over all read organs is ≥ 1."""
    gain = check.get("gain") or {}
    decision = {"asked": AUTO, "gain": gain,
                "cpu_s": {"nee_check": check["nee_cpu_s"], "nee_check_photons": check["photons"],
                          "field_step": check["step_cpu_s"], "field_trace": check["field_cpu_s"],
                          "field_check": check["cpu_s"], "field_per_step": round(field_cost(check, renew), 3),
                          "renew": renew}}
    if not check.get("passed"):
        return dict(decision, estimator="nee", why="the field failed its self-check against nee: its bias decides")
    if "all" not in gain:
        return dict(decision, estimator="nee", why="no organ both estimators gave a σ for: nee, unbiased")
    text = "%.2fx over the %d read organs (%s)" % (gain["all"]["gain"], gain["all"]["organs"], ", ".join(
        "%s %.2fx" % (k, gain[k]["gain"]) for k in sorted(gain) if k != "all"))
    if gain["all"]["gain"] < 1.0:
        return dict(decision, estimator="nee", why="nee is cheaper to a given σ on the organs' %dth percentile: the "
                    "field's gain %s" % (QUANTILE, text))
    return dict(decision, estimator="field", why="the field passed its self-check and is cheaper to a given σ on the "
                "organs' %dth percentile: its gain %s" % (QUANTILE, text))
