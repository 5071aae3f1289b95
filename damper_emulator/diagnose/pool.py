"""Where a diagnosis's fits run: a round's fits are independent tasks
(:class:`~damper_emulator.diagnose.tasks.FitTask`) mapped over any
:class:`concurrent.futures.Executor` (a Dask client's ``get_executor()``), or over the
default :class:`LocalPool`, in the order they finish."""

from __future__ import annotations

from collections.abc import Callable, Iterable, Iterator
from concurrent.futures import Executor, as_completed
from typing import TypeVar

__all__ = ["LocalPool", "unordered"]

#: a task of the pool and its result
_T = TypeVar("_T")
_R = TypeVar("_R")


class LocalPool:
    """The default executor: a fork-based process pool (the workers inherit the compiled
    kernels) of ``jobs`` processes, or this process for one."""

    def __init__(self, jobs: int):
        self.jobs = jobs
        self.pool: Executor | None = None

    def __enter__(self) -> LocalPool:
        if self.jobs > 1:
            import multiprocessing
            from concurrent.futures import ProcessPoolExecutor

            self.pool = ProcessPoolExecutor(self.jobs,
                                            mp_context=multiprocessing.get_context("fork"))
        return self

    def __exit__(self, *exc: object) -> None:
        if self.pool is not None:
            self.pool.shutdown(cancel_futures=True)

    def map_unordered(self, fn: Callable[[_T], _R], tasks: Iterable[_T]
                      ) -> Iterator[tuple[int, _R]]:
        """``(index, fn(task))`` for each task, in the order they finish."""
        if self.pool is None:
            for i, t in enumerate(tasks):
                yield i, fn(t)
            return
        yield from unordered(self.pool, fn, tasks)


def unordered(executor: Executor, fn: Callable[[_T], _R], tasks: Iterable[_T]
              ) -> Iterator[tuple[int, _R]]:
    """``(index, fn(task))`` for each task submitted to ``executor``, as they finish."""
    futures = {executor.submit(fn, t): i for i, t in enumerate(tasks)}
    for fut in as_completed(futures):
        yield futures[fut], fut.result()
