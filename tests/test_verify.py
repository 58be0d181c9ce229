"""An estimator checked against ``nee`` (:mod:`lpy_light.plant.verify`): the ``field``'s self-check on each field it
traces, and ``LightModel(verify=N)``.

The scene and plant are ``test_field``'s (a room lit through a diffusing sheet, a mirror wall; a thin leaf over a
bud in its pocket, 24 more buds): its one leaf and 25 buds are the kinds compared."""
import dataclasses
import logging
import math

import numpy as np
import pytest

import lpy_light.estimators.field as field_module
from lpy_light.errors import InputError
from lpy_light.estimators.field import FieldSettings
from lpy_light.plant.light import LightModel
from lpy_light.plant.verify import VERIFY_COLUMNS, Totals, organ_kind, verify_count
from scenes import write_scene
from test_reuse import GREEN, ROOM, THIN, _plant

CHECKED = FieldSettings(store_photons=800_000, batches=8, rays=1024, shading_rays=64, check_photons=400_000)


@pytest.fixture(scope="module")
def room(tmp_path_factory):
    return write_scene(tmp_path_factory.mktemp("verify"), ROOM)


def _model(scene, estimator="field", photons=100_000, field=CHECKED, **kw):
    return LightModel(scene, organs={"Bud": GREEN, "Leaf": THIN}, lamp_flux=100.0, plant_unit="mm",
                      position=(500, 500, 0), photons=photons, estimator=estimator, seed=5, threads=2,
                      field=field if estimator == "field" else None, **kw)


def test_an_honest_field_passes_its_self_check(room):
    """The field traced with the plant in place, checked against ``nee`` at 4·10⁵ photons: on the leaf and on the
    buds its bias lies within 4σ of zero (σ from the spread of both runs' parts; the buds' 4σ under 6 %: a field 6 %
    off there would fail), so it is used; the verdict, its photons and its cost against the field's are in the step's
    ``field_check``."""
    model = _model(room)
    step = model.run(model.organs_from_meshes(_plant()))
    check = step.extra["field_check"]
    assert check["passed"] and step.extra["lit_by"] == "field" and step.extra["store"]["why"] == "first step"
    for kind, n in (("leaves", 1), ("buds", 25)):
        entry = check[kind]
        assert entry["organs"] == n
        light = entry["ppfd"]                       # the room's bands give no PAR: ppfd summed over the bands
        assert kind == "leaves" or light["sigma"] < 0.015, (kind, light)      # 4σ < 6 %: the test can fail
        assert abs(light["bias"]) <= 4 * light["sigma"], (kind, light)
    assert check["photons"] == 400_000 and check["cpu_s"] > 0 and check["field_cpu_s"] > 0
    assert model.keeper.checks == [check]


def test_a_field_scaled_by_0_9_falls_back_to_nee_and_warns_once(room, monkeypatch, caplog):
    """Every field's light scaled by 0.9: its self-check finds the buds ~10 % low, beyond its bound; that step and
    the next (the same field) are lit by ``nee`` (their light is not 0.9 of the truth), the warning is printed
    once and counted twice (a renewed field fails again)."""
    build = field_module.build_field

    def scaled(*args, **kwargs):
        f = build(*args, **kwargs)
        return dataclasses.replace(f, field=f.field * 0.9)

    monkeypatch.setattr(field_module, "build_field", scaled)
    model = _model(room, field=dataclasses.replace(CHECKED, renew=2))
    organs = model.organs_from_meshes(_plant())
    honest = _model(room, estimator="nee", photons=400_000).run(organs)
    with caplog.at_level(logging.WARNING, logger="lpy_light"):
        steps = [model.run(organs) for _ in range(3)]
    assert [s.extra["lit_by"].split()[0] for s in steps] == ["nee"] * 3
    assert "field_check" in steps[0].extra and "field_check" not in steps[1].extra and "field_check" in steps[2].extra
    assert model.keeper.built == 2 and len(model.keeper.checks) == 2
    assert [c["pooled"]["fields"] for c in model.keeper.checks] == [1, 2]
    for check in model.keeper.checks:
        buds = check["buds"]["ppfd"]
        assert not check["passed"] and not buds["ok"]
        assert abs(buds["bias"] + 0.1) < 4 * buds["sigma"] + 0.01, buds
    failed = [r for r in caplog.records if "failed its self-check" in r.getMessage()]
    assert len(failed) == 1
    assert [n for kind, n in model.messages.counts.items() if "failed its self-check" in kind] == [2]
    # the steps' light is nee's: the buds' total agrees with an honest nee run, not 0.9 of it
    total = sum(steps[1].organs[k].ppfd.sum() for k in steps[1].organs if k != 2)
    ref = sum(honest.organs[k].ppfd.sum() for k in honest.organs if k != 2)
    assert abs(total / ref - 1) < 0.04, total / ref


