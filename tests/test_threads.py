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
    with threads.own_threads():  # one thread: nothing to hold back
        assert blas() == before
