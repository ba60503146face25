"""Thread settings of the numerical libraries, applied by the entry points (the `rvis` command
and the benchmarks) before numpy is imported, never at import time of a library module.

The numerics multiply small matrices (30 x 30, 3 x 30 blocks) very many times: OpenBLAS's thread
pool only adds overhead there, and on a busy 2-core machine it stalls (measured 3-8x slower
planning). rvis parallelises over processes instead.
"""

from __future__ import annotations

import multiprocessing
import os
from multiprocessing.context import ForkServerContext

BLAS_VARIABLES = ("OPENBLAS_NUM_THREADS", "OMP_NUM_THREADS", "MKL_NUM_THREADS")


def limit_blas_threads(n: int = 1) -> None:
    """One BLAS thread per process unless the user set the variable; must run before numpy
    is imported to take effect."""
    for name in BLAS_VARIABLES:
        os.environ.setdefault(name, str(n))


def exit_with_parent() -> None:
    """In a pool worker started by spawn or forkserver (its initializer): end this process when
    the process that started the pool ends, however it ends. A pool worker whose parent is
    killed (SIGKILL, the OOM killer) waits on its call queue for ever, and the forkserver that
    forked it stays as long as it lives: each killed service left one of each behind."""
    import multiprocessing.connection
    import threading

    parent = multiprocessing.parent_process()
    if parent is None or parent.sentinel is None:
        return

    def watch() -> None:
        multiprocessing.connection.wait([parent.sentinel])
        os._exit(0)

    threading.Thread(target=watch, name="exit-with-parent", daemon=True).start()


#: modules the forkserver imports once at its start (`forkserver_context`)
_PRELOAD: set[str] = set()


def forkserver_context(*preload: str) -> ForkServerContext:
    """The forkserver start method (no threads or sockets of the caller are inherited), with
    the modules `preload` imported by the forkserver when it starts: the workers it forks have
    them loaded instead of importing them each (0.2-0.3 s of CPU a worker; a simulated line
    starts a recalibration worker per run). A module named after the forkserver started is
    imported by each worker as before; one that fails to import is too (the forkserver
    ignores it)."""
    ctx = multiprocessing.get_context("forkserver")
    _PRELOAD.update(preload)
    ctx.set_forkserver_preload(["__main__", *sorted(_PRELOAD)])
    return ctx
