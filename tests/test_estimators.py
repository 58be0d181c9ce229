"""The estimators' registry and their settings as one frozen, checked record (issue 44): one default everywhere,
a misspelt or out-of-range setting refused with its name, and nothing outside the kernel scene's module assigning
its attributes."""
import ast
import dataclasses
from pathlib import Path

import pytest

from lpy_light import cli
from lpy_light.run import simulate
from lpy_light.errors import InputError
from lpy_light.estimators.registry import DEFAULT_ESTIMATOR, ESTIMATORS, NextEventSettings, estimator
from lpy_light.plant.light import LightModel
from lpy_light.chamber.scene import load_scene, resolve_scene

ROOT = Path(__file__).resolve().parents[1]


@pytest.fixture(scope="module")
def angers():
    return load_scene(resolve_scene("angers"))


def test_one_default_everywhere(angers):
    parser = cli._parser()
    run = parser.parse_args(["run", "angers", "--out", "o"])
    assert run.estimator == DEFAULT_ESTIMATOR == simulate.KernelScene(angers).estimator
    assert LightModel.__init__.__defaults__[LightModel.__init__.__code__.co_varnames.index("estimator") - 1] \
        == DEFAULT_ESTIMATOR
    choices = next(a for a in parser._subparsers._group_actions[0].choices["run"]._actions if a.dest == "estimator")
    assert tuple(choices.choices) == tuple(ESTIMATORS)


def test_a_misspelt_or_out_of_range_setting_is_named(angers):
    ks = simulate.KernelScene(angers)
    with pytest.raises(InputError, match="unknown next-event setting 'pics'"):
        ks.configure(pics=2)
    with pytest.raises(InputError, match="'picks' must be a whole number in 0..4096"):
        ks.configure(picks=-1)
    with pytest.raises(InputError, match="'images' must be a rate in 0..64"):
        NextEventSettings(images=65)
    with pytest.raises(InputError, match="'control' must be True or False"):
        NextEventSettings(control="yes")
    with pytest.raises(InputError, match="unknown estimator 'mc'"):
        estimator("mc")
    assert ks.settings == ESTIMATORS["nee"].settings          # nothing half-applied


def test_settings_are_frozen_and_changed_by_a_new_record(angers):
    ks = simulate.KernelScene(angers, "nee")
    before = ks.settings
    with pytest.raises(dataclasses.FrozenInstanceError):
        before.picks = 3
    ks.configure(picks=3, cones=2)
    assert (ks.settings.picks, ks.settings.cones, before.picks, before.cones) == (3, 2.0, 1, None)


def test_light_model_arguments_are_checked_by_the_settings_with_their_own_names():
    with pytest.raises(InputError, match="cone_rays must be a rate in 0..64"):
        LightModel("angers", lamp_flux=[1.0], cone_rays=100)
    with pytest.raises(InputError, match="nee_picks must be a whole number"):
        LightModel("angers", lamp_flux=[1.0], nee_picks=-1)


def _kernel_scene_attributes() -> set:
    tree = ast.parse((ROOT / "lpy_light" / "estimators" / "kernel_scene.py").read_text(encoding="utf-8"))
    cls = next(n for n in tree.body if isinstance(n, ast.ClassDef) and n.name == "KernelScene")
    return {t.attr for n in ast.walk(cls) if isinstance(n, (ast.Assign, ast.AugAssign))
            for t in (n.targets if isinstance(n, ast.Assign) else [n.target])
            for t in (t.elts if isinstance(t, ast.Tuple) else [t])
            if isinstance(t, ast.Attribute) and isinstance(t.value, ast.Name) and t.value.id == "self"}


def test_nothing_outside_the_kernel_scenes_module_assigns_its_attributes():
    names = _kernel_scene_attributes()
    assert {"settings", "estimator", "organs"} <= names
    found = []
    for folder in ("lpy_light", "benchmarks", "tests", "scripts"):
        for path in sorted((ROOT / folder).rglob("*.py")):
            if path.name == "kernel_scene.py" and folder == "lpy_light":
                continue
            for node in ast.walk(ast.parse(path.read_text(encoding="utf-8"))):
                targets = node.targets if isinstance(node, ast.Assign) else [node.target] \
                    if isinstance(node, (ast.AugAssign, ast.AnnAssign)) else []
                for t in targets:
                    for t in (t.elts if isinstance(t, ast.Tuple) else [t]):
                        base = t.value if isinstance(t, (ast.Attribute, ast.Subscript)) else None
                        if isinstance(t, ast.Subscript):
                            t, base = base, getattr(base, "value", None)
                        if isinstance(t, ast.Attribute) and t.attr in names and (
                                (isinstance(base, ast.Name) and base.id in ("ks", "kscene", "angers", "k12"))
                                or (isinstance(base, ast.Attribute) and base.attr == "kscene")):
                            found.append("%s:%d" % (path.relative_to(ROOT), node.lineno))
    assert found == []
