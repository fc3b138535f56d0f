"""Where the cases of a sweep run: in this process, on a local process pool, or on a ``dask.distributed`` cluster.

An :class:`Executor` runs one pure function over many payloads (plain, picklable values keyed by a string id) and
yields an :class:`Outcome` per payload *as it finishes*, so the caller can store each result atomically the moment
it arrives: a campaign killed half-way keeps everything that finished, whichever executor ran it.

* ``serial`` (:class:`SerialExecutor`): one payload after the other in this process.
* ``local`` (:class:`LocalPoolExecutor`): spawned worker processes of a :class:`concurrent.futures.ProcessPoolExecutor`.
* ``dask`` (:class:`DaskExecutor`): one task per payload on a ``dask.distributed`` cluster — a ``LocalCluster`` of
  single-threaded worker processes, or any running scheduler given by its address. ``dask[distributed]`` is the
  optional ``cluster`` extra (``pip install -e ".[cluster]"``).

Failures, the same on every executor: a function that raises gives a failed outcome with its error text and
traceback (never retried: a deterministic error would only raise again); a payload whose worker process died is
run again on a fresh worker, at most ``retries`` more times, then given up as failed. Only the worker-death retry
depends on the executor: the local pool is rebuilt after a death (the cases it was running at that moment each
count one attempt); on dask the scheduler reschedules the task itself (its ``allowed_failures``, set to
``retries`` on the LocalCluster; a running scheduler keeps its own ``distributed.scheduler.allowed-failures``).
"""

from __future__ import annotations

import concurrent.futures as cf
import multiprocessing
import signal
import traceback
import uuid
from abc import ABC, abstractmethod
from collections.abc import Callable, Iterator, Mapping
from concurrent.futures.process import BrokenProcessPool
from dataclasses import dataclass
from typing import Any

from tqdm.auto import tqdm

from lightcurve_gp.config.load import ConfigError

__all__ = [
    "CLUSTER_EXTRA",
    "EXECUTORS",
    "DaskExecutor",
    "Executor",
    "ExecutorError",
    "LocalPoolExecutor",
    "Outcome",
    "SerialExecutor",
    "import_distributed",
    "make_executor",
]

#: the executor names of ``--executor``
EXECUTORS = ("local", "dask")
#: how to install what the dask executor needs
CLUSTER_EXTRA = 'pip install -e ".[cluster]"'
#: seconds to wait for a running scheduler to answer
CONNECT_TIMEOUT_S = 20


class ExecutorError(ConfigError):
    """An executor cannot be set up: its extra is not installed, or its scheduler cannot be reached."""


@dataclass(frozen=True)
class Outcome:
    """What became of one payload: the function's return value, or the error that stopped it.

    Attributes:
        key: the payload's id.
        value: the function's return value (``None`` when failed).
        error: ``"ExceptionType: message"`` when the function raised or its worker died too often, else ``None``.
        traceback: the formatted traceback of a raised error (empty otherwise).
    """

    key: str
    value: Any = None
    error: str | None = None
    traceback: str = ""

    @property
    def ok(self) -> bool:
        return self.error is None


def _call(fn: Callable[[Any], Any], key: str, payload: Any) -> Outcome:
    """``fn(payload)`` as an :class:`Outcome`; runs on the worker, so an ``Exception`` never reaches the executor."""
    try:
        return Outcome(key, value=fn(payload))
    except Exception as exc:  # noqa: BLE001 - any error of one payload is its outcome
        return Outcome(key, error=f"{type(exc).__name__}: {exc}", traceback=traceback.format_exc())


def _died(key: str, exc: BaseException, attempts: int) -> Outcome:
    return Outcome(key, error=f"worker died {attempts} time(s) while running it ({type(exc).__name__}: {exc})")


