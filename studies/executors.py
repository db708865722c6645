"""Where Monte Carlo flights run: one interface, three back ends.

    executor = make_executor("local", workers=2)      # processes on this machine (default)
    executor = make_executor("serial")                # in this process (debugging, profiling)
    executor = make_executor("dask-local", workers=2) # a Dask LocalCluster on loopback
    executor = make_executor("tcp://10.0.0.5:8786")   # an existing Dask scheduler
    for index, result in executor.map(function, tasks):
        ...
    executor.close()

`map` yields (task index, result) in completion order; callers that need a fixed
order sort by index. A flight's result depends only on its task (scenario, seed), never
on which worker ran it or when, so every back end gives the same rows for the same
tasks (checked by tests/test_montecarlo.py). Functions and tasks must be picklable
(module-level functions, plain data); Dask workers must have this package installed.
"""

from __future__ import annotations

import concurrent.futures
import os
import signal
import time
from collections.abc import Callable, Iterable, Iterator
from typing import Any, Protocol

from studies.processes import GRACE_PERIOD, death_signal_supported, set_death_signal


class Executor(Protocol):
    """Runs function(task) for every task; yields (index, result) as each one finishes."""

    name: str

    def map(self, function: Callable[[Any], Any], tasks: Iterable[Any]) -> Iterator[tuple[int, Any]]: ...

    def close(self) -> None: ...


class SerialExecutor:
    """Everything in the calling process, in order."""

    name = "serial"

    def map(self, function: Callable[[Any], Any], tasks: Iterable[Any]) -> Iterator[tuple[int, Any]]:
        for index, task in enumerate(tasks):
            yield index, function(task)

    def close(self) -> None:
        pass


#: s: a kernel warm-up longer than this was a compilation (a load from numba's cache takes about 2 s).
SLOW_COMPILE = 10.0


def compile_kernels(say: Callable[[str], None] | None = None) -> float:
    """Compile the plant's and the estimators' numba kernels in this process (or load them from numba's cache), so
    that the worker or child processes started next load the cache instead of each compiling them: on a fresh
    install that is one to several minutes of one core. Returns the seconds it took; nothing to do without numba
    (plain Python) or when already done in this process. say: called with a line before the wait (only when there
    is one: numba in use, not done yet in this process) and with another after it when it took over
    SLOW_COMPILE s (a compilation, not a load from the cache)."""
    from companion import warmup as estimator_kernels
    from sitl_plant.vehicle import kernels as plant_kernels

    announce = say is not None and estimator_kernels.pending()
    if announce:
        say("loading the compiled kernels (numba); the first run after an install compiles them, which takes "
            "minutes (`companion --precompile` does it ahead of a flight)")
    started = time.perf_counter()
    estimator_kernels.warm_up()
    plant_kernels.warm_up()
    took = time.perf_counter() - started
    if announce and took > SLOW_COMPILE:
        say(f"kernels compiled in {took:.0f} s; later runs load them from numba's cache")
    return took


#: Local worker processes per core at most: flights are CPU-bound, so more only wait, and each one holds its own
#: interpreter, numpy and kernels (a typo such as --workers 10000 would fork ten thousand of them).
WORKERS_PER_CORE = 4


def local_workers(workers: int | None) -> int:
    """The local worker processes to start: `workers`, default one per core; ValueError below 1 or above
    WORKERS_PER_CORE per core of this machine (at least WORKERS_PER_CORE)."""
    cores = os.cpu_count() or 1
    if workers is None:
        return cores
    limit = WORKERS_PER_CORE * cores
    if not 1 <= workers <= limit:
        raise ValueError(f"{workers} local workers: use 1 to {limit} on this machine ({cores} cores, at most "
                         f"{WORKERS_PER_CORE} per core; flights are CPU-bound, so more processes only wait)")
    return workers


def _start_worker(parent: int) -> None:
    """A local worker's first step. The owner decides on Ctrl-C and stop signals (it stops its workers), so a worker
    ignores SIGINT and takes SIGTERM and SIGHUP as the default (end), whatever handlers it inherited through fork;
    on Linux the kernel sends it SIGTERM when the owner dies (studies.processes.set_death_signal), so a killed
    owner leaves no worker behind."""
    signal.signal(signal.SIGINT, signal.SIG_IGN)
    signal.signal(signal.SIGTERM, signal.SIG_DFL)
    signal.signal(signal.SIGHUP, signal.SIG_DFL)
    if death_signal_supported() and set_death_signal(parent) is not None:
        os._exit(1)  # the owner is already gone: nobody would collect this worker's results


