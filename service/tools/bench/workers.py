"""The local process pool the benchmarks run their missions in.

Each worker's BLAS gets its share of the cores, no more. NumPy's OpenBLAS starts a thread per core
in every process by default, so ``jobs`` workers on as many cores run ``jobs`` x cores threads, and
the mapper's small matrix products (a few hundred by a few dozen) then spend most of their time
waiting for each other: on the 2-core machine one product took 36 ms that way and 3.4 ms with one
thread each. Limiting the threads changes no result, only the time.
"""

from __future__ import annotations

import os
from collections.abc import Callable, Iterator, Sequence
from concurrent.futures import Future, ProcessPoolExecutor
from typing import TypeVar

import numpy  # noqa: F401  (loads the BLAS that the workers limit: an unloaded one cannot be)
from threadpoolctl import threadpool_limits

T = TypeVar("T")
R = TypeVar("R")

_limits: list[object] = []
"""Keeps the worker's limit alive for the worker's lifetime."""


def _share_the_cores(threads: int) -> None:
    _limits.append(threadpool_limits(limits=threads, user_api="blas"))


def worker_pool(jobs: int) -> ProcessPoolExecutor:
    """A pool of ``jobs`` processes whose BLAS threads together do not exceed the cores."""
    threads = max(1, (os.cpu_count() or 1) // jobs)
    return ProcessPoolExecutor(max_workers=jobs, initializer=_share_the_cores, initargs=(threads,))


def in_order(
    task: Callable[[T], R],
    items: Sequence[T],
    jobs: int | None = None,
    progress: Callable[[int], None] = lambda _: None,
) -> Iterator[R]:
    """``task`` of each item, yielded in the items' order: in this process with one job, else in a
    ``worker_pool`` of ``jobs`` processes (default: the cores). ``progress`` is told of each task
    as it finishes (``task`` must be picklable: a module-level function)."""
    workers = jobs or os.cpu_count() or 1
    if workers == 1:
        for item in items:
            result = task(item)
            progress(1)
            yield result
        return
    with worker_pool(workers) as pool:
        futures: list[Future[R]] = []
        for item in items:
            future = pool.submit(task, item)
            future.add_done_callback(lambda _: progress(1))
            futures.append(future)
        for future in futures:
            yield future.result()


def in_order_by_batch(
    task: Callable[[T], R], batches: Sequence[tuple[str, Sequence[T]]], jobs: int | None = None
) -> Iterator[tuple[str, list[R]]]:
    """(name, ``task`` of each of its items) for each named batch, in order, each as soon as its
    items are done; every item of every batch goes to one ``in_order`` run."""
    results = in_order(task, [item for _, batch in batches for item in batch], jobs)
    for name, batch in batches:
        yield name, [next(results) for _ in batch]
