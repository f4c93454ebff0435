"""Threads for the work that releases the GIL (Embree's ray queries, scipy's k-d tree
queries, numpy on large arrays): how many a process may use, and one shared pool.

``compute_threads()`` is ``OMP_NUM_THREADS`` where set (what a scheduler such as Ray
gives each worker), else the cores this process may run on. Work split over them must
give the same answers as in one piece (each ray, each query point, its own answer).
"""

from __future__ import annotations

import contextlib
import os
import threading

_POOL = None
_POOL_LOCK = threading.Lock()
_PREFIX = "zcomp-pool"


def compute_threads() -> int:
    """Threads a large query splits over (module docstring)."""
    env = os.environ.get("OMP_NUM_THREADS", "").strip()
    if env.isdigit() and int(env) > 0:
        return int(env)
    try:
        return max(1, len(os.sched_getaffinity(0)))
    except AttributeError:  # not on Linux
        return max(1, os.cpu_count() or 1)


def in_pool() -> bool:
    """This code runs on a thread of ``pool`` (where it must not wait on the pool: it
    does its work on this thread alone)."""
    return threading.current_thread().name.startswith(_PREFIX)


def pool():
    """The process's thread pool, ``compute_threads()`` threads (made once; again if that
    number changes). A task running in it must not wait on another task of it."""
    global _POOL
    n = compute_threads()
    with _POOL_LOCK:
        if _POOL is None or _POOL._max_workers != n:
            from concurrent.futures import ThreadPoolExecutor

            _POOL = ThreadPoolExecutor(max_workers=n, thread_name_prefix=_PREFIX)
        return _POOL


def beside(fn):
    """A future of ``fn()``, run on a second thread while the caller goes on; run at once
    on this thread where the process has one (``compute_threads``)."""
    if compute_threads() > 1 and not in_pool():
        return pool().submit(fn)
    from concurrent.futures import Future

    f = Future()
    try:
        f.set_result(fn())
    except BaseException as e:  # raised where the result is asked for, as from a thread
        f.set_exception(e)
    return f


def map_over(fn, items) -> list:
    """``[fn(x) for x in items]``, in order, the items taken in turn by this thread and
    the pool's (this thread works too, rather than wait on a pool busy with other work:
    ``beside``'s); on this thread alone where the process has one, or where this is a
    pool thread. ``fn`` must not depend on which thread runs it."""
    items = list(items)
    n = min(compute_threads(), len(items))
    if n < 2 or in_pool():
        return [fn(x) for x in items]
    out = [None] * len(items)
    order = iter(range(len(items)))
    lock = threading.Lock()
    failed = []  # (an error or an interrupt on any thread: no item is handed out after it)

    def work():
        while True:
            with lock:
                i = None if failed else next(order, None)
            if i is None:
                return
            try:
                out[i] = fn(items[i])
            except BaseException:
                failed.append(True)
                raise

    helpers = [pool().submit(work) for _ in range(n - 1)]
    try:
        work()
    finally:
        for h in helpers:  # a helper still queued (the pool busy) has nothing left to do
            if not h.cancel():
                h.result()
    return out


@contextlib.contextmanager
def own_threads():
    """A block that splits its own work over ``compute_threads()`` threads (``pool``,
    ``beside``, ``map_over``, the ray queries), with the BLAS libraries (numpy's
    OpenBLAS) held to one thread meanwhile:
    * the light fit's matrices are small (thousands of rows by at most a thousand
      columns), where OpenBLAS's threads, spinning beside ours on the same cores, cost
      more than they give (benchmarks/bench_physical_speed.py, interleaved in one
      process on 2 cores: the estimate's median 0.63 -> 0.52 s with a sun);
    * one BLAS thread rounds the same whatever the machine's core count, so the block's
      results do not depend on it."""
    from threadpoolctl import threadpool_limits

    with threadpool_limits(limits=1, user_api="blas"):
        yield


__all__ = ["compute_threads", "in_pool", "pool", "beside", "map_over", "own_threads"]
