"""Many runs as one command (``lpy-light sweep``): a grid of growth runs or of chamber runs.

    lpy-light sweep MODEL.lpy --steps 30 --set PAR_MIN=20,40,80 --set SEED=1..10 --out runs/sweep
    lpy-light sweep a.toml b.toml --set seed=1..4 --photons 1e6 --out runs/scenes [--dask ADDRESS]

Each combination of the inputs (``.lpy`` models, grown by ``lpy-light grow``; or scenes, traced by
``lpy-light run``) and of the ``--set`` values is one task: the command line of that run (options
the sweep does not know go to every run as they are).  ``--set NAME=V1,V2`` or ``NAME=A..B``
(whole numbers, both ends included): for a model, an ``extern`` of the model (``grow --set``); for
a scene, a ``run`` option (``--set seed=1..4`` is ``--seed 1`` .. ``--seed 4``).

A task runs ``python -m lpy_light ARGV --out TMP`` in a process of its own (:func:`run_task`), on
this machine (a pool of ``--workers`` at once) or on a Dask worker (``--dask``); its files come back
here and are written into ``OUT/NAME/`` at once (a folder renamed into place: a folder that exists
is a finished run), with ``task.json`` (its command line).  ``OUT/sweep.csv`` lists every task with
its values and status (done, failed, interrupted, pending), rewritten as each one ends.  Running
the same command again skips the finished runs; a finished folder made by another command line is
refused rather than taken for this one's.

Faults: a Dask worker that dies takes its running tasks with it, and the scheduler runs them again
elsewhere; each task's result is stored once.  Ctrl-C (or SIGTERM) stops the runs in progress
(their processes are ended, locally and on the cluster), keeps the finished ones, writes
``sweep.csv`` and exits with status 130.
"""
from __future__ import annotations

import contextlib
import csv
import hashlib
import io
import itertools
import json
import os
import re
import shutil
import signal
import socket
import subprocess
import sys
import tempfile
import threading
import time
import uuid
from concurrent.futures import FIRST_COMPLETED, ThreadPoolExecutor, wait
from dataclasses import dataclass, field
from pathlib import Path

from ..errors import InputError
from ..chamber.scene import resolve_scene

#: how often a running task checks whether the sweep was stopped (s)
POLL = 0.5
#: lines of a failed run's stderr kept in sweep.csv
ERROR_LINES = 1
_NAME_CHARS = re.compile(r"[^A-Za-z0-9._=,+-]")
_RANGE = re.compile(r"\s*(-?\d+)\s*\.\.\s*(-?\d+)\s*$")


@dataclass
class Task:
    """One run of a sweep: its folder ``name`` in the sweep's ``--out``, the grid's ``params``
    (``{"input": ...}`` first when the sweep has several inputs), and its ``argv`` (the ``lpy-light``
    command line, without ``--out``)."""

    name: str
    params: dict
    argv: list
    status: str = "pending"
    seconds: float | None = None
    worker: str = ""
    message: str = ""
    extra: dict = field(default_factory=dict)


# ------------------------------------------------------------------------------------------
# The grid
def parse_set(text: str) -> tuple[str, list[str]]:
    """``NAME=V1,V2,...`` or ``NAME=A..B`` → (NAME, [value texts]); values stay text (the run parses them)."""
    name, eq, values = text.partition("=")
    name = name.strip()
    if not eq or not re.fullmatch(r"[A-Za-z_][A-Za-z0-9_-]*", name):
        raise InputError("--set %s: expected NAME=V1,V2,... or NAME=A..B" % text)
    m = _RANGE.match(values)
    if m:
        a, b = int(m.group(1)), int(m.group(2))
        if b < a or b - a >= 100_000:
            raise InputError("--set %s: a range A..B needs A <= B and fewer than 100000 values" % text)
        return name, [str(v) for v in range(a, b + 1)]
    out = [v.strip() for v in values.split(",")]
    if not values.strip() or any(not v for v in out):
        raise InputError("--set %s: an empty value (expected NAME=V1,V2,... or NAME=A..B)" % text)
    return name, out


def grid(sets) -> list[dict]:
    """Every combination of the ``--set`` values, the first ``--set`` varying slowest: [{NAME: text}]."""
    axes = [parse_set(s) for s in sets]
    names = [n for n, _ in axes]
    if len(set(names)) != len(names):
        raise InputError("--set names %s more than once" % ", ".join(sorted({n for n in names if names.count(n) > 1})))
    return [dict(zip(names, combo)) for combo in itertools.product(*[v for _, v in axes])]


