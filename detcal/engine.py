"""Where the tasks of a sweep or a multi-log calibration run: in this process, or on Dask workers.

Three engines, one interface (:meth:`Engine.map_unordered`: every task's
result, or its error, as it completes):

* ``--workers 0``: this process, one task after another (:class:`InProcess`);
* default: a Dask ``LocalCluster`` started for the command and closed after it
  (``--workers N`` processes, default the CPU count, one thread each), bound to
  the loopback interface, with no dashboard;
* ``--scheduler ADDRESS``: an existing Dask cluster. Its workers must run the
  same detcal, numpy, scipy and numba as this process (checked before any
  task: other versions could give other bytes).

What a task carries: the function (by reference: the worker imports detcal),
small arguments (settings, a profile, seeds) and a :class:`LogSource` instead
of the log: the log's absolute path, the reader options and a fingerprint of
its content. The worker reads the log where it lives (the same path on every
node: shared storage) and checks the fingerprint, so a node that sees another
file at that path fails the task with a message naming the log, rather than
computing on other data. Each worker process keeps the last logs it read
(:data:`CACHE_LOGS`), so the runs of one log on one worker read it once.

Dask retries a task whose worker died (``distributed.scheduler.allowed-failures``,
3 by default); a task that still fails comes back as an error naming what it was
(:class:`TaskLost` for a worker that kept dying: killed, or out of memory).
Nothing here decides what to do with a failure: the sweep records it and goes
on, a calibration reports every failed log.
"""

from __future__ import annotations

import contextlib
import dataclasses
import hashlib
import logging
import os
import resource
import signal
import socket
import threading
import time
import uuid
from collections import OrderedDict
from collections.abc import Callable, Iterator, Mapping
from pathlib import Path

import numpy as np

from detectors.sensor_log import SensorLog
from profiles.errors import DataError, DetcalError, UsageError

#: Logs a worker process keeps in memory after reading them (the last ones used).
CACHE_LOGS = 2

#: Packages whose versions must match between this process and the workers (same inputs, same bytes).
_PINNED = ("detcal", "numpy", "scipy", "numba", "pandas", "matplotlib")


class TaskLost(DataError):
    """A task's worker process died every time it ran it (killed, or out of memory)."""


# ---------------------------------------------------------------------------- logs read where they live


def log_fingerprint(log: SensorLog) -> str:
    """sha256 of a log's content: every stream's arrays (dtype, shape, bytes), models and metadata.

    Two reads of the same file with the same options give the same
    fingerprint; a worker compares it with the one the client computed.
    """
    h = hashlib.sha256()
    _feed(h, log)
    return h.hexdigest()


def _feed(h, x) -> None:
    from pydantic import BaseModel

    if x is None:
        h.update(b"N;")
    elif isinstance(x, np.ndarray):
        h.update(f"A{x.dtype.str}{x.shape};".encode())
        h.update(repr(x.tolist()).encode() if x.dtype.hasobject else np.ascontiguousarray(x).tobytes())
    elif dataclasses.is_dataclass(x) and not isinstance(x, type):
        h.update(f"D{type(x).__name__};".encode())
        for f in dataclasses.fields(x):
            h.update(f.name.encode() + b"=")
            _feed(h, getattr(x, f.name))
    elif isinstance(x, BaseModel):
        h.update(f"M{type(x).__name__};".encode() + x.model_dump_json().encode())
    elif isinstance(x, Mapping):
        h.update(b"{")
        for k in sorted(x, key=str):
            h.update(str(k).encode() + b":")
            _feed(h, x[k])
        h.update(b"}")
    elif isinstance(x, list | tuple):
        h.update(b"[")
        for v in x:
            _feed(h, v)
        h.update(b"]")
    else:
        h.update(f"{type(x).__name__}:{x!r};".encode())


