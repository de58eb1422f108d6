"""One BLAS thread per process: our matrices are small and our parallelism is our own.

The 3-D circle fit (station/wheel/circle_fit.py) solves least-squares problems whose Jacobian is about
2400 x 6. On the station's shared 2-core machine, OpenBLAS' own worker threads made each SVD of
such a matrix take ~20 ms instead of ~0.5 ms single-threaded: the four 3-D wheels of a cycle
took 3.0 s instead of 0.46 s (docs/speed.md, "Why it is this fast"), with the same results.
Parallel work is done by our own threads (rim detection, four cameras at once), which OpenBLAS
threads only contend with.

:func:`single_thread_blas` sets numpy's and scipy's OpenBLAS to one thread at run time (the
OPENBLAS_NUM_THREADS variable works only before numpy is imported: `station` sets it, but a
process that imported numpy first has its threads already). Linux only: it finds the loaded
libraries in /proc/self/maps; elsewhere, or when OPENBLAS_NUM_THREADS asks for more than one
thread (the user chose), it does nothing.
"""

from __future__ import annotations

import ctypes
import os

_SETTERS = ("openblas_set_num_threads", "openblas_set_num_threads64_",
            "scipy_openblas_set_num_threads", "scipy_openblas_set_num_threads64_")


def single_thread_blas() -> list[str]:
    """Set every loaded OpenBLAS to one thread; returns the paths of the libraries set."""
    if os.environ.get("OPENBLAS_NUM_THREADS", "1") != "1":  # the user chose another number
        return []
    import scipy.linalg  # noqa: F401 - loads scipy's own OpenBLAS now, so that it is found and set too
    try:
        with open("/proc/self/maps") as maps:
            libs = sorted({line.split()[-1] for line in maps if "openblas" in line.lower()})
    except OSError:
        return []
    done = []
    for path in libs:
        try:
            lib = ctypes.CDLL(path)
        except OSError:
            continue
        for name in _SETTERS:
            fn = getattr(lib, name, None)
            if fn is not None:
                fn(1)
                done.append(path)
                break
    return done
