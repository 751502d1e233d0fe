"""The sweep's worker processes, which end with the process that started them.

A killed `nerfaug run` (SIGKILL, a crash, the machine's memory killer) runs no clean-up, and a
process pool's workers do not notice: they trained on for the rest of their runs, and the
multiprocessing resource tracker, which exits only once every process holding its pipe has, lived
on with them. Each worker therefore asks the kernel for SIGKILL when its parent dies (Linux's
PR_SET_PDEATHSIG), and watches its parent's pid as well (every platform, and the moment between
the worker's start and that request). A worker killed so loses only its unfinished run: a run's
result is written last and atomically (`experiment.store`), so a resumed sweep runs it again.
"""

from __future__ import annotations

import concurrent.futures as futures
import ctypes
import ctypes.util
import multiprocessing
import os
import signal
import sys
import threading
import time

PR_SET_PDEATHSIG = 1  # <linux/prctl.h>
POLL_S = 0.5  # how often a worker looks at its parent's pid


def worker_pool(workers: int) -> futures.ProcessPoolExecutor:
    """A pool of `workers` spawned processes (each run sets its own thread count; fork would
    inherit torch's thread pools) that end with this process, however it ends."""
    context = multiprocessing.get_context("spawn")
    return futures.ProcessPoolExecutor(
        max_workers=workers, mp_context=context, initializer=end_with_parent, initargs=(os.getpid(),)
    )


def stop_now(pool: futures.ProcessPoolExecutor) -> None:
    """Cancel the pool's queued work and kill its workers, for a sweep stopped by Ctrl-C or
    SIGTERM: leaving the pool would wait for every running run to finish (minutes). A killed
    worker loses only its unfinished run, which a resumed sweep runs again."""
    # The pool's processes are a private attribute: Python 3.11's executor has no public way to
    # end its workers (3.14 adds `terminate_workers`).
    processes = list((getattr(pool, "_processes", None) or {}).values())
    pool.shutdown(wait=False, cancel_futures=True)
    for process in processes:
        process.kill()
    for process in processes:
        process.join(timeout=5)


def end_with_parent(parent: int) -> None:
    """In a child process: end it when the process `parent` (the pid that started it) ends.

    On Linux the kernel sends SIGKILL at the parent's death; everywhere a daemon thread checks
    every `POLL_S` seconds that the parent is still this process's parent (an orphan is adopted
    by another process) and ends the process at once if not."""
    if sys.platform.startswith("linux"):
        _kill_me_with_my_parent()
    if os.getppid() != parent:  # the parent died before the request above: nothing will send it
        os._exit(1)
    threading.Thread(target=_watch, args=(parent,), name="nerfaug-parent-watch", daemon=True).start()


def _kill_me_with_my_parent() -> None:
    """prctl(PR_SET_PDEATHSIG, SIGKILL); the watch thread still covers a libc without it."""
    try:
        libc = ctypes.CDLL(ctypes.util.find_library("c") or "libc.so.6", use_errno=True)
        libc.prctl(PR_SET_PDEATHSIG, signal.SIGKILL, 0, 0, 0)
    except (OSError, AttributeError):
        pass


def _watch(parent: int) -> None:
    while os.getppid() == parent:
        time.sleep(POLL_S)
    os._exit(1)  # no clean-up: nothing is left to report to