@dataclasses.dataclass(frozen=True)
class LogSource:
    """How a worker gets a log: read ``path`` with the reader options, check the content's fingerprint.

    ``trim``: drop the records outside the ground truth's time span, as
    ``detcal calibrate`` does (:func:`calib.truth.trim_to_truth`).
    """

    name: str
    path: str  # absolute
    fmt: str | None
    options: tuple[tuple[str, object], ...]  # calib.io.registry.ReadOptions as sorted items
    trim: bool = False
    fingerprint: str = ""

    @classmethod
    def of(cls, log: SensorLog, path: Path, fmt: str | None, options, *, trim: bool = False) -> LogSource:
        """The source of ``log`` (already read here from ``path`` with ``options``, trimmed when ``trim``)."""
        opts = tuple(sorted(options.model_dump().items()))
        src = cls(log.name, str(Path(path).resolve()), fmt, opts, trim, log_fingerprint(log))
        src._keep(log)  # tasks run in this process need not read it again
        return src

    def _keep(self, log: SensorLog) -> None:
        with _CACHE_LOCK:
            _CACHE[self] = log
            _CACHE.move_to_end(self)
            while len(_CACHE) > CACHE_LOGS:
                _CACHE.popitem(last=False)

    def load(self) -> SensorLog:
        """The log, read on this machine (or this process's cache); refuses other content than the client read."""
        with _CACHE_LOCK:
            if self in _CACHE:
                _CACHE.move_to_end(self)
                return _CACHE[self]
        from calib.io.registry import ReadOptions, read_log

        where = socket.gethostname()
        try:
            log = read_log(Path(self.path), self.fmt, ReadOptions(**dict(self.options)))
        except DetcalError as exc:
            raise type(exc)(f"log {self.name!r} read on {where}: {exc} (every worker must see the logs at the same path)") from None
        except OSError as exc:
            raise DataError(f"log {self.name!r}: cannot read {self.path} on {where} ({exc.strerror or exc}); every worker must see the logs at the same path") from None
        if self.trim:
            from calib.truth import trim_to_truth

            log, _ = trim_to_truth(log)
        if self.fingerprint and log_fingerprint(log) != self.fingerprint:
            raise DataError(
                f"log {self.name!r}: {self.path} on {where} holds other content than the client read (another file at the same path?)"
            )
        self._keep(log)
        return log


_CACHE: OrderedDict[LogSource, SensorLog] = OrderedDict()
_CACHE_LOCK = threading.Lock()


def load_log(handle) -> SensorLog:
    """A log itself, or what a :class:`LogSource` reads."""
    return handle.load() if hasattr(handle, "load") else handle


# ---------------------------------------------------------------------------- tasks


def _task(fn: Callable, args: tuple) -> tuple[object, dict]:
    """Run one task; its result and where and how long it ran (wall and CPU seconds, the process's peak memory)."""
    t0, c0 = time.perf_counter(), time.process_time()
    value = fn(*args)
    return value, {
        "host": socket.gethostname(),
        "pid": os.getpid(),
        "wall_s": time.perf_counter() - t0,
        "cpu_s": time.process_time() - c0,
        "max_rss_mb": resource.getrusage(resource.RUSAGE_SELF).ru_maxrss / 1024.0,
    }


def _with_log(fn: Callable, handle, rest: tuple):
    return fn(load_log(handle), *rest)


class Engine:
    """Runs tasks; :meth:`map_unordered` yields ``(index, ok, result or error, stats)`` as each completes."""

    workers = 1
    label = "in this process"

    def map_unordered(self, fn: Callable, args: list[tuple], keys: list[str]) -> Iterator[tuple[int, bool, object, dict]]:
        raise NotImplementedError

    def per_log(self, handles: list, names: list[str], progress=None) -> Callable[[Callable, list[tuple]], list]:
        """A ``per_log`` for :func:`calib.calibrate.calibrate`: ``fn(log_k, *args)`` for every log, each log read
        where its task runs (``handles[k]``); every failure is reported, naming its log, once all have ended."""

        def each(fn: Callable, args: list[tuple]) -> list:
            out: list = [None] * len(args)
            failed: list[tuple[int, BaseException]] = []
            it = self.map_unordered(
                _with_log, [(fn, handles[k], tuple(a[1:])) for k, a in enumerate(args)],
                [f"{fn.__name__}-{k}-{n}" for k, n in enumerate(names)],  # unique: two logs may share a name (a seed, a robot)
            )
            if progress is not None:
                it = progress(it, len(args), f"{fn.__name__.replace('_', ' ')} ({self.label})")
            for k, ok, value, _ in it:
                if ok:
                    out[k] = value
                else:
                    failed.append((k, value))
            if failed:
                failed.sort(key=lambda kv: kv[0])
                code = max(getattr(e, "exit_code", 1) for _, e in failed)
                text = "; ".join(f"log {names[k]!r}: {describe(e)}" for k, e in failed)
                raise (UsageError if code == 2 else DataError)(f"{len(failed)} of {len(args)} logs failed: {text}")
            return out

        return each