class Executor(ABC):
    """Runs ``fn`` over payloads and yields outcomes in completion order; a context manager that frees its workers."""

    #: short name for messages and progress bars
    name: str = "executor"

    @property
    @abstractmethod
    def slots(self) -> int:
        """How many payloads can run at the same time now (worker processes × threads)."""

    @abstractmethod
    def map_unordered(self, fn: Callable[[Any], Any], payloads: Mapping[str, Any]) -> Iterator[Outcome]:
        """Run ``fn(payload)`` for every item of ``payloads`` (``{key: payload}``); yield one outcome per key as it
        finishes. Closing the iterator early (an exception in the consumer, Ctrl-C) cancels what has not run."""

    def close(self) -> None:
        """Free the workers (idempotent)."""

    def __enter__(self):
        return self

    def __exit__(self, *exc_info: object) -> None:
        self.close()

    def run(self, fn: Callable[[Any], Any], payloads: Mapping[str, Any], *, desc: str = "cases",
            total: int | None = None, initial: int = 0, progress: bool | None = None) -> Iterator[Outcome]:
        """:meth:`map_unordered` behind a progress bar of the whole campaign.

        The bar counts ``initial`` items already done before this run (out of ``total``, default
        ``initial + len(payloads)``) and shows done / failed / running in its postfix.
        """
        total = initial + len(payloads) if total is None else total
        bar = tqdm(total=total, initial=initial, desc=desc, unit=desc.rstrip("s") or "item",
                   disable=None if progress is None else not progress)
        done = failed = 0
        try:
            if not bar.disable:
                bar.set_postfix(done=initial, failed=0, running=min(len(payloads), self.slots))
            for outcome in self.map_unordered(fn, payloads):
                done += outcome.ok
                failed += not outcome.ok
                if progress:
                    running = min(len(payloads) - done - failed, self.slots)
                    bar.set_postfix(done=initial + done, failed=failed, running=running, refresh=False)
                bar.update()
                yield outcome
        finally:
            bar.close()


class SerialExecutor(Executor):
    """Every payload in this process, one after the other (no pickling: any callable works)."""

    name = "serial"

    @property
    def slots(self) -> int:
        return 1

    def map_unordered(self, fn: Callable[[Any], Any], payloads: Mapping[str, Any]) -> Iterator[Outcome]:
        for key, payload in payloads.items():
            yield _call(fn, key, payload)


class LocalPoolExecutor(Executor):
    """A pool of ``workers`` spawned processes on this machine (``fn`` and payloads must pickle).

    A worker that dies breaks the whole pool: the pool is rebuilt and every payload that had not finished is
    submitted again, each charged one attempt; a payload is given up as failed after ``1 + retries`` attempts.
    """

    name = "local"

    def __init__(self, workers: int, *, retries: int = 2) -> None:
        if workers < 1:
            raise ExecutorError(f"workers: {workers} must be >= 1")
        if retries < 0:
            raise ExecutorError(f"retries: {retries} must be >= 0")
        self.workers, self.retries = workers, retries
        self._pool: cf.ProcessPoolExecutor | None = None

    @property
    def slots(self) -> int:
        return self.workers

    def _fresh_pool(self) -> cf.ProcessPoolExecutor:
        if self._pool is not None:
            self._pool.shutdown(wait=True, cancel_futures=True)
        self._pool = cf.ProcessPoolExecutor(max_workers=self.workers, mp_context=multiprocessing.get_context("spawn"))
        return self._pool

    def map_unordered(self, fn: Callable[[Any], Any], payloads: Mapping[str, Any]) -> Iterator[Outcome]:
        remaining = dict(payloads)
        attempts = dict.fromkeys(payloads, 0)
        pool = self._pool or self._fresh_pool()
        while remaining:
            futures = {pool.submit(_call, fn, key, payload): key for key, payload in remaining.items()}
            try:
                for fut in cf.as_completed(futures):
                    key = futures[fut]
                    try:
                        outcome = fut.result()
                    except BrokenProcessPool as exc:
                        attempts[key] += 1
                        if attempts[key] <= self.retries:
                            continue  # submitted again to the rebuilt pool
                        outcome = _died(key, exc, attempts[key])
                    except Exception as exc:  # noqa: BLE001 - the payload or the result does not pickle
                        outcome = Outcome(key, error=f"{type(exc).__name__}: {exc}")
                    del remaining[key]
                    yield outcome
            finally:
                for fut in futures:
                    fut.cancel()
            if remaining:
                pool = self._fresh_pool()

    def close(self) -> None:
        if self._pool is not None:
            self._pool.shutdown(wait=True, cancel_futures=True)
            self._pool = None


def import_distributed():
    """The ``distributed`` module, or :class:`ExecutorError` naming the extra that installs it."""
    try:
        import distributed
    except ImportError:
        raise ExecutorError(f"--executor dask needs dask.distributed, which is not installed: install the cluster "
                            f"extra with {CLUSTER_EXTRA}") from None
    return distributed


