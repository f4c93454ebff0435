"""The process's threads (zcomp_cli/threads.py): how many, the pool, work beside the
caller, and numpy's BLAS held to one thread while zcomp's own threads work."""

import numpy as np
import pytest

from zcomp_cli import threads


def test_compute_threads_follows_omp_num_threads(monkeypatch):
    monkeypatch.setenv("OMP_NUM_THREADS", "3")
    assert threads.compute_threads() == 3
    monkeypatch.setenv("OMP_NUM_THREADS", "nonsense")
    assert threads.compute_threads() >= 1
    monkeypatch.delenv("OMP_NUM_THREADS")
    assert threads.compute_threads() >= 1


@pytest.mark.parametrize("n", ["1", "2"])
def test_beside_gives_the_result_and_the_error(monkeypatch, n):
    monkeypatch.setenv("OMP_NUM_THREADS", n)
    assert threads.beside(lambda: 6 * 7).result() == 42

    def boom():
        raise ValueError("from the task")

    f = threads.beside(boom)
    with pytest.raises(ValueError, match="from the task"):
        f.result()


def test_one_thread_runs_beside_work_on_the_callers_thread(monkeypatch):
    import threading

    monkeypatch.setenv("OMP_NUM_THREADS", "1")
    assert threads.beside(threading.current_thread).result() is threading.current_thread()
    monkeypatch.setenv("OMP_NUM_THREADS", "2")
    other = threads.beside(threading.current_thread).result()
    assert other is not threading.current_thread() and threads.in_pool() is False
    assert threads.pool().submit(threads.in_pool).result() is True


def test_own_threads_holds_blas_to_one_thread_and_restores_it(monkeypatch):
    from threadpoolctl import threadpool_info

    blas = lambda: [i["num_threads"] for i in threadpool_info() if i["user_api"] == "blas"]  # noqa: E731
    np.ones((4, 4)) @ np.ones((4, 4))  # numpy's BLAS loaded
    before = blas()
    assert before, "no BLAS library found"
    monkeypatch.setenv("OMP_NUM_THREADS", "2")
    with threads.own_threads():
        assert set(blas()) == {1}
    assert blas() == before
    monkeypatch.setenv("OMP_NUM_THREADS", "1")
    with threads.own_threads():  # one thread of zcomp's: BLAS on one too (the same rounding)
        assert set(blas()) == {1}
    assert blas() == before


@pytest.mark.parametrize("n", ["1", "3"])
def test_map_over_keeps_the_order_and_raises_the_error(monkeypatch, n):
    monkeypatch.setenv("OMP_NUM_THREADS", n)
    assert threads.map_over(lambda x: x * x, range(50)) == [x * x for x in range(50)]
    assert threads.map_over(str, []) == []

    def picky(x):
        if x == 7:
            raise KeyError("seven")
        return x

    with pytest.raises(KeyError, match="seven"):
        threads.map_over(picky, range(20))


def test_map_over_does_its_work_on_the_callers_thread_when_the_pool_is_busy(monkeypatch):
    """Every pool thread held by other work (``beside``'s): the caller does all the items
    itself and returns, without waiting for the pool."""
    import threading

    monkeypatch.setenv("OMP_NUM_THREADS", "2")
    release = threading.Event()
    started = [threading.Event(), threading.Event()]

    def hold(i):
        started[i].set()
        release.wait()

    held = [threads.pool().submit(hold, i) for i in range(2)]
    for s in started:
        s.wait()
    me = threading.current_thread()
    try:
        who = threads.map_over(lambda x: threading.current_thread(), range(8))
    finally:
        release.set()
    assert all(t is me for t in who)
    for h in held:
        h.result()
