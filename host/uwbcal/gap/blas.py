"""The BLAS thread count for the diagnosis: one thread per process.

The diagnosis' parallelism is its forked worker processes (``--jobs``). Its fits sum the t loss
over each fold's features as a matrix product (attribute._masked_nll_sums), and OpenBLAS would
run each product on a thread per core: with two workers on two cores the threads contend with the
workers and spin while they wait. Measured on the 100k-record benchmark (tools/bench/bench_gap.py,
2 cores), serially under cProfile: 170 s wall for 235 s of CPU with the default threads, the
forward selection alone 65 s wall for 130 s CPU. The thread count can move a product's last bit:
the benchmark's diagnosis JSON with one thread and with two differs in one float, by 1.3e-16
relative, with the same verdict, named effects and fitted values. Set once per process; forked
workers inherit it.
"""

from __future__ import annotations

_done: list[bool] = []


def one_blas_thread() -> None:
    """Limit BLAS (OpenBLAS, MKL, BLIS) to one thread in this process and the ones it forks."""
    if _done:
        return
    from threadpoolctl import threadpool_limits

    threadpool_limits(limits=1, user_api="blas")
    _done.append(True)
