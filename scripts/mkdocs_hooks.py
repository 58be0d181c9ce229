"""MkDocs hooks of the documentation site (mkdocs.yml), run by ``bash scripts/docs.sh``.

* A line ``<!-- help: lpy-light ARGS -->`` in a page becomes the output of ``lpy-light ARGS --help``, run with the
  package's own interpreter (``$LPY_LIGHT_PYTHON``, else ``.venv/bin/python``): the command line's reference is
  its parser's, never a copy that drifts.
* The reference pages are checked against the code, each gap a warning (so an error under ``--strict``): every
  parameter of ``LightModel.__init__`` is documented in its docstring's Parameters section, and every key a scene
  accepts (``_SCENE_KEYS``, ``_PHYSICS_KEYS`` of ``lpy_light/chamber/scene.py``) is named in
  ``docs/scene-format.md``.  Both are read from the source (``ast``): nothing is imported.
"""
from __future__ import annotations

import ast
import logging
import os
import re
import subprocess
from pathlib import Path

log = logging.getLogger("mkdocs.plugins.lpy_light")

ROOT = Path(__file__).resolve().parents[1]
HELP = re.compile(r"^<!-- help: lpy-light(?P<args>(?: [\w-]+)*) -->$", re.MULTILINE)


def _python() -> str:
    return os.environ.get("LPY_LIGHT_PYTHON") or str(ROOT / ".venv" / "bin" / "python")


def _help(args: str, page: str) -> str:
    command = [_python(), "-m", "lpy_light", *args.split(), "--help"]
    try:
        out = subprocess.run(command, cwd=ROOT, capture_output=True, text=True, timeout=120,
                             env={**os.environ, "COLUMNS": "110"})
    except (OSError, subprocess.TimeoutExpired) as exc:
        log.warning("%s: `lpy-light%s --help` could not run (%s): run bash scripts/setup.sh first", page, args, exc)
        return "(lpy-light%s --help could not run when this page was built)" % args
    if out.returncode != 0:
        log.warning("%s: `lpy-light%s --help` exited %d: %s", page, args, out.returncode, out.stderr.strip()[-500:])
    return "```text\n$ lpy-light%s --help\n%s```" % (args, out.stdout)


def on_page_markdown(markdown, page, config, files):
    return HELP.sub(lambda m: _help(m.group("args"), page.file.src_uri), markdown)


# -- the reference pages against the code ----------------------------------------------------------------------
def _class(path: Path, name: str) -> ast.ClassDef:
    tree = ast.parse(path.read_text(encoding="utf-8"))
    return next(node for node in tree.body if isinstance(node, ast.ClassDef) and node.name == name)


def _documented_parameters(docstring: str) -> set:
    """The names of a numpy docstring's Parameters section (``name : type`` lines)."""
    section = re.search(r"^\s*Parameters\n\s*-+\n(.*?)(?:^\s*\w[\w ]*\n\s*-+\n|\Z)", docstring, re.S | re.M)
    if not section:
        return set()
    names = set()
    for line in section.group(1).splitlines():
        m = re.match(r"^\s{0,8}(\w+(?:\s*,\s*\w+)*)\s*:", line)
        if m and not line.startswith(" " * 9):
            names.update(n.strip() for n in m.group(1).split(","))
    return names


def _check_light_model():
    cls = _class(ROOT / "lpy_light" / "plant" / "light.py", "LightModel")
    init = next(node for node in cls.body if isinstance(node, ast.FunctionDef) and node.name == "__init__")
    parameters = [a.arg for a in init.args.args[1:] + init.args.kwonlyargs]
    missing = [p for p in parameters if p not in _documented_parameters(ast.get_docstring(cls) or "")]
    if missing:
        log.warning("LightModel's docstring does not document %s (lpy_light/plant/light.py): the API page lists "
                    "every parameter with its unit", ", ".join(missing))


def _assigned_set(path: Path, name: str) -> set:
    tree = ast.parse(path.read_text(encoding="utf-8"))
    for node in tree.body:
        targets = node.targets if isinstance(node, ast.Assign) else [getattr(node, "target", None)]
        if any(isinstance(t, ast.Name) and t.id == name for t in targets):
            value = ast.literal_eval(node.value) if not isinstance(node.value, ast.Dict) else \
                {ast.literal_eval(k) for k in node.value.keys}
            return set(value)
    raise LookupError("%s not found in %s" % (name, path))


def _check_scene_format(docs_dir: Path):
    scene = ROOT / "lpy_light" / "chamber" / "scene.py"
    page = (docs_dir / "scene-format.md").read_text(encoding="utf-8")
    keys = _assigned_set(scene, "_SCENE_KEYS") | {"physics." + k for k in _assigned_set(scene, "_PHYSICS_KEYS")}
    named = set(re.findall(r"`([\w.]+)`", page))
    missing = sorted(k for k in keys if k not in named and k.split(".")[-1] not in named)
    if missing:
        log.warning("docs/scene-format.md does not name the scene keys %s (lpy_light/chamber/scene.py)",
                    ", ".join(missing))


def on_pre_build(config):
    _check_light_model()
    _check_scene_format(Path(config["docs_dir"]))