def test_verify_compares_the_first_steps_with_nee(room):
    """``verify=1`` on a ``nee`` model: the first step only is also lit by an independent ``nee`` run at the
    model's photons; every read organ has its row, and agrees (within max(4σ, 3 %)) nearly everywhere."""
    model = _model(room, estimator="nee", photons=200_000, verify=1)
    organs = model.organs_from_meshes(_plant())
    first, second = model.run(organs), model.run(organs)
    rows = first.comparison
    assert len(rows) == 26 and set(rows[0]) == set(VERIFY_COLUMNS) and not second.comparison
    assert {r["kind"] for r in rows} == {"leaves", "buds"} and {r["estimator"] for r in rows} == {"nee"}
    summary = first.extra["verify"]
    assert summary["all"]["organs"] == 26 and summary["all"]["within"] >= 0.9 and summary["passed"]
    assert model.verification.steps == 1 and "verify" not in second.extra
    total = model.verification.summary(model)
    assert total["steps"] == 1 and total["nee_photons"] == 200_000 and total["buds"]["organs"] == 25


def test_totals_are_ratios_of_sums_and_kinds_by_module_name():
    """A kind's bias is the ratio of its sums (PAR, and red over far red for R:FR) − 1, σ from the sums'
    covariances; it fails beyond max(4σ, its tolerance).  Kinds come from the module's name."""
    rows = [{"kind": "buds", "quantity": "par", "within": 1, "rfr_within": ""} for _ in range(2)]
    est = {"value": np.array([99.0, 40.0, 50.0]), "cov": np.diag([1.0, 0.01, 0.01]), "photons": 1,
           "sigma_from": "parts"}
    ref = {"value": np.array([110.0, 40.0, 40.0]), "cov": np.diag([1.0, 0.01, 0.01]), "photons": 1,
           "sigma_from": "parts"}
    s = Totals().add(rows, {"buds": (est, ref)}).summary()
    assert s["buds"]["par"]["bias"] == pytest.approx(99 / 110 - 1)
    assert s["buds"]["par"]["sigma"] == pytest.approx(0.9 * math.sqrt(1 / 99 ** 2 + 1 / 110 ** 2))
    assert not s["buds"]["par"]["ok"] and not s["passed"]            # −10 % against max(4σ, 5 %)
    assert s["buds"]["rfr"]["bias"] == pytest.approx(0.8 - 1.0) and not s["buds"]["rfr"]["ok"]
    assert s["buds"]["rfr"]["sigma"] == pytest.approx(math.sqrt((0.01 + 0.64 * 0.01) / 50 ** 2
                                                                + (0.01 + 0.01) / 40 ** 2))
    assert [organ_kind(m) for m in ("Leaf", "FeuilleVieille", "Bud", "bourgeon", "Internode", "")] == \
        ["leaves", "leaves", "buds", "buds", "other organs", "other organs"]
    with pytest.raises(InputError, match="verify"):
        verify_count(-1)
