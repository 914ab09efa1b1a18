"""Worker processes for many images: a local pool, or a Dask cluster through joblib.

:func:`ordered_map` runs a function over argument tuples and yields the
results in order: in this process (one job), in a pool of worker processes
that end with their parent (:func:`worker_pool`), or on a Dask cluster
(``scheduler``: a ``distributed.Client`` or a scheduler address such as
``tcp://host:8786``) through joblib's ``dask`` backend. The workers of a
cluster need posevote installed and the files the tasks name; the results
are those of the local pool, whatever runs them.
"""

from __future__ import annotations

import contextlib
import functools
import os
import sys
import threading
from collections import deque
from collections.abc import Callable, Iterable, Iterator
from concurrent.futures import Future, ProcessPoolExecutor, ThreadPoolExecutor
from typing import Any

from threadpoolctl import threadpool_limits


def _init_worker(parent: int) -> None:
    """One thread per worker process for numba and BLAS: the processes fill the cores.

    OpenCV's thread count is set to one in the parent before the workers
    are forked (:func:`ordered_map`): setting it in a forked child whose
    parent had used OpenCV's threads hangs. On Linux the kernel kills the
    worker when its parent dies, however it dies (SIGTERM, SIGKILL).
    """
    import signal

    if sys.platform.startswith("linux"):
        import ctypes

        pr_set_pdeathsig = 1
        ctypes.CDLL(None, use_errno=True).prctl(pr_set_pdeathsig, int(signal.SIGKILL))
    if os.getppid() != parent:   # the parent died before the line above
        os._exit(1)
    # Ctrl-C is the parent's to handle: it stops the workers (:func:`_stop`).
    signal.signal(signal.SIGINT, signal.SIG_IGN)
    os.environ["NUMBA_NUM_THREADS"] = "1"
    threadpool_limits(1)


def worker_pool(jobs: int) -> ProcessPoolExecutor:
    """Worker processes for the test images, each ending with its parent (:func:`_init_worker`)."""
    return ProcessPoolExecutor(max_workers=jobs, initializer=_init_worker,
                               initargs=(os.getpid(),))


def ordered_map(fn: Callable[..., Any], tasks: Iterable[tuple[Any, ...]], *, jobs: int = 1,
                scheduler: Any = None) -> Iterator[Any]:
    """``fn(*task)`` for every task, in order (see the module docstring).

    Raises
    ------
    ImportError
        If a scheduler is given and ``distributed`` is not installed
        (``pip install 'posevote[dask]'``).
    """
    tasks = list(tasks)
    if scheduler is not None:
        yield from _on_dask(fn, tasks, scheduler)
        return
    if jobs <= 1 or len(tasks) < 2:
        for task in tasks:
            yield fn(*task)
        return
    import cv2

    threads = cv2.getNumThreads()
    cv2.setNumThreads(1)   # before the workers fork: set in a forked child it hangs
    pool = worker_pool(jobs)
    finished = False
    try:
        yield from pool.map(fn, *zip(*tasks, strict=True), chunksize=1)
        finished = True
    finally:
        if finished:
            pool.shutdown(wait=True)
        else:
            _stop(pool)
        cv2.setNumThreads(threads)


def _stop(pool: ProcessPoolExecutor) -> None:
    """End a pool at once (an interrupt, an error, a consumer that stopped early): its workers
    are killed, so that nothing waits on the images they were estimating."""
    processes = dict(getattr(pool, "_processes", None) or {})
    pool.shutdown(wait=False, cancel_futures=True)
    processes.update(getattr(pool, "_processes", None) or {})
    for process in processes.values():
        with contextlib.suppress(OSError, ValueError):
            process.kill()
    for process in processes.values():
        with contextlib.suppress(OSError, ValueError, AssertionError):
            process.join(timeout=5)


