"""A first run's compile on two cores: the entry point's helpers compiled in two processes at once.

numba compiles in one thread.  On a first run (empty cache) the ``nee`` kernel's compile is ~60 % helpers
(:func:`kernel.jit.helper`: ``next_event``, ``image_event``, ``zone_event`` ... each a subtree of helpers, each
cached on disk on its own) and ~40 % the entry point :func:`kernel.trace.trace_photons` itself, which needs
them all (typing, lowering, LLVM of the whole inlined loop).  Where another core is free, the helpers'
subtrees are shared out before the entry point compiles: a child process compiles its share and caches it
while this process compiles the rest; the entry point then loads the child's share from numba's cache.

Which helpers, for which argument types, is only known by typing the entry point, so it is recorded once by
the developers (:func:`record`, ``python scripts/compile_plan.py``) in ``compile_plan.pkl`` beside this file:
for each entry-point signature, its direct helper calls (module, name, argument types, seconds to compile).
A stale or unreadable plan costs time, never results: a helper compiled for types the entry point does not
use is never linked, and one the plan lacks is compiled when the entry point asks for it, as without a plan.
The numbers are the same either way, bit for bit (``tests/test_warm.py``); the machine code may differ in
its symbols' names and hence in details such as the stack frame's layout.
"""
from __future__ import annotations

import contextlib
import importlib
import os
import pickle
import subprocess
import sys
from pathlib import Path

#: the recorded plan: (numba's version, {(entry module, entry name, entry argument types): [(module, name,
#: argument types, s)]})
PLAN = Path(__file__).with_name("compile_plan.pkl")
#: seconds a child process takes to start (imports) before it compiles: its share is that much smaller
CHILD_START = 1.0
#: below this many seconds of helpers, a second process is not worth its start
MIN_SHARED = 3.0


def read_plan(plan_path=PLAN):
    """(the numba version it was recorded with, the plan: see :data:`PLAN`); raises if unreadable."""
    with open(plan_path, "rb") as f:
        version, plan = pickle.load(f)
    return version, plan


def plan_for(dispatcher, args, plan_path=PLAN):
    """The recorded helper calls of ``dispatcher`` for ``args``' types, or None (none recorded, no plan,
    a plan this numba cannot read: another numba's types may differ, and then only the shortcut is lost)."""
    try:
        return _plan_for(dispatcher, _signature(dispatcher, args), plan_path)
    except Exception:       # noqa: BLE001 -- any failure only means no shortcut
        return None


def _plan_for(dispatcher, sig, plan_path=PLAN):
    return read_plan(plan_path)[1].get(_entry_key(dispatcher, sig))


def _signature(dispatcher, args):
    """numba's argument types of a call of ``dispatcher`` with ``args``."""
    return tuple(dispatcher.typeof_pyval(a) for a in args)


def _entry_key(dispatcher, sig):
    return dispatcher.py_func.__module__, dispatcher.py_func.__qualname__, tuple(sig)


def is_ready(dispatcher, args) -> bool:
    """Is ``dispatcher`` compiled for ``args`` in this process, or in numba's cache?"""
    try:
        return _is_ready(dispatcher, _signature(dispatcher, args))
    except Exception:       # noqa: BLE001 -- unknown: compile as numba would
        return True


def _is_ready(dispatcher, sig) -> bool:
    if sig in dispatcher.overloads:
        return True
    cache = dispatcher._cache
    return cache._index_key(sig, dispatcher.targetctx.codegen()) in cache._cache_file._load_index()


def shares(calls, child_start=CHILD_START):
    """Split ``calls`` [(module, name, types, seconds)] into (this process's, the child's): each call, the
    longest first, goes to the one that would finish first (the child starts ``child_start`` s late)."""
    mine, theirs, t_mine, t_theirs = [], [], 0.0, child_start
    for call in sorted(calls, key=lambda c: -c[3]):
        if t_mine <= t_theirs:
            mine.append(call)
            t_mine += call[3]
        else:
            theirs.append(call)
            t_theirs += call[3]
    return mine, theirs