def model_externs(path) -> list[str]:
    """Names an ``.lpy`` model declares with ``extern(NAME=default, ...)`` (what ``grow --set`` may set)."""
    text = Path(path).read_text(errors="replace")
    names = []
    for args in re.findall(r"^\s*extern\s*\((.*)\)", text, flags=re.M):
        names += re.findall(r"(?:^|,)\s*([A-Za-z_]\w*)\s*=", args)
    return list(dict.fromkeys(names))


def _folder_name(parts: list[str]) -> str:
    name = ",".join(parts) or "run"
    safe = _NAME_CHARS.sub("_", name)
    if safe != name or len(safe) > 120 or safe.startswith("."):
        # characters a folder name should not have: keep it readable, and unique by the exact text
        safe = safe.lstrip(".")[:100] + "-" + hashlib.sha256(name.encode()).hexdigest()[:8]
    return safe


def _kind(path: str) -> str:
    return "grow" if path.endswith(".lpy") else "run"


def tasks_for(inputs, sets, passthrough=(), threads: int = 1) -> list[Task]:
    """The tasks of a sweep: every input × every combination of ``sets``.

    ``inputs``: ``.lpy`` models (``lpy-light grow``) or scenes (``lpy-light run``: files or built-in
    names), not both; ``passthrough``: options given to every run (``--steps 30``); ``threads``:
    threads per run unless ``passthrough`` says ``--threads``.
    """
    kinds = {_kind(i) for i in inputs}
    if len(kinds) != 1:
        raise InputError("a sweep grows .lpy models or runs scenes, not both: %s" % " ".join(inputs))
    kind = kinds.pop()
    resolved = []         # absolute paths (a built-in scene's name stays a name)
    for i in inputs:
        if kind == "grow" and not Path(i).is_file():
            raise InputError("L-Py model not found", i)
        if kind == "run":
            resolve_scene(i)                      # refused here if it is neither a file nor a built-in scene
        resolved.append(str(Path(i).resolve()) if Path(i).exists() else i)
    passthrough = list(passthrough)
    for opt in ("--out", "--set") if kind == "grow" else ("--out",):
        if any(a == opt or a.startswith(opt + "=") for a in passthrough):
            raise InputError("%s belongs to the sweep, not to each run (it is set for every task)" % opt)
    if not any(a == "--threads" or a.startswith("--threads=") for a in passthrough):
        passthrough += ["--threads", str(threads)]
    combos = grid(sets)
    if kind == "grow" and combos:
        for path in resolved:
            declared = model_externs(path)
            unknown = [name for name in combos[0] if name not in declared]
            if unknown:
                raise InputError("--set %s: the model declares no such extern (it has %s)"
                                 % (", ".join(unknown), ", ".join(declared) or "none"), path)
    tasks = []
    stems = [Path(i).stem for i in inputs]
    for i, (path, stem) in enumerate(zip(resolved, stems)):
        for combo in combos:
            argv = [kind, path] + passthrough
            for k, v in combo.items():
                argv += ["--set", "%s=%s" % (k, v)] if kind == "grow" else ["--" + k.replace("_", "-"), v]
            argv.append("--quiet")
            parts = ([stem] if len(inputs) > 1 or not combo else []) + ["%s=%s" % kv for kv in combo.items()]
            params = ({"input": inputs[i]} if len(inputs) > 1 else {}) | combo
            tasks.append(Task(_folder_name(parts), params, argv))
    names = [t.name for t in tasks]
    for t in tasks:                   # two inputs with one stem (a/scene.toml, b/scene.toml)
        if names.count(t.name) > 1:
            t.name = _folder_name([t.name, hashlib.sha256(json.dumps(t.argv).encode()).hexdigest()[:8]])
    return tasks


# ------------------------------------------------------------------------------------------
# One task, wherever it runs
def _child():
    """Entry of a task's process: die with the process that started it (Linux), then be ``lpy-light``."""
    parent = int(os.environ.pop("LPY_LIGHT_SWEEP_PARENT", "0"))
    with contextlib.suppress(Exception):
        import ctypes
        ctypes.CDLL(None, use_errno=True).prctl(1, signal.SIGKILL)      # PR_SET_PDEATHSIG
    if parent and os.getppid() != parent:          # the parent died before prctl took effect
        sys.exit(137)
    import runpy
    runpy.run_module("lpy_light", run_name="__main__")      # lpy-light ARGV (sys.argv[1:])


