"""Limit the BLAS threads of numpy/scipy in this process (no threadpoolctl dependency).

On a small shared machine a multi-threaded OpenBLAS fights the other
processes: a least-squares step's SVD of a 8000 x 35 Jacobian took 2 s with
the default threads and 0.05 s with one.  The tracer runs its fits in
parallel processes, so each uses one BLAS thread.
"""

from __future__ import annotations

import ctypes

__all__ = ["limit_blas_threads"]

_SYMBOLS = ("openblas_set_num_threads", "openblas_set_num_threads64_", "scipy_openblas_set_num_threads",
            "scipy_openblas_set_num_threads64_", "MKL_Set_Num_Threads")


def limit_blas_threads(n: int = 1) -> int:
    """Set the thread count of every OpenBLAS/MKL loaded in this process; returns how many were set."""
    import numpy  # noqa: F401  (load the BLAS libraries first)
    import scipy.linalg  # noqa: F401

    done = 0
    try:
        with open("/proc/self/maps", encoding="utf-8") as fh:
            paths = {line.split()[-1] for line in fh if ("blas" in line.lower() or "mkl" in line.lower())
                     and line.split()[-1].startswith("/")}
    except OSError:
        return 0
    for path in paths:
        try:
            lib = ctypes.CDLL(path)
        except OSError:
            continue
        for sym in _SYMBOLS:
            fn = getattr(lib, sym, None)
            if fn is not None:
                fn(int(n))
                done += 1
                break
    return done