def describe(exc: BaseException) -> str:
    """One line for a task's error: a detcal error's own message, else its type and message."""
    if isinstance(exc, DetcalError):
        return str(exc)
    return f"{type(exc).__name__}: {exc}" if str(exc) else type(exc).__name__


class InProcess(Engine):
    """Every task in this process, in order (``--workers 0``: for debugging, and the reference others are compared with)."""

    workers = 0
    label = "in this process"

    def map_unordered(self, fn, args, keys):
        for i, a in enumerate(args):
            try:
                value, stats = _task(fn, a)
            except KeyboardInterrupt:
                raise
            except Exception as exc:  # a failed task is a result: the caller names it and goes on  # noqa: BLE001
                yield i, False, exc, {}
            else:
                yield i, True, value, stats


class DaskEngine(Engine):
    """Tasks on a Dask cluster through ``client``; keys name the tasks in Dask's own logs."""

    def __init__(self, client, label: str) -> None:
        self.client = client
        self.label = label
        self.workers = len(client.nthreads())

    def map_unordered(self, fn, args, keys):
        from distributed import as_completed
        from distributed.scheduler import KilledWorker

        tag = uuid.uuid4().hex[:8]
        futures = [self.client.submit(_task, fn, a, key=f"{k}-{tag}", pure=False) for k, a in zip(keys, args, strict=True)]
        index = {f.key: i for i, f in enumerate(futures)}
        try:
            for fut in as_completed(futures, loop=self.client.loop):
                i = index[fut.key]
                if fut.status == "finished":
                    value, stats = fut.result()
                    yield i, True, value, stats
                else:
                    exc = fut.exception()
                    if isinstance(exc, KilledWorker):
                        exc = TaskLost("its worker process died each time Dask ran it (killed, or out of memory)")
                    yield i, False, exc, {}
                fut.release()
        finally:
            with contextlib.suppress(RuntimeError):  # the client's loop already closed (an interrupt unwound it first)
                self.client.cancel([f for f in futures if not f.done()])


# ---------------------------------------------------------------------------- opening an engine


def check_options(workers: int | None, scheduler: str | None) -> None:
    """``--workers`` and ``--scheduler`` as they must be, before any work."""
    if workers is not None and workers < 0:
        raise UsageError(f"--workers: expected 0 (this process) or a positive number of worker processes, got {workers}")
    if scheduler is not None and workers is not None:
        raise UsageError("--workers: the cluster at --scheduler has its own workers; give one of the two")
    if scheduler is not None and not scheduler.strip():
        raise UsageError("--scheduler: expected a Dask scheduler address such as tcp://10.0.0.5:8786")
    if scheduler is not None:
        _probe(scheduler)


def versions() -> dict[str, str]:
    """The versions of the packages whose results must agree (and Python's)."""
    import platform
    from importlib.metadata import PackageNotFoundError, version

    out = {"python": platform.python_version()}
    for p in _PINNED:
        try:
            out[p] = version(p)
        except PackageNotFoundError:
            out[p] = "missing"
    return out


@contextlib.contextmanager
def _quiet_dask(level: int = logging.CRITICAL) -> Iterator[None]:
    """Dask's own log lines (workers restarting, slow event loops on a loaded machine) stay out of the command's output."""
    loggers = [logging.getLogger(n) for n in ("distributed", "tornado", "asyncio")]
    saved = [lg.level for lg in loggers]
    for lg in loggers:
        lg.setLevel(level)
    try:
        yield
    finally:
        for lg, lv in zip(loggers, saved, strict=True):
            lg.setLevel(lv)