def run_task(argv, cancelled=None) -> dict:
    """Run ``lpy-light ARGV --out TMP`` in a process of its own; return its outcome and files.

    ``cancelled``: None, a callable, or the name of a ``distributed.Event`` (on a Dask worker):
    polled every :data:`POLL` s; when true the process is ended (SIGTERM).  Returns ``{"code",
    "files": {name: bytes}, "stderr": last lines, "seconds", "worker"}``.
    """
    if isinstance(cancelled, str):
        from distributed import Event
        event = Event(cancelled)
        cancelled = event.is_set
    start = time.perf_counter()
    with tempfile.TemporaryDirectory(prefix="lpy-light-task-") as tmp:
        out, log = Path(tmp) / "out", Path(tmp) / "stderr.txt"
        env = dict(os.environ, LPY_LIGHT_SWEEP_PARENT=str(os.getpid()))
        with open(log, "wb") as err:
            proc = subprocess.Popen([sys.executable, "-c", "from lpy_light.run.sweep import _child; _child()",
                                     *argv, "--out", str(out)], stdin=subprocess.DEVNULL, stdout=err, stderr=err,
                                    env=env, start_new_session=True)    # a terminal's Ctrl-C is the sweep's
            try:
                while True:
                    try:
                        code = proc.wait(timeout=POLL)
                        break
                    except subprocess.TimeoutExpired:
                        if cancelled is not None and cancelled():
                            proc.terminate()
            finally:
                if proc.poll() is None:
                    proc.kill()
                    proc.wait()
        files = {p.name: p.read_bytes() for p in sorted(out.iterdir()) if p.is_file()} if out.is_dir() else {}
        stderr = log.read_text(errors="replace").strip().splitlines()
    return {"code": code, "files": files, "stderr": stderr[-20:], "seconds": time.perf_counter() - start,
            "worker": "%s:%d" % (socket.gethostname(), os.getpid())}


# ------------------------------------------------------------------------------------------
# The sweep's folder
def _task_json(task: Task, outcome: dict) -> str:
    return json.dumps({"argv": task.argv, "params": task.params, "seconds": outcome["seconds"],
                       "worker": outcome["worker"]}, indent=2) + "\n"


def finished(out: Path, task: Task) -> bool:
    """Whether ``out/NAME`` holds this task's finished run (refused if it holds another command's)."""
    folder = out / task.name
    if not folder.is_dir():
        return False
    try:
        done = json.loads((folder / "task.json").read_text())
    except (OSError, ValueError):
        raise InputError("%s holds no task.json: not a run of this sweep; remove it or choose another --out"
                         % folder) from None
    if done.get("argv") != task.argv:
        raise InputError("%s holds a run of another command line (%s); this sweep's is %s: choose another --out"
                         % (folder, " ".join(map(str, done.get("argv", []))), " ".join(task.argv)))
    task.status, task.seconds, task.worker = "done", done.get("seconds"), done.get("worker", "")
    task.message = "finished before"
    return True


def store(out: Path, task: Task, outcome: dict):
    """Write a finished task's files into ``out/NAME`` at once: a hidden folder renamed into place."""
    tmp = out / (".%s.tmp-%s" % (task.name, uuid.uuid4().hex[:8]))
    tmp.mkdir(parents=True)
    try:
        for name, data in outcome["files"].items():
            (tmp / name).write_bytes(data)
        (tmp / "task.json").write_text(_task_json(task, outcome))
        os.rename(tmp, out / task.name)
    except OSError:
        shutil.rmtree(tmp, ignore_errors=True)
        if not (out / task.name / "task.json").is_file():
            raise                             # (else: another sweep stored the same run first)


def write_index(out: Path, tasks):
    """``out/sweep.csv``: one row per task, its values, status, seconds, worker, message (atomically)."""
    from .results import atomic_write

    keys = list(dict.fromkeys(k for t in tasks for k in t.params))
    buf = io.StringIO()
    w = csv.writer(buf, lineterminator="\n")
    w.writerow(["run"] + keys + ["status", "seconds", "worker", "message"])
    for t in tasks:
        w.writerow([t.name] + [t.params.get(k, "") for k in keys]
                   + [t.status, "" if t.seconds is None else "%.3f" % t.seconds, t.worker, t.message])
    atomic_write(out / "sweep.csv", buf.getvalue())


# ------------------------------------------------------------------------------------------
# Where the tasks run
class _LocalPool:
    """Tasks on this machine, ``workers`` at once."""

    def __init__(self, workers: int):
        self.pool = ThreadPoolExecutor(max_workers=workers)
        self.stopping = threading.Event()
        self.where = "%d local process(es)" % workers

    def submit(self, task):
        return self.pool.submit(run_task, task.argv, self.stopping.is_set)

    def wait(self, futures):
        done, _ = wait(futures, timeout=1.0, return_when=FIRST_COMPLETED)
        return done

    def stop(self, futures):
        self.stopping.set()
        for f in futures:
            f.cancel()

    def close(self):
        self.pool.shutdown(wait=True)


