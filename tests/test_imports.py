"""The package's modules import one way: no cycle, even through imports inside functions (issue 44); its rooms
(subpackages) import only the rooms below them (issue 55); each module imports alone in a fresh interpreter; and
no kernel function takes more than a dozen parameters."""
import ast
import subprocess
import sys
from pathlib import Path

import pytest

PACKAGE = Path(__file__).resolve().parents[1] / "lpy_light"
MODULES = sorted(p for p in PACKAGE.rglob("*.py") if p.name != "__main__.py")


def _name(path: Path) -> str:
    parts = path.relative_to(PACKAGE.parent).with_suffix("").parts
    return ".".join(parts[:-1] if parts[-1] == "__init__" else parts)


def imports_of(path: Path) -> set:
    """The package's modules that ``path`` imports, at its top or inside its functions (relative imports)."""
    here = _name(path).split(".")
    if path.name != "__init__.py":
        here = here[:-1]
    names = {_name(p) for p in MODULES}
    out = set()
    for node in ast.walk(ast.parse(path.read_text(encoding="utf-8"))):
        if isinstance(node, ast.ImportFrom) and node.level:
            base = here[:len(here) - node.level + 1]
            target = ".".join(base + ([node.module] if node.module else []))
            candidates = [target] + ([target + "." + a.name for a in node.names])
            out.update(c for c in candidates if c in names)
    out.discard(_name(path))
    return out


def cycles(graph: dict) -> list:
    """The strongly connected components of more than one module (Tarjan)."""
    index, low, stack, on, found, counter = {}, {}, [], set(), [], [0]

    def visit(v):
        index[v] = low[v] = counter[0]
        counter[0] += 1
        stack.append(v)
        on.add(v)
        for w in graph.get(v, ()):
            if w not in index:
                visit(w)
                low[v] = min(low[v], low[w])
            elif w in on:
                low[v] = min(low[v], index[w])
        if low[v] == index[v]:
            comp = []
            while True:
                w = stack.pop()
                on.discard(w)
                comp.append(w)
                if w == v:
                    break
            if len(comp) > 1:
                found.append(sorted(comp))

    for v in sorted(graph):
        if v not in index:
            visit(v)
    return found


def test_the_cycle_finder_finds_a_cycle():
    assert cycles({"a": {"b"}, "b": {"c"}, "c": {"a"}, "d": {"a"}}) == [["a", "b", "c"]]


def test_no_import_cycle_in_the_package():
    graph = {_name(p): {m for m in imports_of(p) if m != "lpy_light"} for p in MODULES}
    assert cycles(graph) == []


#: the package's floors, ground first: a module may import its own room's modules and those of lower floors only
#: (two rooms on one floor know nothing of each other).  Top-level modules are rooms of their own, on the floor named.
FLOORS = [
    {"errors", "messages", "process_state"},
    {"chamber"},
    {"estimators"},
    {"run"},
    {"plant", "report"},
    {"calibration"},
    {"cli", "__main__", "lpy_light"},
]
MAX_TOP_MODULES = 8


def room(module: str) -> str:
    """The room of a module: its subpackage, or its own name at the top (the package's __init__: 'lpy_light')."""
    parts = module.split(".")
    return parts[1] if len(parts) > 1 else parts[0]


def floor(name: str) -> int:
    return next(i for i, rooms in enumerate(FLOORS) if name in rooms)


def imports_against_the_floors(graph: dict) -> list:
    """(importer, imported) pairs where a room imports another room that is not below it."""
    return sorted((a, b) for a, bs in graph.items() for b in bs
                  if room(a) != room(b) and floor(room(b)) >= floor(room(a)))


def test_the_floor_check_finds_an_import_upward_and_across():
    graph = {"lpy_light.chamber.scene": {"lpy_light.errors", "lpy_light.run.simulate"},
             "lpy_light.plant.grow": {"lpy_light.report.plots", "lpy_light.chamber.units"}}
    assert imports_against_the_floors(graph) == [("lpy_light.chamber.scene", "lpy_light.run.simulate"),
                                                 ("lpy_light.plant.grow", "lpy_light.report.plots")]


def test_rooms_import_only_the_rooms_below_them():
    graph = {_name(p): imports_of(p) for p in MODULES}
    assert {room(m) for m in graph} <= set().union(*FLOORS), "a room or top module the floors do not place"
    assert imports_against_the_floors(graph) == []


def test_few_modules_at_the_top_and_every_room_says_what_it_serves():
    top = [p for p in PACKAGE.glob("*.py")]
    assert len(top) <= MAX_TOP_MODULES, sorted(p.name for p in top)
    for init in PACKAGE.glob("*/__init__.py"):
        tree = ast.parse(init.read_text(encoding="utf-8"))
        assert ast.get_docstring(tree), init
        assert len(tree.body) == 1, "%s: a room's __init__ is its docstring alone (no re-exports)" % init


@pytest.mark.parametrize("module", [_name(p) for p in MODULES])
def test_each_module_imports_alone(module):
    code = subprocess.run([sys.executable, "-c", "import %s" % module], capture_output=True, text=True)
    assert code.returncode == 0, code.stderr


KERNEL = Path(__file__).resolve().parents[1] / "kernel"
MAX_PARAMETERS = 12


def parameters(fn: ast.FunctionDef) -> int:
    a = fn.args
    return len(a.posonlyargs) + len(a.args) + len(a.kwonlyargs) + bool(a.vararg) + bool(a.kwarg)


def test_parameters_counts_every_kind():
    fn = ast.parse("def f(a, /, b, *c, d, **e): pass").body[0]
    assert parameters(fn) == 5


@pytest.mark.parametrize("path", sorted(KERNEL.glob("*.py")), ids=lambda p: p.name)
def test_kernel_functions_take_records_not_dozens_of_arrays(path):
    """A kernel function reads the few records it needs (kernel/records.py): at most 12 parameters."""
    long = ["%s (%d)" % (n.name, parameters(n)) for n in ast.walk(ast.parse(path.read_text(encoding="utf-8")))
            if isinstance(n, ast.FunctionDef) and parameters(n) > MAX_PARAMETERS]
    assert long == []