def _on_dask(fn: Callable[..., Any], tasks: list[tuple[Any, ...]], scheduler: Any
             ) -> Iterator[Any]:
    try:
        from distributed import Client
    except ImportError as exc:
        raise ImportError("a Dask scheduler needs distributed: pip install 'posevote[dask]'"
                          ) from exc
    from joblib import Parallel, delayed, parallel_config

    task_fn = functools.partial(_one_thread, fn)
    own = not isinstance(scheduler, Client)
    client = _connect(scheduler) if own else scheduler
    try:
        with parallel_config(backend="dask", client=client):
            yield from Parallel(n_jobs=-1, return_as="generator")(
                delayed(task_fn)(*task) for task in tasks)
    finally:
        if own:
            client.close()


#: How long a scheduler's address has to answer as a Dask scheduler, seconds.
CONNECT_SECONDS = 30.0


def _connect(address: Any) -> Any:
    """A client of the scheduler at ``address``, or an error within :data:`CONNECT_SECONDS`.

    The address is asked who it is first, in a thread of its own and without
    a client: a server that is not a Dask scheduler may never answer the
    handshake (a web server), or answer nonsense, and a client that failed on
    it hangs a minute when it is collected.
    """
    from distributed import Client
    from distributed.comm import parse_address, parse_host_port

    try:
        scheme, where = parse_address(str(address))
        if scheme not in ("tcp", "tls", "ws", "wss", "inproc", "ucx"):
            raise ValueError(f"unknown protocol {scheme!r}")
        if scheme != "inproc":
            parse_host_port(where)
    except (ValueError, TypeError) as exc:
        raise ValueError(f"cannot use the Dask scheduler {address!r}: {exc} (an address "
                         "such as tcp://host:8786)") from None
    box: dict[str, Any] = {}

    def probe() -> None:
        import asyncio

        from distributed.core import rpc

        async def identity() -> Any:
            remote = rpc(str(address), timeout=CONNECT_SECONDS)
            try:
                return await asyncio.wait_for(remote.identity(), CONNECT_SECONDS)
            finally:
                await remote.close_rpc()

        try:
            box["identity"] = asyncio.run(identity())
        except BaseException as exc:   # handed to the caller's thread
            box["error"] = exc

    thread = threading.Thread(target=probe, daemon=True, name="posevote-dask-probe")
    thread.start()
    thread.join(CONNECT_SECONDS + 5.0)
    found = box.get("identity")
    if isinstance(found, dict) and found.get("type") == "Scheduler":
        return Client(str(address), set_as_default=False, timeout=CONNECT_SECONDS)
    if "error" in box and not isinstance(box["error"], TimeoutError):
        raise ValueError(f"cannot use the Dask scheduler {address!r}: it does not answer as "
                         f"one ({type(box['error']).__name__}: {box['error']})") from None
    if "identity" in box:
        raise ValueError(f"cannot use the Dask scheduler {address!r}: it answers as "
                         f"{found.get('type') if isinstance(found, dict) else found!r}") from None
    raise TimeoutError(f"no Dask scheduler answered at {address!r} within "
                       f"{CONNECT_SECONDS:g} s (is it a Dask scheduler's address?)")


def _one_thread(fn: Callable[..., Any], *args: Any) -> Any:
    """``fn(*args)`` with BLAS on one thread: a cluster's worker fills its core as a local one does."""
    with threadpool_limits(1):
        return fn(*args)


def thread_map(function: Callable[[Any], Any], items: Iterable[Any], n_threads: int,
               ahead: int = 4) -> Iterator[Any]:
    """``map(function, items)`` in ``n_threads`` threads, the results yielded in order.

    At most ``ahead`` results per thread wait to be taken, so that memory
    stays bounded when the consumer is slower than the threads. With one
    thread it is the plain ``map``. An exception is raised where its item's
    result would have been yielded.
    """
    if n_threads <= 1:
        yield from map(function, items)
        return
    with ThreadPoolExecutor(max_workers=n_threads) as pool:
        pending: deque[Future[Any]] = deque()
        try:
            for item in items:
                pending.append(pool.submit(function, item))
                if len(pending) >= ahead * n_threads:
                    yield pending.popleft().result()
            while pending:
                yield pending.popleft().result()
        finally:
            for future in pending:
                future.cancel()