class _DaskPool:
    """Tasks on a Dask cluster: one Dask task per run."""

    def __init__(self, client):
        from distributed import Event
        self.client = client
        self.event_name = "lpy-light-sweep-stop-%s" % uuid.uuid4().hex
        self.event = Event(self.event_name, client=client)
        self.where = "Dask at %s" % getattr(client, "lpy_address", client.scheduler.address)

    def submit(self, task):
        key = "lpy-light-sweep-%s-%s" % (task.name, hashlib.sha256(json.dumps(task.argv).encode()).hexdigest()[:8])
        return self.client.submit(run_task, task.argv, self.event_name, key=key, pure=False)

    def wait(self, futures):
        from distributed import wait as dask_wait
        done, _ = dask_wait(list(futures), timeout=1.0, return_when="FIRST_COMPLETED") \
            if futures else (set(), set())
        return done

    def stop(self, futures):
        with contextlib.suppress(Exception):
            self.event.set()                         # tasks running end their processes
            self.client.cancel(list(futures))

    def close(self):
        pass


def _wait_done(pool, futures):
    try:
        return pool.wait(futures)
    except Exception as exc:           # distributed.TimeoutError when nothing finished within the second
        if type(exc).__name__ in ("TimeoutError", "CancelledError"):
            return set()
        raise


def run_sweep(tasks, out, workers: int | None = None, client=None, stop=None, report=None) -> int:
    """Run ``tasks`` (:func:`tasks_for`) into ``out``; return the exit status (0 all done, 1 some failed,
    130 stopped).  ``client``: a ``distributed.Client`` (else a local pool of ``workers`` processes);
    ``stop()`` true ends the sweep as Ctrl-C does; ``report(line)`` hears one line per finished task."""
    out = Path(out)
    out.mkdir(parents=True, exist_ok=True)
    for tmp in out.glob(".*.tmp-*"):          # a folder being stored when an earlier sweep was stopped
        shutil.rmtree(tmp, ignore_errors=True)
    todo = [t for t in tasks if not finished(out, t)]
    skipped = len(tasks) - len(todo)
    write_index(out, tasks)
    if not todo:
        if report:
            report("all %d runs finished before; nothing to do (sweep.csv in %s)" % (len(tasks), out))
        return 0
    if client is not None:
        pool = _DaskPool(client)
    else:
        from .simulate import default_threads
        pool = _LocalPool(workers or default_threads())
    if report:
        report("%d runs (%d finished before), on %s" % (len(tasks), skipped, pool.where))
    running = {pool.submit(t): t for t in todo}
    for t in todo:
        t.status = "running"
    stopped = False
    try:
        while running:
            for fut in _wait_done(pool, running):
                task = running.pop(fut)
                try:
                    outcome = fut.result()
                except Exception as exc:        # the task itself could not run (a worker lost too often)
                    task.status, task.message = "failed", " ".join(("%s: %s" % (type(exc).__name__, exc)).split())
                else:
                    _record(out, task, outcome)
                write_index(out, tasks)
                if report:
                    report("[%d/%d] %s: %s%s" % (sum(t.status in ("done", "failed") for t in tasks), len(tasks),
                                                 task.name, task.status,
                                                 " in %.1f s" % task.seconds if task.status == "done" else
                                                 " (%s)" % task.message))
            if stop is not None and running and stop():
                raise KeyboardInterrupt
    except KeyboardInterrupt:
        stopped = True
        pool.stop(running)
        for t in running.values():
            t.status, t.message = "interrupted", "stopped before it finished"
    finally:
        pool.close()
        write_index(out, tasks)
    done = sum(t.status == "done" for t in tasks)
    failed = sum(t.status == "failed" for t in tasks)
    if report:
        report("%d of %d runs done (%d finished before)%s%s; sweep.csv in %s"
               % (done, len(tasks), skipped, ", %d failed" % failed if failed else "",
                  " — STOPPED: the same command goes on where it stopped" if stopped else "", out))
    return 130 if stopped else (1 if failed else 0)


def _record(out: Path, task: Task, outcome: dict):
    task.seconds, task.worker = outcome["seconds"], outcome["worker"]
    code = outcome["code"]
    if code == 0:
        store(out, task, outcome)
        task.status, task.message = "done", ""
    else:
        errors = [line for line in outcome["stderr"] if "error" in line.lower()] or outcome["stderr"]
        task.status = "interrupted" if code in (130, -signal.SIGTERM) else "failed"
        task.message = " ".join(" | ".join(errors[-ERROR_LINES:]).split()) or "exit status %d" % code
