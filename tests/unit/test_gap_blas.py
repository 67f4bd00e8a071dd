"""One BLAS thread in the diagnosis' process and its forked workers (gap/blas.py)."""

from __future__ import annotations

import json
import os
import subprocess
import sys

import pytest

_CHILD = """
import multiprocessing as mp
import numpy as np
from threadpoolctl import threadpool_info
from uwbcal.gap.blas import one_blas_thread

def blas_threads(_=None):
    return sorted({i["num_threads"] for i in threadpool_info() if i["user_api"] == "blas"})

before = blas_threads()
one_blas_thread()
one_blas_thread()  # idempotent
with mp.get_context("fork").Pool(1) as pool:
    forked = pool.map(blas_threads, [0])[0]
import json
print(json.dumps([before, blas_threads(), forked]))
"""


def test_one_blas_thread_holds_in_the_process_and_its_forked_workers() -> None:
    env = {**os.environ, "OPENBLAS_NUM_THREADS": "2", "MKL_NUM_THREADS": "2", "OMP_NUM_THREADS": "2"}
    out = subprocess.run([sys.executable, "-c", _CHILD], capture_output=True, text=True, timeout=120, env=env)
    assert out.returncode == 0, out.stderr
    before, after, forked = json.loads(out.stdout)
    if not before:
        pytest.skip("numpy's BLAS is not one threadpoolctl can see")
    assert before == [2]  # numpy's BLAS started with two threads (env above): the limit is a change
    assert after == [1] and forked == [1]