#: Dask settings of the local cluster: a worker takes its next task when it finishes one (runs last seconds:
#: nothing to gain from queueing on workers, and a lost worker loses one task); patient timeouts for a loaded
#: machine; one BLAS thread per worker process (the workers are the parallelism), and none of Dask's
#: ``MALLOC_TRIM_THRESHOLD_=65536``: it pins glibc's mmap threshold, so every array above 128 kB is mapped and
#: unmapped afresh, and the filter spent more CPU per step on a worker than in one process. The worker's
#: statistical profiler is off: it walks the running task's stack every 10 ms under the GIL (docs/results.md).
#: Workers import what the tasks use as they start (:data:`PRELOAD`).
LOCAL_CONFIG = {
    "distributed.worker.profile.enabled": False,
    "distributed.worker.preload": ["detcal.engine"],
    "distributed.nanny.pre-spawn-environ": {"OMP_NUM_THREADS": 1, "MKL_NUM_THREADS": 1, "OPENBLAS_NUM_THREADS": 1},
    "distributed.scheduler.worker-saturation": 1.0,
    "distributed.comm.timeouts.connect": "60s",
    "distributed.comm.timeouts.tcp": "120s",
    "distributed.diagnostics.nvml": False,
    "distributed.admin.system-monitor.gil.enabled": False,
}


#: What the tasks import, imported by every worker as it starts (:func:`dask_setup`), all workers at once, rather
#: than inside each worker's first task: 1.5-2 s of CPU a process (matplotlib, scipy, detcal's own modules).
PRELOAD = ("detcal.pipelines.sweep", "slam_runtime.run", "detcal.reports.slam_run", "slam_runtime.labels", "calib.calibrate", "matplotlib.pyplot")


def dask_setup(worker=None) -> None:
    """Dask's preload hook (``distributed.worker.preload: [detcal.engine]``, or ``dask worker --preload detcal.engine``):
    import what the tasks use before the worker takes its first task."""
    import importlib

    import matplotlib

    matplotlib.use("Agg")
    for name in PRELOAD:
        importlib.import_module(name)


@contextlib.contextmanager
def _sigint_held() -> Iterator[None]:
    """SIGINT ignored while a local cluster starts its worker processes: they inherit the disposition and ignore a
    Ctrl-C for life, which then reaches this process alone (it closes them in order) instead of printing each one's
    traceback, and a cluster is never left half-started for Dask's exit hook. A Ctrl-C in those few seconds is lost;
    the next one stops the command. The main thread only (signal handlers can be set nowhere else)."""
    if threading.current_thread() is not threading.main_thread():
        yield
        return
    old = signal.signal(signal.SIGINT, signal.SIG_IGN)
    try:
        yield
    finally:
        signal.signal(signal.SIGINT, old)


def local_cluster(n: int):
    """A Dask ``LocalCluster`` of ``n`` worker processes of one thread each, on the loopback interface only.

    Call it inside ``dask.config.set(LOCAL_CONFIG)``. No dashboard; the
    scheduler's HTTP endpoints (health, metrics), which Dask always serves,
    listen on a free loopback port rather than on 8787, which another cluster
    on the machine may hold.
    """
    from distributed import LocalCluster

    return LocalCluster(
        n_workers=n,
        threads_per_worker=1,
        processes=True,
        host="127.0.0.1",
        dashboard_address=None,
        scheduler_kwargs={"dashboard": False, "dashboard_address": "127.0.0.1:0"},
        silence_logs=logging.CRITICAL,
    )


