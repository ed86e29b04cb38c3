"""OpenCV's worker threads: all cores for a single run, one per worker in a study.

OpenCV splits some of a frame's work (warps, colour conversions, optical flow, the frame
noise) across its threads; each of those writes its own pixels or points, so the result does
not depend on the thread count (tests/test_paper2_speed.py flies E1 both ways). What gathers
results from several threads in the order they finish (SIFT's keypoint lists, a parallel
connected-component labelling) runs inside ``single_thread()``.

A single run (``cosim run``, ``cosim bench``) uses every core that is free (``run_threads``);
a study's worker runs one mission per core and sets ``set_run_threads(1)``
(``cosim/studies/jobs.py``); ``COSIM_CV_THREADS=N`` in the environment sets N.
"""

from __future__ import annotations

import contextlib
import os
from collections.abc import Iterator

import cv2

_run_threads: int | None = None


def set_run_threads(n: int | None) -> None:
    """The OpenCV thread count of the runs in this process (None: the default)."""
    global _run_threads
    _run_threads = n


def run_threads() -> int:
    """The count a run uses: ``set_run_threads``, else ``COSIM_CV_THREADS``, else every core
    when the cores are free (load average of the last minute below the cores less a half:
    this run's own thread counts), else one. OpenCV's pool waits actively for its slowest
    thread: on a machine busy with other work, two threads made E2 2x slower than one
    (docs/performance-paper2.md). The count never changes a result, only the speed."""
    if _run_threads is not None:
        return max(1, int(_run_threads))
    env = os.environ.get("COSIM_CV_THREADS", "").strip()
    if env.isdigit() and int(env) >= 1:
        return int(env)
    cores = max(1, cv2.getNumberOfCPUs())
    try:
        busy = os.getloadavg()[0] > cores - 0.5
    except OSError:
        busy = False
    return 1 if busy else cores


def apply(pipelined: bool = False) -> int:
    """Set OpenCV's thread count for a run; returns it. A pipelined run (its camera stream
    renders, and computes the app's per-frame image work, in a worker while the main thread
    flies: cosim/sensors/stream.py) has its cores in its worker and its main thread, and
    OpenCV runs on one thread in each: with a worker thread, the count is global to the
    process, and a parallel section of one thread must not change what ``single_thread()``
    holds in the other; a render process is forked after this (a fork does not copy
    OpenCV's pool)."""
    n = 1 if pipelined else run_threads()
    cv2.setNumThreads(n)
    return n


@contextlib.contextmanager
def single_thread() -> Iterator[None]:
    """OpenCV on one thread inside the block (results gathered in a fixed order)."""
    n = cv2.getNumThreads()
    if n == 1:
        yield
        return
    cv2.setNumThreads(1)
    try:
        yield
    finally:
        cv2.setNumThreads(n)
