"""Run ``fn(i)`` for ``i in range(n)`` in forked worker processes, reporting progress.

The work function and its data are inherited by fork (no pickling of the simulator's scenes and
Embree handles, or of a session's detections); results (small) come back in order. Without
``fork`` (or with one worker) it runs serially.
"""

from __future__ import annotations

import multiprocessing
import os
from collections.abc import Callable

_FN: list = []   # the function being mapped, inherited by forked workers


def run_indexed(fn: Callable[[int], object], n: int, workers: int | None = None,
                progress: Callable[[int], None] | None = None) -> list:
    """Results of ``fn(0) ... fn(n - 1)`` in index order.

    Parameters
    ----------
    fn : callable
        Takes an index; must be deterministic given the index (each call owns its generator).
    n : int
    workers : int, optional
        Processes; default the number of CPUs, at most 4.
    progress : callable, optional
        Called with the number of finished items.
    """
    workers = workers or min(4, os.cpu_count() or 1)
    progress = progress or (lambda done: None)
    results: list = [None] * n
    if workers > 1 and n > 1 and "fork" in multiprocessing.get_all_start_methods():
        _FN[:] = [fn]
        try:
            n_chunks = min(n, workers * 4)
            chunks = [list(range(i, n, n_chunks)) for i in range(n_chunks)]
            with multiprocessing.get_context("fork").Pool(workers) as pool:
                done = 0
                for chunk in pool.imap_unordered(_run_chunk, chunks):
                    for i, r in chunk:
                        results[i] = r
                    done += len(chunk)
                    progress(done)
        finally:
            _FN.clear()
    else:
        for i in range(n):
            results[i] = fn(i)
            progress(i + 1)
    return results


def _run_chunk(indices: list[int]) -> list:
    fn = _FN[0]
    return [(i, fn(i)) for i in indices]
