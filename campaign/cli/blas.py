"""BLAS threads of a trackcal process: one by default, `TRACKCAL_BLAS_THREADS=N` for another number.

One on purpose: trackcal's matrices have tens of columns, where a second BLAS thread buys little and, on a
machine shared with other work, costs much (issue 16, measured on 2 cores: diagnose of a 156-row campaign
51 s with numpy's default of two threads, 6.4 s with one). Parallelism comes from processes instead (plan
starts, batches), each on one BLAS thread, and from a diagnosis's own threads, whose folds' LAPACK calls run at once
(campaign.jobs.diagnose.diagnosis_threads; issue 26).
"""

from __future__ import annotations

import contextlib
import os
from collections.abc import Iterator

from threadpoolctl import threadpool_limits

from trackcal.campaign.errors import UsageError

ENV = "TRACKCAL_BLAS_THREADS"
# read by the BLAS / OpenMP libraries when they load: libraries loaded later in this process (scipy's own
# OpenBLAS is loaded on first use) and child processes started with a fresh interpreter
LIBRARY_ENV = ("OPENBLAS_NUM_THREADS", "OMP_NUM_THREADS", "MKL_NUM_THREADS")


def blas_threads() -> int:
    text = os.environ.get(ENV, "1")
    try:
        n = int(text)
    except ValueError:
        n = 0
    if n < 1:
        raise UsageError(f"{ENV} must be a positive integer (BLAS threads per process), got {text!r}")
    return n


@contextlib.contextmanager
def limited_blas() -> Iterator[int]:
    """Run a command with `blas_threads()` BLAS threads: the libraries already loaded through threadpoolctl,
    later ones and child processes through their environment variables."""
    n = blas_threads()
    before = {name: os.environ.get(name) for name in LIBRARY_ENV}
    os.environ.update(dict.fromkeys(LIBRARY_ENV, str(n)))
    try:
        with threadpool_limits(limits=n, user_api="blas"):
            yield n
    finally:  # a caller of main() in-process (tests, notebooks) gets its environment back
        for name, value in before.items():
            if value is None:
                os.environ.pop(name, None)
            else:
                os.environ[name] = value