def compile_calls(entry, calls) -> None:
    """Compile (or load from the cache) each helper call [(module, name, types, seconds)] as the entry point
    ``entry`` (module, name) would: under its flags, which callees inherit (no reference counting in
    :func:`kernel.trace.trace_photons`'s helpers: numba's cache key does not tell the two builds apart)."""
    from numba.core import compiler
    from numba.core.targetconfig import ConfigStack
    dispatcher = _function(*entry)
    flags = compiler.Flags()
    dispatcher.targetdescr.options.parse_as_flags(flags, dispatcher.targetoptions)
    flags = dispatcher._compiler._customize_flags(flags)
    with ConfigStack().enter(flags):
        for module, name, types, _ in calls:
            _function(module, name).compile(tuple(types))


def _function(module, name):
    target = importlib.import_module(module)
    for part in name.split("."):
        target = getattr(target, part)
    return target


def share_compile(dispatcher, args, plan_path=PLAN) -> bool:
    """Before ``dispatcher`` compiles for ``args``: if it is not ready (:func:`is_ready`), a plan is recorded
    for these types and a second core is free, compile the plan's helper calls, a share in a child process
    and the rest here, and wait for the child.  Returns whether a child shared the work."""
    if _cpus() < 2 or not _is_python(sys.executable):
        return False
    try:
        sig = _signature(dispatcher, args)
        if _is_ready(dispatcher, sig):
            return False
        calls = _plan_for(dispatcher, sig, plan_path)
    except Exception:       # noqa: BLE001 -- unknown state or no plan: compile as numba would
        return False
    if not calls or sum(c[3] for c in calls) < MIN_SHARED:
        return False
    mine, theirs = shares(calls)
    entry = dispatcher.py_func.__module__, dispatcher.py_func.__qualname__
    child = _start_child(entry, theirs)
    if child is None:
        return False
    try:
        compile_calls(entry, mine)
    finally:
        try:
            child.wait(timeout=600)
        except subprocess.TimeoutExpired:
            child.kill()
    return child.returncode == 0


def _cpus() -> int:
    return len(os.sched_getaffinity(0)) if hasattr(os, "sched_getaffinity") else (os.cpu_count() or 1)


def _is_python(executable) -> bool:
    """A Python interpreter (not an application embedding one, e.g. L-Py's editor): can run ``-c``."""
    return bool(executable) and Path(executable).name.startswith("python")


def _start_child(entry, calls):
    """A child process compiling ``calls`` (as ``entry``'s callees) into numba's cache, the same cache folder
    as this process's."""
    from numba.core import config
    env = dict(os.environ)
    if config.CACHE_DIR:
        env["NUMBA_CACHE_DIR"] = config.CACHE_DIR
    env["PYTHONPATH"] = os.pathsep.join(p for p in sys.path if p)
    try:
        child = subprocess.Popen([sys.executable, "-c", "from %s import _child; _child()" % __name__],
                                 stdin=subprocess.PIPE, stdout=subprocess.DEVNULL, stderr=subprocess.DEVNULL,
                                 env=env)
        child.stdin.write(pickle.dumps((entry, calls)))
        child.stdin.close()
        return child
    except (OSError, pickle.PicklingError):
        return None


def _child():
    """The child's side: read the calls from stdin, compile them (numba caches each on disk)."""
    compile_calls(*pickle.loads(sys.stdin.buffer.read()))


@contextlib.contextmanager
def record(entries):
    """Record, while the block compiles, each entry point's direct helper calls: yields a dict that is filled,
    at exit, as :data:`PLAN` is: {(module, name, types): [(module, name, types, seconds)]}.  ``entries``: the
    dispatchers to watch.  Needs an empty cache (what loads from the cache is not compiled, so not seen)."""
    from numba.core import event
    from .jit import _HELPERS
    watched = {id(d) for d in entries}
    found = {}
    with event.install_recorder("numba:compile") as rec:
        yield found
    stack = []
    for ts, ev in rec.buffer:
        if ev.is_start:
            stack.append((ts, ev))
            continue
        t0, start = stack.pop()
        if len(stack) != 1 or id(stack[0][1].data["dispatcher"]) not in watched:
            continue                            # not a direct call of a watched entry point
        d, parent = start.data["dispatcher"], stack[0][1].data["dispatcher"]
        name = (d.py_func.__module__, d.py_func.__qualname__)
        if name in _HELPERS:
            key = _entry_key(parent, stack[0][1].data["args"])
            found.setdefault(key, []).append(name + (tuple(start.data["args"]), ts - t0))
