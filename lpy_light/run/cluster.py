"""Photon chunks on a Dask cluster (``lpy-light run --dask ADDRESS``): an executor of :func:`simulate.run`.

Chunks are Dask tasks; :func:`lpy_light.run.simulate.run` submits them, sums their tallies in chunk
order and keeps ``--precision``, the progress line and interrupts, as it does for its local
threads (:class:`lpy_light.run.simulate.LocalThreads`) — so a run on a cluster gives bitwise the
numbers of a local run with the same seed and photons.

The chamber travels once per worker, not with each chunk: the :class:`~lpy_light.estimators.kernel_scene.KernelScene`
is pickled (without its Embree scene: its settings, the pruning of next events and the organs come
as they are here), registered as a worker plugin under its content digest, and every worker —
also one that joins or restarts during the run — keeps it; a worker builds its Embree scene at its
first chunk and keeps it for the next ones (:func:`worker_scene`).  A task ships the digest, the
seed and its chunks' (first photon index, photon count) — up to :data:`MAX_CHUNKS_PER_TASK`
consecutive chunks, to keep the scheduler's cost per task small — and returns each chunk's
tallies apart, for the client to sum one chunk at a time.

Faults: a worker that dies takes its running chunks with it; the scheduler runs them again on
another worker (results depend only on seed and photon index, and each chunk's future is summed
once), so the result is that of an undisturbed run.

Addresses (:func:`dask_client`): ``local`` or ``local:N`` starts a ``LocalCluster`` of N worker
processes bound to 127.0.0.1; ``tls://host:port`` (certificates from Dask's configuration,
``docs/scaling.md``), ``tcp://host:port`` or ``host:port`` connect to a running scheduler; a
``.json`` file is a scheduler file (``dask scheduler --scheduler-file``, dask-jobqueue).
"""
from __future__ import annotations

import contextlib
import hashlib
import ipaddress
import logging
import pickle
import re
import signal
import threading
import time
import uuid
from collections import OrderedDict
from pathlib import Path

from ..errors import InputError, LpyLightError

try:
    from distributed.diagnostics.plugin import WorkerPlugin as _WorkerPlugin
except ImportError:                 # without Dask this module only parses addresses
    _WorkerPlugin = object

log = logging.getLogger("lpy_light")

#: seconds to wait for a scheduler to answer before saying it cannot be reached
CONNECT_TIMEOUT = 20.0
#: scenes (with their recipes) a worker keeps built, the latest used
KEEP_SCENES = 4
#: a run's chunks are grouped into tasks so that each worker thread gets at least this many tasks ...
TASKS_PER_THREAD = 4
#: ... of at most this many chunks (16 x 32768 photons: ~0.3-2 s of tracing on the Angers chamber)
MAX_CHUNKS_PER_TASK = 16
_LOCAL = re.compile(r"local(?::(\d+))?$")


def _require_distributed():
    try:
        import distributed
    except ImportError:
        raise InputError("--dask needs Dask's distributed scheduler: pip install 'lpy-light[dask]'") from None
    return distributed


# ------------------------------------------------------------------------------------------
# Addresses
def local_workers(address: str) -> int | None:
    """N of ``local`` / ``local:N`` (None: not a local cluster; ``local``: one worker per core)."""
    m = _LOCAL.match(address.strip())
    if not m:
        return None
    if m.group(1) is None:
        from .simulate import default_threads
        return default_threads()
    n = int(m.group(1))
    if not 1 <= n <= 256:
        raise InputError("--dask local:N needs 1 <= N <= 256 worker processes, got %d" % n)
    return n


def scheduler_host(address: str) -> tuple[str, str]:
    """(protocol, host) of a scheduler address: ``tls://a:8786`` → (tls, a); ``a:8786`` → (tcp, a)."""
    protocol, _, rest = address.strip().rpartition("://")
    rest = rest.split("/")[0]
    if rest.startswith("["):                      # [::1]:8786
        host = rest[1:rest.find("]")] if "]" in rest else rest[1:]
    else:
        host = rest.rsplit(":", 1)[0] if rest.count(":") == 1 else rest
    return (protocol or "tcp").lower(), host