def _interrupt_ignorer(distributed):
    """A worker plugin that makes each LocalCluster worker ignore SIGINT: a Ctrl-C in the terminal reaches the
    whole process group, and the client, not each worker, shuts the cluster down (restarted workers too)."""

    class IgnoreInterrupt(distributed.WorkerPlugin):
        def setup(self, worker) -> None:
            signal.signal(signal.SIGINT, signal.SIG_IGN)

    return IgnoreInterrupt()


class DaskExecutor(Executor):
    """One ``dask.distributed`` task per payload, on a LocalCluster or on a running scheduler.

    Args:
        workers: worker processes of the LocalCluster (one thread each); ignored with ``address``.
        address: a running scheduler (``tcp://host:8786``); ``None`` starts a LocalCluster.
        retries: times a task whose worker died is run again on the LocalCluster (the scheduler's
            ``allowed_failures``); a running scheduler applies its own setting.

    Raises:
        ExecutorError: dask.distributed is not installed, or the scheduler does not answer.
    """

    name = "dask"

    def __init__(self, *, workers: int = 2, address: str | None = None, retries: int = 2) -> None:
        distributed = import_distributed()
        if retries < 0:
            raise ExecutorError(f"retries: {retries} must be >= 0")
        self._cluster = None
        if address is None:
            if workers < 1:
                raise ExecutorError(f"workers: {workers} must be >= 1")
            self._cluster = distributed.LocalCluster(n_workers=workers, threads_per_worker=1, processes=True,
                                                     dashboard_address=":0",
                                                     scheduler_kwargs={"allowed_failures": retries})
            self._client = distributed.Client(self._cluster)
            self._client.register_plugin(_interrupt_ignorer(distributed), name="lightcurve-gp-ignore-sigint")
        else:
            try:
                self._client = distributed.Client(address, timeout=CONNECT_TIMEOUT_S)
            except (OSError, TimeoutError, ValueError) as exc:
                raise ExecutorError(f"--scheduler {address}: cannot connect to a dask scheduler ({exc})") from None
        self._as_completed, self._killed = distributed.as_completed, distributed.KilledWorker

    @property
    def client(self):
        """The ``distributed.Client`` (for its dashboard link, or to restart workers)."""
        return self._client

    @property
    def slots(self) -> int:
        return max(1, sum(self._client.nthreads().values()))

    def map_unordered(self, fn: Callable[[Any], Any], payloads: Mapping[str, Any]) -> Iterator[Outcome]:
        token = uuid.uuid4().hex[:8]
        prefix = getattr(fn, "__name__", "task")
        futures = {self._client.submit(_call, fn, key, payload, key=f"{prefix}-{key}-{token}"): key
                   for key, payload in payloads.items()}
        try:
            for fut in self._as_completed(futures):
                key = futures[fut]
                try:
                    outcome = fut.result()
                except self._killed as exc:
                    outcome = _died(key, exc, exc.allowed_failures + 1)
                except Exception as exc:  # noqa: BLE001 - it does not pickle, or was cancelled
                    outcome = Outcome(key, error=f"{type(exc).__name__}: {exc}")
                fut.release()
                yield outcome
        finally:
            pending = [fut for fut in futures if not fut.done()]
            if pending and self._client.status == "running":
                self._client.cancel(pending)

    def close(self) -> None:
        self._client.close()
        if self._cluster is not None:
            self._cluster.close()


def make_executor(kind: str, *, workers: int = 1, address: str | None = None, retries: int = 2) -> Executor:
    """The executor ``kind`` (one of :data:`EXECUTORS`): ``local`` with one worker runs in this process.

    Raises:
        ExecutorError: an unknown kind, an address without ``dask``, or what :class:`DaskExecutor` raises.
    """
    if kind not in EXECUTORS:
        raise ExecutorError(f"--executor: unknown executor {kind!r}; choose from {', '.join(EXECUTORS)}")
    if kind == "dask":
        return DaskExecutor(workers=workers, address=address, retries=retries)
    if address is not None:
        raise ExecutorError("--scheduler: a scheduler address needs --executor dask")
    return SerialExecutor() if workers == 1 else LocalPoolExecutor(workers, retries=retries)