@contextlib.contextmanager
def open_engine(workers: int | None, scheduler: str | None, tasks: int) -> Iterator[Engine]:
    """The engine of ``--workers``/``--scheduler`` for ``tasks`` tasks; a local cluster is closed on exit.

    workers: 0 = this process; None = the CPU count; a local cluster never has
    more workers than tasks.
    """
    check_options(workers, scheduler)
    if scheduler is None and workers == 0:
        yield InProcess()
        return
    import dask
    from distributed import Client

    if scheduler is not None:
        with _quiet_dask():
            try:
                client = Client(scheduler, set_as_default=False)
            except (OSError, TimeoutError, ValueError, TypeError) as exc:
                raise UsageError(f"--scheduler {scheduler}: no Dask scheduler answered ({' '.join(str(exc).split()) or type(exc).__name__})") from None
            with client:
                _check_workers(client, scheduler)
                yield DaskEngine(client, f"on the cluster at {scheduler}")
        return
    n = max(1, min(workers or os.cpu_count() or 1, tasks))
    with _quiet_dask(), dask.config.set(LOCAL_CONFIG):
        cluster = None
        try:
            with _sigint_held():
                cluster = local_cluster(n)
            with Client(cluster, set_as_default=False) as client:
                yield DaskEngine(client, f"on {n} local worker{'s' if n > 1 else ''}")
        finally:
            if cluster is not None:
                cluster.close()


def _probe(scheduler: str, timeout: float = 5.0) -> None:
    """Refuse a TCP scheduler address that is malformed, that nothing listens at, or whose listener does not answer as
    a Dask scheduler (a dashboard's port, say), before a Client is made: a Client that fails to connect is closed when
    it is collected, which waits 60 s and prints a traceback at exit."""
    import asyncio

    from distributed.comm import parse_address, parse_host_port
    from distributed.core import rpc

    try:
        scheme, location = parse_address(scheduler)
        if scheme != "tcp":  # http:// (a dashboard's address), tls://, ucx://: a Client would wait out its timeout
            raise UsageError(
                f"--scheduler {scheduler}: detcal reaches a Dask scheduler over tcp:// (e.g. tcp://10.0.0.5:8786), not {scheme}://"
                + (" (an http:// address is the dashboard's; the scheduler's is printed as tcp://...)" if scheme in ("http", "https") else "")
            )
        host, port = parse_host_port(location)
    except (ValueError, TypeError) as exc:
        raise UsageError(f"--scheduler {scheduler}: not a scheduler address ({' '.join(str(exc).split())}; e.g. tcp://10.0.0.5:8786)") from None
    try:
        socket.create_connection((host, port), timeout=timeout).close()
    except OSError as exc:
        raise UsageError(f"--scheduler {scheduler}: no Dask scheduler answered ({exc.strerror or type(exc).__name__})") from None

    async def identity() -> dict:
        r = rpc(scheduler, timeout=timeout)
        try:
            return await asyncio.wait_for(r.identity(), timeout)
        finally:
            await r.close_rpc()

    try:
        with _quiet_dask():
            who = asyncio.run(identity())
    except (OSError, TimeoutError, ValueError, TypeError) as exc:
        who = {"error": " ".join(str(exc).split()) or type(exc).__name__}
    if not isinstance(who, dict) or who.get("type") != "Scheduler":
        why = who.get("error") if isinstance(who, dict) and "error" in who else f"it answered as {who.get('type') if isinstance(who, dict) else who!r}"
        raise UsageError(f"--scheduler {scheduler}: something listens there but it is not a Dask scheduler ({why})")


def _check_workers(client, scheduler: str) -> None:
    """Refuse a cluster with no workers, or whose workers run other versions than this process."""
    info = client.nthreads()
    if not info:
        raise UsageError(f"--scheduler {scheduler}: the cluster has no workers")
    ours = versions()
    try:
        theirs = client.run(versions)
    except Exception as exc:  # noqa: BLE001  (a worker without detcal cannot even unpickle the check)
        raise UsageError(f"--scheduler {scheduler}: a worker could not run detcal ({describe(exc)}); install this detcal on every worker") from None
    for addr, v in sorted(theirs.items()):
        diff = [f"{k} {v.get(k)} (here {ours[k]})" for k in ours if v.get(k) != ours[k]]
        if diff:
            raise UsageError(f"--scheduler {scheduler}: worker {addr} runs {', '.join(diff)}; results would not be the same bytes")