def is_loopback(host: str) -> bool:
    """Whether ``host`` (a name or an IP literal) is this machine's loopback."""
    if host.lower() in ("localhost", "localhost.localdomain", "ip6-localhost"):
        return True
    try:
        return ipaddress.ip_address(host).is_loopback
    except ValueError:
        return False


def insecure_warning(address: str) -> str | None:
    """The one-line warning for a scheduler reached without TLS outside the loopback, or None."""
    protocol, host = scheduler_host(address)
    if protocol in ("tls", "inproc") or is_loopback(host):
        return None
    return ("--dask %s is neither TLS (tls://) nor on this machine: anyone who reaches this scheduler can run "
            "code on its workers, and the scene travels unencrypted; see docs/scaling.md for a TLS cluster" % address)


def _probe(address: str):
    """Fail at once, naming ``address``, when it is malformed, its host unknown or its port closed
    (Dask itself would retry for ``CONNECT_TIMEOUT`` seconds)."""
    import socket
    from distributed.comm import parse_address, parse_host_port

    try:
        protocol, location = parse_address(address)
        host, port = parse_host_port(location)
    except (ValueError, TypeError) as exc:
        raise InputError("--dask %s is not a Dask scheduler address (tls://host:8786, host:8786, local, local:N, "
                         "or a scheduler .json file): %s" % (address, exc)) from None
    if protocol not in ("tcp", "tls") or not port:
        return
    try:
        socket.create_connection((host, port), timeout=CONNECT_TIMEOUT).close()
    except OSError as exc:
        raise InputError("cannot reach the Dask scheduler at %s: %s" % (address, exc.strerror or exc)) from None


