"""Compile the simulator's casadi Functions to C, cached on disk.

casadi generates the C source of one control period (``sample``, with
outputs, and ``sample_x``, the state update alone); a small C driver added
here loops over the periods in place (no copies between periods) and writes
one output column per output period.  The source is hashed and the shared
library built once per hash with the system C compiler, then reused by every
later process.  The cache lives in ``$THSA_CACHE_DIR`` or
``~/.cache/thsa-control``.  Without a C compiler :func:`compile_run_loop`
returns None and the simulator falls back to casadi's virtual machine.
"""

from __future__ import annotations

import ctypes
import hashlib
import os
import shutil
import subprocess
import tempfile
import time
from pathlib import Path

import casadi as ca
import numpy as np

__all__ = ["cache_dir", "compile_run_loop", "RunLoop"]

_DRIVER = r"""
#include <stdlib.h>
#include <string.h>

/* Runs n_steps control periods from z (updated in place); every decim-th
   period (from the first) writes its outputs to the next column of Y. */
int thsa_run(double* z, const double* W, const double* theta, long long n_steps, long long decim, double* Y) {
  casadi_int sz_arg, sz_res, sz_iw, sz_w, a2, r2, iw2, w2;
  thsa_sample_work(&sz_arg, &sz_res, &sz_iw, &sz_w);
  thsa_sample_x_work(&a2, &r2, &iw2, &w2);
  if (a2 > sz_arg) sz_arg = a2;
  if (r2 > sz_res) sz_res = r2;
  if (iw2 > sz_iw) sz_iw = iw2;
  if (w2 > sz_w) sz_w = w2;
  const double** arg = (const double**) malloc(sizeof(double*) * (sz_arg + 3));
  double** res = (double**) malloc(sizeof(double*) * (sz_res + 2));
  casadi_int* iw = (casadi_int*) malloc(sizeof(casadi_int) * (sz_iw + 1));
  double* w = (double*) malloc(sizeof(double) * (sz_w + 1));
  const casadi_int nz = thsa_sample_sparsity_in(0)[0];
  const casadi_int nw = thsa_sample_sparsity_in(1)[0];
  const casadi_int ny = thsa_sample_sparsity_out(1)[0];
  double* zn = (double*) malloc(sizeof(double) * nz);
  int flag = 0;
  if (!arg || !res || !iw || !w || !zn) { flag = -1; goto done; }
  for (long long k = 0; k < n_steps; ++k) {
    arg[0] = z; arg[1] = W + k * nw; arg[2] = theta;
    res[0] = zn;
    if (k % decim == 0) {
      res[1] = Y + (k / decim) * ny;
      flag = thsa_sample(arg, res, iw, w, 0);
    } else {
      flag = thsa_sample_x(arg, res, iw, w, 0);
    }
    if (flag) goto done;
    memcpy(z, zn, sizeof(double) * nz);
  }
done:
  free(arg); free(res); free(iw); free(w); free(zn);
  return flag;
}
"""


def cache_dir() -> Path:
    """Directory of the compiled-library cache (created on demand)."""
    root = os.environ.get("THSA_CACHE_DIR") or os.path.join(
        os.environ.get("XDG_CACHE_HOME") or os.path.join(os.path.expanduser("~"), ".cache"), "thsa-control")
    path = Path(root)
    path.mkdir(parents=True, exist_ok=True)
    return path


class RunLoop:
    """A compiled run loop: ``loop(z0, W, theta, decimation) -> (Y, z_final)``.

    ``W`` is (n_w x n_steps), ``Y`` is (n_y x ceil(n_steps / decimation)).
    """

    def __init__(self, lib_path: str, nz: int, nw: int, ny: int):
        self._lib = ctypes.CDLL(lib_path)
        self._fn = self._lib.thsa_run
        dp = ctypes.POINTER(ctypes.c_double)
        self._fn.argtypes = [dp, dp, dp, ctypes.c_longlong, ctypes.c_longlong, dp]
        self._fn.restype = ctypes.c_int
        self.nz, self.nw, self.ny = nz, nw, ny

    def __call__(self, z0: np.ndarray, W: np.ndarray, theta: np.ndarray, decimation: int):
        z = np.array(z0, dtype=float, order="C").copy()
        # column k of W (casadi's column-major) is row k of the C-ordered transpose
        Wt = np.ascontiguousarray(np.asarray(W, dtype=float).T)
        th = np.ascontiguousarray(theta, dtype=float)
        n = Wt.shape[0]
        n_out = -(-n // decimation)
        Y = np.empty((n_out, self.ny))
        dp = ctypes.POINTER(ctypes.c_double)
        flag = self._fn(z.ctypes.data_as(dp), Wt.ctypes.data_as(dp), th.ctypes.data_as(dp), n, decimation,
                        Y.ctypes.data_as(dp))
        if flag:
            raise RuntimeError(f"compiled run loop returned {flag}")
        return Y.T, z


def compile_run_loop(sample: ca.Function, sample_x: ca.Function, *, flags: tuple[str, ...] = ("-O2",)):
    """Generate, compile (or find in the cache) and load the run loop.

    Returns
    -------
    loop : RunLoop or None
        None when no C compiler is available or compilation failed.
    info : dict
        ``{"compiled", "cached", "codegen_s", "compile_s", "path", "error"?}``.
    """
    cc = shutil.which(os.environ.get("CC", "gcc")) or shutil.which("cc")
    t0 = time.perf_counter()
    f1 = ca.Function("thsa_sample", sample.sx_in(), sample.call(sample.sx_in()))
    f2 = ca.Function("thsa_sample_x", sample_x.sx_in(), sample_x.call(sample_x.sx_in()))
    with tempfile.TemporaryDirectory() as tmp:
        cg = ca.CodeGenerator("thsa_run.c", {"with_header": False})
        cg.add(f1)
        cg.add(f2)
        src_path = Path(cg.generate(tmp + os.sep))
        source = src_path.read_text() + _DRIVER
        src_path.write_text(source)
        codegen_s = time.perf_counter() - t0
        info = {"compiled": False, "cached": False, "codegen_s": codegen_s, "compile_s": 0.0, "path": ""}
        if cc is None:
            info["error"] = "no C compiler found (set CC)"
            return None, info
        digest = hashlib.sha256((source + " ".join(flags) + ca.__version__).encode()).hexdigest()[:24]
        lib = cache_dir() / f"thsa_run_{digest}.so"
        info["cached"] = lib.exists()
        if not info["cached"]:
            t1 = time.perf_counter()
            tmp_lib = Path(tmp) / lib.name
            proc = subprocess.run([cc, *flags, "-fPIC", "-shared", str(src_path), "-o", str(tmp_lib), "-lm"],
                                  capture_output=True, text=True)
            if proc.returncode != 0:
                info["error"] = proc.stderr[-2000:]
                return None, info
            staged = lib.with_name(f"{lib.name}.{os.getpid()}.tmp")
            shutil.copyfile(tmp_lib, staged)
            os.replace(staged, lib)  # atomic publish; racing processes write identical files
            info["compile_s"] = time.perf_counter() - t1
    info["compiled"] = True
    info["path"] = str(lib)
    return RunLoop(str(lib), sample.size1_in(0), sample.size1_in(1), sample.size1_out(1)), info
