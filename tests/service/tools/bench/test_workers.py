"""The benchmarks' worker pool: each worker's BLAS threads are its share of the cores."""

import os

import pytest
from threadpoolctl import threadpool_info

from service.tools.bench.workers import in_order_by_batch, worker_pool


def _blas_threads() -> list[int]:
    return [int(pool["num_threads"]) for pool in threadpool_info() if pool["user_api"] == "blas"]


@pytest.mark.parametrize("jobs", [1, 2])
def test_workers_share_the_cores_among_their_blas_threads(jobs: int) -> None:
    share = max(1, (os.cpu_count() or 1) // jobs)
    with worker_pool(jobs) as pool:
        seen = pool.submit(_blas_threads).result(timeout=60)
    assert seen
    assert all(n == share for n in seen), seen


def _square(x: int) -> int:
    return x * x


@pytest.mark.parametrize("jobs", [1, 2])
def test_batches_come_back_whole_in_their_order(jobs: int) -> None:
    batches = [("a", [1, 2]), ("b", []), ("c", [3])]
    assert list(in_order_by_batch(_square, batches, jobs)) == [("a", [1, 4]), ("b", []), ("c", [9])]