# ------------------------------------------------------------------------------------------
# Client and cluster
@contextlib.contextmanager
def dask_client(address: str, threads: int | None = None):
    """A ``distributed.Client`` for ``--dask ADDRESS``, closed (with its local cluster) on exit.

    ``local[:N]``: a ``LocalCluster`` of N worker processes with ``threads`` threads each (default:
    the cores shared out), every socket on 127.0.0.1 (its HTTP server too, on a free port).
    Otherwise the scheduler at ``address`` (or in the scheduler file ``address``); ``threads``
    must then be None (workers have their own: ``dask worker --nthreads``).  Raises
    :class:`~lpy_light.errors.InputError` naming the address when it cannot be reached.
    """
    distributed = _require_distributed()
    for name in ("distributed", "distributed.client", "distributed.scheduler", "distributed.nanny",
                 "distributed.worker", "tornado"):
        # Dask's own news (workers starting, connections) at INFO would pass for lpy-light's warnings
        logging.getLogger(name).setLevel(logging.WARNING)
    n = local_workers(address)
    if n is not None:
        from .simulate import default_threads
        per_worker = threads or max(1, default_threads() // n)
        # the workers ignore Ctrl-C (SIGINT is sent to the whole terminal's process group): the run
        # decides what an interrupt does -- finish the chunks in flight, then cancel the others
        previous = signal.getsignal(signal.SIGINT) if threading.current_thread() is threading.main_thread() else None
        if previous is not None:
            signal.signal(signal.SIGINT, signal.SIG_IGN)
        try:
            cluster = distributed.LocalCluster(n_workers=n, threads_per_worker=per_worker, processes=True,
                                               host="127.0.0.1", dashboard_address="127.0.0.1:0",
                                               silence_logs=logging.ERROR)
        finally:
            if previous is not None:
                signal.signal(signal.SIGINT, previous)
        try:
            with distributed.Client(cluster) as client:
                client.lpy_address = "local:%d" % n
                yield client
        finally:
            cluster.close()
        return
    if threads is not None:
        raise InputError("--threads is for local runs and --dask local:N; a cluster's workers have their own "
                         "threads (dask worker --nthreads)")
    kwargs = {}
    label = address
    if address.endswith(".json"):
        waited = time.monotonic() + CONNECT_TIMEOUT
        while not Path(address).is_file() and time.monotonic() < waited:   # a scheduler just started
            time.sleep(0.2)
        if not Path(address).is_file():
            raise InputError("Dask scheduler file not found (waited %g s for it)" % CONNECT_TIMEOUT, address)
        kwargs["scheduler_file"] = address
        try:
            import json
            label = json.loads(Path(address).read_text())["address"]
        except (OSError, ValueError, KeyError, TypeError):
            raise InputError("not a Dask scheduler file (a JSON object with an 'address')", address) from None
    else:
        kwargs["address"] = address
    _probe(label)
    warning = insecure_warning(label)
    if warning:
        log.warning("%s", warning)
    try:
        client = distributed.Client(timeout=CONNECT_TIMEOUT, **kwargs)
    except Exception as exc:        # OSError, TimeoutError, ValueError (a malformed address), TLS errors
        reason = " ".join(str(exc).split()) or type(exc).__name__
        raise InputError("cannot reach the Dask scheduler at %s: %s%s"
                         % (label, reason, " (a tls:// scheduler needs Dask's TLS settings: docs/scaling.md)"
                            if label.startswith("tls://") else "")) from None
    with client:
        client.lpy_address = label
        yield client


# ------------------------------------------------------------------------------------------
# Worker side: the scene kept per content digest
_RECIPES: OrderedDict = OrderedDict()     # digest -> pickled KernelScene (SceneOnWorkers.setup)
_SCENES: OrderedDict = OrderedDict()      # digest -> KernelScene built on this worker
BUILDS: list = []                         # (digest, seconds) of each scene built here (benchmarks)
_LOCK = threading.Lock()


def _keep_latest(table: OrderedDict):
    while len(table) > KEEP_SCENES:
        table.popitem(last=False)


class SceneOnWorkers(_WorkerPlugin):
    """A worker plugin carrying one pickled :class:`~lpy_light.estimators.kernel_scene.KernelScene` (``state``) to every
    worker, now and joining later, filed under ``digest``; built at a worker's first chunk."""

    def __init__(self, digest: str, state: bytes):
        self.digest, self.state = digest, state

    def setup(self, worker=None):
        with _LOCK:
            _RECIPES[self.digest] = self.state
            _RECIPES.move_to_end(self.digest)
            _keep_latest(_RECIPES)

    def teardown(self, worker=None):
        pass            # the recipe stays with its built scene, among the latest KEEP_SCENES


def worker_scene(digest: str):
    """The KernelScene of ``digest`` on this worker, built once (from its plugin's recipe) and kept."""
    with _LOCK:
        kscene = _SCENES.get(digest)
        if kscene is None:
            state = _RECIPES.get(digest)
            if state is None:
                raise LpyLightError("scene %s is not on this worker (its plugin did not reach it)" % digest)
            start = time.perf_counter()
            kscene = pickle.loads(state)         # KernelScene.__setstate__ builds the Embree scene
            BUILDS.append((digest, time.perf_counter() - start))
            _SCENES[digest] = kscene
        _SCENES.move_to_end(digest)
        _keep_latest(_SCENES)
    return kscene


def trace_chunks(digest: str, seed: int, chunks) -> list:
    """A task: each chunk ``(first, count)`` of the scene ``digest`` traced alone -> [kscene.trace's tallies]
    (summed by the client one chunk at a time, in chunk order, as a local run sums them)."""
    kscene = worker_scene(digest)
    return [kscene.trace(seed, first, count) for first, count in chunks]


def worker_fingerprint() -> str:
    """This worker's arithmetic fingerprint (``client.run(cluster.worker_fingerprint)``): workers that share it
    give a chunk the same bits (:mod:`lpy_light.kernel.fingerprint`)."""
    from ..kernel.fingerprint import arithmetic_fingerprint

    return arithmetic_fingerprint()


def mixed_machines_note(fingerprints: dict) -> str | None:
    """One line where the workers (address -> fingerprint) are of more than one kind of arithmetic, else None."""
    kinds = sorted(set(fingerprints.values()))
    if len(kinds) < 2:
        return None
    return ("the Dask workers are of %d kinds of machine (arithmetic fingerprints %s): this run's numbers are a "
            "one-machine run's in their statistics, not to the last bit (docs/physics.md, 'What is reproducible')"
            % (len(kinds), ", ".join(kinds)))


def build_seconds() -> list:
    """(digest, seconds) of each scene build on this worker (``client.run(cluster.build_seconds)``)."""
    return list(BUILDS)


# ------------------------------------------------------------------------------------------
class DaskChunks:
    """:func:`lpy_light.run.simulate.run`'s executor on a Dask cluster (see
    :class:`lpy_light.run.simulate.LocalThreads`).

    ``client``: a ``distributed.Client`` (:func:`dask_client`).  Its ``threads`` (the workers'
    threads together, at ``open``) is how many tasks run at once; :func:`simulate.run` keeps twice
    that many submitted and sums their chunks one by one in chunk order.

    ``chunks_per_task``: consecutive chunks in one task, each traced and returned alone (so the
    numbers do not depend on it).  Default: as many as leave every thread :data:`TASKS_PER_THREAD`
    tasks, at most :data:`MAX_CHUNKS_PER_TASK` -- fewer, longer tasks keep the scheduler's cost
    per task (~1 ms) small beside the tracing (docs/scaling.md).
    """

    def __init__(self, client, chunks_per_task: int | None = None):
        self.client = client
        self.fixed_chunks_per_task = chunks_per_task
        self.chunks_per_task = chunks_per_task or 1
        self.address = getattr(client, "lpy_address", None) or client.scheduler.address
        self.threads = max(1, self._threads())
        self.digest = self._plugin = None
        self.fingerprints = {}

    def _threads(self) -> int:
        workers = self.client.scheduler_info(n_workers=-1)["workers"]
        self.workers = len(workers)
        return sum(w.get("nthreads", 1) for w in workers.values())

    def open(self, kscene, n_chunks: int, note=None) -> int:
        kscene.records(note)       # what the records need a pilot for (a plant's mean pick share) travels with it
        state = pickle.dumps(kscene, protocol=pickle.HIGHEST_PROTOCOL)
        self.digest = hashlib.sha256(state).hexdigest()[:24]
        self._plugin = "lpy-light-scene-%s-%s" % (self.digest, uuid.uuid4().hex[:8])
        self.client.register_plugin(SceneOnWorkers(self.digest, state), name=self._plugin)
        threads = self._threads()
        if not threads:
            log.warning("the Dask scheduler at %s has no workers yet: the chunks wait for them", self.address)
        else:
            self._check_machines()
        self.threads = max(1, threads)
        self.chunks_per_task = self.fixed_chunks_per_task or \
            max(1, min(MAX_CHUNKS_PER_TASK, n_chunks // (TASKS_PER_THREAD * self.threads)))
        return self.threads

    def _check_machines(self):
        """Ask each worker its arithmetic fingerprint; say once where they differ (the numbers then depend on
        which worker traced which chunk, to the last bit only)."""
        try:
            self.fingerprints = self.client.run(worker_fingerprint)
        except Exception as e:          # a worker that cannot answer does not stop the run
            log.debug("workers' fingerprints not known: %s", e)
            return
        note = mixed_machines_note(self.fingerprints)
        if note:
            log.warning(note)

    def submit(self, seed: int, chunks):
        # the key names the computation (scene, seed, photons): the same key is the same tallies
        first, last = chunks[0][0], chunks[-1][0] + chunks[-1][1]
        return self.client.submit(trace_chunks, self.digest, seed, list(chunks),
                                  key="lpy-light-chunks-%s-%d-%d-%d" % (self.digest, seed, first, last))

    def close(self):
        if self._plugin is not None:
            with contextlib.suppress(Exception):       # a cluster already gone has nothing to unregister
                self.client.unregister_worker_plugin(self._plugin)
            self._plugin = None

    def describe(self) -> dict:
        return {"dask": {"scheduler": self.address, "workers": self.workers, "threads": self.threads,
                         "chunks_per_task": self.chunks_per_task, "scene": self.digest,
                         "fingerprints": sorted(set(self.fingerprints.values()))}}