class ProcessExecutor:
    """A pool of worker processes on this machine (concurrent.futures). The parent compiles the kernels first
    (`compile_kernels`), so the workers share numba's cache rather than all compiling at once. The pool starts
    when `map` is given its tasks, with no more processes than tasks. Workers never outlive the owner (see
    `_start_worker`), and `close` with flights still unfinished (an interrupt) stops them at once instead of
    waiting for the flights they had taken."""

    def __init__(self, workers: int | None = None, say: Callable[[str], None] | None = None) -> None:
        self.workers = local_workers(workers)
        compile_kernels(say)
        self.name = f"local processes ({self.workers})"
        self._pool: concurrent.futures.ProcessPoolExecutor | None = None
        self._futures: dict = {}

    def map(self, function: Callable[[Any], Any], tasks: Iterable[Any]) -> Iterator[tuple[int, Any]]:
        tasks = list(tasks)
        if self._pool is None:
            # With the fork start method the pool forks all its processes at the first submit.
            self.workers = max(1, min(self.workers, len(tasks)))
            self.name = f"local processes ({self.workers})"
            self._pool = concurrent.futures.ProcessPoolExecutor(max_workers=self.workers, initializer=_start_worker,
                                                                initargs=(os.getpid(),))
        futures = {self._pool.submit(function, task): index for index, task in enumerate(tasks)}
        self._futures.update(futures)
        try:
            for future in concurrent.futures.as_completed(futures):
                yield futures[future], future.result()
        finally:
            for future in futures:
                future.cancel()

    def close(self) -> None:
        """Wait for the workers to end when every flight is done; with flights unfinished (the caller stopped
        early: an interrupt, an error), stop the workers now (SIGTERM, then SIGKILL after a grace period)."""
        pool, self._pool = self._pool, None
        if pool is None:
            return
        if all(future.done() for future in self._futures):
            pool.shutdown(wait=True)
            return
        processes = list((getattr(pool, "_processes", None) or {}).values())  # concurrent.futures' own table
        pool.shutdown(wait=False, cancel_futures=True)
        for process in processes:
            process.terminate()
        deadline = time.monotonic() + GRACE_PERIOD
        for process in processes:
            process.join(max(0.0, deadline - time.monotonic()))
            if process.is_alive():
                process.kill()
                process.join()


class DaskExecutor:
    """Dask distributed: a scheduler at `address` ("tcp://host:port"), or, with address None,
    a LocalCluster of `workers` single-threaded worker processes bound to loopback (for
    trying a campaign, and for the tests). Needs the optional dependency dask[distributed]."""

    def __init__(self, address: str | None = None, workers: int | None = None,
                 say: Callable[[str], None] | None = None) -> None:
        try:
            from distributed import Client, LocalCluster
        except ImportError:
            raise RuntimeError("the Dask executor needs dask[distributed]: pip install 'bearing-follow[dask]'") from None
        self._cluster = None
        if address is None:
            count = local_workers(workers)
            compile_kernels(say)  # the local workers share this machine's numba cache
            self._cluster = LocalCluster(n_workers=count, threads_per_worker=1, processes=True, host="127.0.0.1",
                                         scheduler_port=0, dashboard_address=None)
            self._client = Client(self._cluster)
            self.name = f"dask local cluster ({count} workers, {self._cluster.scheduler_address})"
        else:
            self._client = Client(address, timeout=30)
            self.name = f"dask scheduler {address}"

    def map(self, function: Callable[[Any], Any], tasks: Iterable[Any]) -> Iterator[tuple[int, Any]]:
        from distributed import as_completed

        tasks = list(tasks)
        futures = self._client.map(function, tasks, pure=False)
        indices = {future.key: index for index, future in enumerate(futures)}
        try:
            for future in as_completed(futures):
                yield indices[future.key], future.result()
        finally:
            self._client.cancel(futures)

    def close(self) -> None:
        self._client.close()
        if self._cluster is not None:
            self._cluster.close()


#: The most flights one study command takes: the parent holds every task (a validated scenario, ~25 kB) and every
#: flight's series (~34 kB for 60 s) until it writes them, so 100,000 flights are already some 6 GB of memory.
MAX_FLIGHTS = 100_000


def check_flight_count(count: int, what: str) -> None:
    """ValueError when `count` flights (`what` says how they were asked for) exceed MAX_FLIGHTS."""
    if count > MAX_FLIGHTS:
        raise ValueError(f"{what} make {count:,} flights; at most {MAX_FLIGHTS:,} in one run (the parent holds every "
                         f"flight's task and series in memory until the end)")


def check_executor(spec: str, workers: int | None) -> None:
    """What make_executor(spec, workers) would refuse, refused now (ValueError), before a command makes its run
    folder: an unknown executor, or local workers outside local_workers' bounds."""
    if spec not in ("local", "serial", "dask-local") and "://" not in spec:
        raise ValueError(f"unknown executor {spec!r}: use 'local', 'serial', 'dask-local' or a scheduler address tcp://host:port")
    if spec in ("local", "dask-local"):
        local_workers(workers)


def make_executor(spec: str = "local", workers: int | None = None, say: Callable[[str], None] | None = None) -> Executor:
    """'local' (processes, default), 'serial', 'dask-local', or a Dask scheduler address (tcp://...). say: handed to
    `compile_kernels` by the executors that compile in this process before starting their workers."""
    check_executor(spec, workers)
    if spec == "local":
        return ProcessExecutor(workers, say)
    if spec == "serial":
        return SerialExecutor()
    if spec == "dask-local":
        return DaskExecutor(None, workers, say)
    return DaskExecutor(spec, workers, say)
