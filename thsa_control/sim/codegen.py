"""Compile casadi Functions to C, cached on disk, and verify what is loaded: the one C build of the workbench.

The simulator's run loop (:func:`compile_run_loop`) and the tuning
objective's stage Functions (:func:`compile_functions`, loaded as casadi
``external`` Functions) go through the same generation, cache and checks.

casadi generates the C source of one control period (``sample``, with
outputs, and ``sample_x``, the state update alone) and of ``thsa_pre``, the
parts of a period that depend on the parameters alone (``extract_parametric``),
computed once per run; a small C driver added here loops over the periods in
place (no copies between periods), reads constant inputs once, writes one
output column per output period, stops a run at its first non-finite output
and spreads a batch of runs over threads (:class:`RunLoop`).  Every change to
the generated code keeps the operations and their order: the same bits
(``bench/bit_identity.py``).  The library is built once per source
hash with the system C compiler and reused by every later process.  The cache
lives in ``$THSA_CACHE_DIR`` or ``~/.cache/thsa-control``.

The cache is never trusted blindly (issue #7, item 2):

* next to ``thsa_run_<hash>.so`` lies ``thsa_run_<hash>.json`` with the
  SHA-256 of the generated C source and of the library; both are checked
  before ``dlopen`` (a truncated file would otherwise kill the process with
  SIGBUS), and the library itself reports the source hash it was built from
  (``thsa_source_sha256()``), checked after loading, so a library of another
  model under the right name is rejected;
* any mismatch or load failure rebuilds; a fresh build is loaded and checked
  from its private build folder before it is published, so a compiler that
  writes an empty or broken file never poisons the cache;
* files are published atomically (temporary name + ``os.replace``);
* a library is built by one process at a time (``flock`` on ``.<name>.lock`` in the cache): a second
  process that needs it meanwhile (two pytest-xdist workers, two fit processes on a fresh machine)
  waits and loads the published file, verified as any cached one, instead of compiling it again;
* an unwritable cache falls back to a per-process temporary folder, and a
  missing or broken C compiler to casadi's interpreter (about 20x slower);
  each fallback is said once per process on stderr.
"""

from __future__ import annotations

import atexit
import contextlib
import ctypes
import hashlib
import json
import os
import re
import shutil
import subprocess
import sys
import tempfile
import time
from pathlib import Path

import casadi as ca
import numpy as np

__all__ = ["cache_dir", "compile_run_loop", "compile_functions", "RunLoop", "NonFiniteOutput", "library_files",
           "install_library"]

_NOTED: set[str] = set()  # fallbacks already reported in this process (said once)
_PRIVATE_DIR: list[Path] = []  # per-process fallback cache, removed at exit


def _note_once(key: str, message: str) -> None:
    if key not in _NOTED:
        _NOTED.add(key)
        print(f"note: {message}", file=sys.stderr)


_DRIVER = r"""
#include <stdlib.h>
#include <string.h>
#include <pthread.h>

#define THSA_YBLOCK 64  /* output columns gathered before they are written to Y (thsa_flush) */

/* The per-run constants: thsa_pre(theta) -> q, the parts of a control period that depend on the
   parameters alone (casadi's extract_parametric), computed once per run instead of once per period;
   thsa_sample(z, w, theta, q) -> (z_next, y) and thsa_sample_x(z, w, theta, q) -> z_next are the
   period with (every decim-th period) and without outputs.  Same operations on the same values:
   the same bits as evaluating the period from theta alone. */
typedef struct {
  const double** arg; double** res; casadi_int* iw; double* w; double* za; double* zb; double* wk; double* yk;
  double* q; const double** wp; casadi_int* iv; double* yb;
} thsa_buf;

static casadi_int thsa_nz(void) { return thsa_sample_sparsity_in(0)[0]; }
static casadi_int thsa_nw(void) { return thsa_sample_sparsity_in(1)[0]; }
static casadi_int thsa_nq(void) { return thsa_sample_sparsity_in(3)[0]; }
static casadi_int thsa_ny(void) { return thsa_sample_sparsity_out(1)[0]; }

static int thsa_buf_init(thsa_buf* b) {
  casadi_int sz_arg, sz_res, sz_iw, sz_w, a2, r2, iw2, w2;
  const casadi_int nz = thsa_nz(), nw = thsa_nw(), ny = thsa_ny(), nq = thsa_nq();
  thsa_sample_work(&sz_arg, &sz_res, &sz_iw, &sz_w);
  thsa_sample_x_work(&a2, &r2, &iw2, &w2);
  if (a2 > sz_arg) sz_arg = a2;
  if (r2 > sz_res) sz_res = r2;
  if (iw2 > sz_iw) sz_iw = iw2;
  if (w2 > sz_w) sz_w = w2;
  thsa_pre_work(&a2, &r2, &iw2, &w2);
  if (a2 > sz_arg) sz_arg = a2;
  if (r2 > sz_res) sz_res = r2;
  if (iw2 > sz_iw) sz_iw = iw2;
  if (w2 > sz_w) sz_w = w2;
  b->arg = (const double**) malloc(sizeof(double*) * (sz_arg + 4));
  b->res = (double**) malloc(sizeof(double*) * (sz_res + 2));
  b->iw = (casadi_int*) malloc(sizeof(casadi_int) * (sz_iw + 1));
  b->w = (double*) malloc(sizeof(double) * (sz_w + 1));
  b->za = (double*) malloc(sizeof(double) * (nz + 1));
  b->zb = (double*) malloc(sizeof(double) * (nz + 1));
  b->wk = (double*) malloc(sizeof(double) * (nw + 1));
  b->yk = (double*) malloc(sizeof(double) * (ny + 1));
  b->q = (double*) malloc(sizeof(double) * (nq + 1));
  b->wp = (const double**) malloc(sizeof(double*) * (nw + 1));
  b->iv = (casadi_int*) malloc(sizeof(casadi_int) * (nw + 1));
  b->yb = (double*) malloc(sizeof(double) * (ny * THSA_YBLOCK + 1));
  return (b->arg && b->res && b->iw && b->w && b->za && b->zb && b->wk && b->yk && b->q && b->wp && b->iv && b->yb) ? 0 : -1;
}

static void thsa_buf_free(thsa_buf* b) {
  free(b->arg); free(b->res); free(b->iw); free(b->w); free(b->za); free(b->zb); free(b->wk); free(b->yk);
  free(b->q); free(b->wp); free(b->iv); free(b->yb);
}

/* Output columns are gathered THSA_YBLOCK at a time and written to Y (output-major) as short
   contiguous rows: writing each column straight into Y touches ny rows n_out apart (ny pages per
   sample: TLB misses). */
static void thsa_flush(const double* yb, casadi_int n_cols, casadi_int ny, double* Y, long long n_out, long long col0) {
  for (casadi_int i = 0; i < ny; ++i) {
    double* row = Y + i * n_out + col0;
    for (casadi_int c = 0; c < n_cols; ++c) row[c] = yb[c * ny + i];
  }
}

/* One run: n_steps control periods from z (updated in place).  Input j of period k is
   W[j][k * ws[j]] (ws[j] = 1: one sample per period; 0: constant, one value).  Every decim-th
   period (from the first) writes its outputs to the next column of Y (ny x n_out, output-major).
   *bad: the first output column with a non-finite value (the run stops there), else -1. */
static int thsa_run_one(thsa_buf* b, double* z, const double* const* W, const long long* ws, const double* theta,
                        long long n_steps, long long decim, double* Y, long long* bad) {
  const casadi_int nz = thsa_nz(), nw = thsa_nw(), ny = thsa_ny();
  const long long n_out = (n_steps + decim - 1) / decim;
  double* zc = b->za;
  double* zn = b->zb;
  casadi_int* vary = b->iv;  /* the inputs that change from period to period */
  casadi_int n_vary = 0;
  int flag;
  *bad = -1;
  b->arg[0] = theta; b->res[0] = b->q;
  flag = thsa_pre(b->arg, b->res, b->iw, b->w, 0);
  if (flag) return flag;
  memcpy(zc, z, sizeof(double) * nz);
  for (casadi_int j = 0; j < nw; ++j) {
    b->wp[j] = W[j];
    b->wk[j] = n_steps > 0 ? W[j][0] : 0.0;  /* a constant input is set once */
    if (ws[j]) vary[n_vary++] = j;
  }
  b->arg[1] = b->wk; b->arg[2] = theta; b->arg[3] = b->q;
  long long until_out = 0, col = 0, col0 = 0;
  casadi_int in_block = 0;  /* output columns gathered in b->yb (column-major), written to Y as rows */
  for (long long k = 0; k < n_steps; ++k) {
    for (casadi_int v = 0; v < n_vary; ++v) b->wk[vary[v]] = b->wp[vary[v]][k];
    b->arg[0] = zc; b->res[0] = zn;
    if (until_out == 0) {
      double* yk = b->yb + in_block * ny;
      int finite = 1;  /* x * 0 == 0 exactly when x is finite (independent compares, no chain of adds) */
      b->res[1] = yk;
      flag = thsa_sample(b->arg, b->res, b->iw, b->w, 0);
      for (casadi_int i = 0; i < ny; ++i) finite &= (yk[i] * 0.0 == 0.0);
      if (!finite) { *bad = col; break; }
      ++col;
      if (++in_block == THSA_YBLOCK) { thsa_flush(b->yb, in_block, ny, Y, n_out, col0); col0 = col; in_block = 0; }
      until_out = decim;
    } else {
      flag = thsa_sample_x(b->arg, b->res, b->iw, b->w, 0);
    }
    --until_out;
    if (flag) break;
    double* t = zc; zc = zn; zn = t;
  }
  if (in_block) thsa_flush(b->yb, in_block, ny, Y, n_out, col0);
  memcpy(z, zc, sizeof(double) * nz);
  return flag;
}

typedef struct {
  long long next;  /* next run to take (shared by the threads, atomic) */
  long long n_runs; double* z; const double* const* W; const long long* ws; const double* theta;
  long long th_stride; long long n_steps; long long decim; double* Y; long long* bad; int flag;
} thsa_batch;

static void* thsa_worker(void* p) {
  thsa_batch* B = (thsa_batch*) p;
  const casadi_int nz = thsa_nz(), nw = thsa_nw(), ny = thsa_ny();
  const long long n_out = (B->n_steps + B->decim - 1) / B->decim;
  thsa_buf b;
  int flag = thsa_buf_init(&b);
  for (;;) {
    if (flag) { __atomic_store_n(&B->flag, flag, __ATOMIC_RELAXED); break; }
    if (__atomic_load_n(&B->flag, __ATOMIC_RELAXED)) break;
    const long long r = __atomic_fetch_add(&B->next, 1, __ATOMIC_RELAXED);
    if (r >= B->n_runs) break;
    flag = thsa_run_one(&b, B->z + r * nz, B->W + r * nw, B->ws + r * nw, B->theta + r * B->th_stride,
                        B->n_steps, B->decim, B->Y + r * ny * n_out, B->bad + r);
  }
  thsa_buf_free(&b);
  return 0;
}

/* n_runs runs of n_steps periods: run r starts from z + r*nz (updated in place), reads its inputs
   W[r*nw + j] with strides ws[r*nw + j] and theta + r*th_stride (stride 0: shared), writes
   Y + r*ny*n_out and bad[r].  n_threads > 1: threads take the next run as they finish one (each run
   computed exactly as alone: the same bits whatever the thread count). */
int thsa_run_batch(long long n_runs, double* z, const double* const* W, const long long* ws, const double* theta,
                   long long th_stride, long long n_steps, long long decim, double* Y, long long* bad, int n_threads) {
  thsa_batch B = {0, n_runs, z, W, ws, theta, th_stride, n_steps, decim, Y, bad, 0};
  if (n_threads < 1) n_threads = 1;
  if (n_threads > n_runs) n_threads = (int) n_runs;
  pthread_t* th = n_threads > 1 ? (pthread_t*) malloc(sizeof(pthread_t) * n_threads) : 0;
  char* started = n_threads > 1 ? (char*) calloc(n_threads, 1) : 0;
  if (n_threads > 1 && th && started)
    for (int t = 1; t < n_threads; ++t) started[t] = pthread_create(&th[t], 0, thsa_worker, &B) == 0;
  thsa_worker(&B);  /* this thread works too; a thread that could not start leaves its share to the others */
  if (th && started)
    for (int t = 1; t < n_threads; ++t) if (started[t]) pthread_join(th[t], 0);
  free(th); free(started);
  return B.flag;
}
"""


#: C compiler flags.  None of them lets the compiler change a floating-point result: no -ffast-math, no
#: FMA contraction (-ffp-contract=off; the default x86-64 target has no FMA anyway), IEEE semantics kept;
#: -fno-semantic-interposition lets casadi's helper functions inline inside the library, -fno-math-errno
#: lets sqrt be one instruction (errno is not read).
FLAGS = ("-O3", "-ffp-contract=off", "-fno-math-errno", "-fno-semantic-interposition", "-pthread")

#: casadi's fmin/fmax call libm through the PLT; these inline forms return the same bits for every
#: input (glibc's minsd/maxsd semantics: the first argument when strictly smaller/larger, else the
#: second unless it is NaN) -- checked against libm on signed zeros, infinities, NaNs and subnormals by
#: tests/test_cache.py.
_INLINE_MINMAX = (("  return fmax(x, y);", "  return x>y ? x : (y==y ? y : x);"),
                  ("  return fmin(x, y);", "  return x<y ? x : (y==y ? y : x);"))


def cache_dir() -> Path:
    """Directory of the compiled-library cache (created on demand; may raise OSError)."""
    root = os.environ.get("THSA_CACHE_DIR") or os.path.join(
        os.environ.get("XDG_CACHE_HOME") or os.path.join(os.path.expanduser("~"), ".cache"), "thsa-control")
    path = Path(root)
    path.mkdir(parents=True, exist_ok=True)
    return path


def _private_dir() -> Path:
    if not _PRIVATE_DIR:
        d = Path(tempfile.mkdtemp(prefix="thsa-cache-"))
        _PRIVATE_DIR.append(d)
        atexit.register(shutil.rmtree, d, True)
    return _PRIVATE_DIR[0]


def _sha256_file(path: Path) -> str | None:
    try:
        h = hashlib.sha256()
        with open(path, "rb") as f:
            for block in iter(lambda: f.read(1 << 20), b""):
                h.update(block)
        return h.hexdigest()
    except OSError:
        return None


def _verified(lib: Path, manifest: Path, source_sha: str) -> bool:
    """True when the manifest matches the source and the library's bytes (checked before dlopen)."""
    try:
        meta = json.loads(manifest.read_text(encoding="utf-8"))
    except (OSError, ValueError):
        return False
    if not isinstance(meta, dict) or meta.get("source_sha256") != source_sha:
        return False
    try:
        if lib.stat().st_size != meta.get("library_size"):
            return False
    except OSError:
        return False
    return _sha256_file(lib) == meta.get("library_sha256")


def _load(lib: Path, source_sha: str, dims) -> "RunLoop | None":
    """dlopen and check the library's own source hash; None when it does not load or is another model's."""
    try:
        loop = RunLoop(str(lib), *dims)
    except (OSError, AttributeError):
        return None
    if loop.source_sha256() != source_sha:
        return None
    return loop


def _publish(src: Path, target: Path) -> None:
    staged = target.with_name(f".{target.name}.{os.getpid()}.tmp")
    try:
        shutil.copyfile(src, staged)
        os.replace(staged, target)
    finally:
        staged.unlink(missing_ok=True)


class RunLoop:
    """A compiled run loop: ``loop(z0, W, theta, decimation) -> (Y, z_final)`` and its batched form.

    ``W`` is (n_w x n_steps) or a sequence of n_w rows, each of n_steps samples or of one
    (a constant input: read with stride 0, nothing is expanded); ``Y`` is
    (n_y x ceil(n_steps / decimation)), row-major (one row per signal: no transposes).
    """

    def __init__(self, lib_path: str, nz: int, nw: int, ny: int):
        self._lib = ctypes.CDLL(lib_path)
        ll = ctypes.c_longlong
        vp = ctypes.c_void_p
        self._batch = self._lib.thsa_run_batch
        self._batch.argtypes = [ll, vp, vp, vp, vp, ll, ll, ll, vp, vp, ctypes.c_int]
        self._batch.restype = ctypes.c_int
        self.nz, self.nw, self.ny = nz, nw, ny
        self._sha = self._lib.thsa_source_sha256
        self._sha.argtypes = []
        self._sha.restype = ctypes.c_char_p

    def source_sha256(self) -> str:
        """SHA-256 of the C source this library was built from (embedded at build time)."""
        return self._sha().decode("ascii", "replace")

    def __call__(self, z0: np.ndarray, W, theta: np.ndarray, decimation: int):
        """One run: ``(Y, z_final)``; raises :class:`NonFiniteOutput` when an output is not finite."""
        Y, z, bad = self.batch(np.asarray(z0, dtype=float)[None, :], [W], np.asarray(theta, dtype=float), decimation)
        if bad[0] >= 0:
            raise NonFiniteOutput(0, int(bad[0]))
        return Y[0], z[0]

    def rows(self, W, n: int | None = None):
        """``(pointers, strides, keep)`` of one run's input rows (see the class docstring); ``n`` its length."""
        if isinstance(W, np.ndarray) and W.ndim == 2:
            W = np.ascontiguousarray(W, dtype=float)
            rows = list(W)
        else:
            rows = [_row(r) for r in W]
        if len(rows) != self.nw:
            raise ValueError(f"{len(rows)} input rows, the loop has {self.nw}")
        if n is None:
            n = max((r.shape[0] for r in rows if r.ndim == 1), default=0)
        ptrs, strides = [], []
        for j, r in enumerate(rows):
            if r.ndim != 1 or r.shape[0] not in (n, 1):
                raise ValueError(f"input row {j} of shape {r.shape}, expected ({n},) or (1,)")
            ptrs.append(r.ctypes.data)
            strides.append(1 if r.shape[0] == n and n != 1 else 0)
        return ptrs, strides, rows, n

    def batch(self, Z0: np.ndarray, W, theta: np.ndarray, decimation: int, threads: int = 1, *, n_steps=None,
              out: np.ndarray | None = None):
        """Runs in one call, looping over them in C (``threads`` > 1: spread over threads).

        ``Z0`` (n_runs x n_z); ``W`` one input set per run (a (n_w x n_steps) matrix or n_w rows,
        see the class docstring; the same arrays may serve several runs: nothing is copied);
        ``theta`` (n_runs x n_theta), or (n_theta,) shared; ``out``: a preallocated
        (n_runs x n_y x n_out) block to write.  Returns ``Y`` (n_runs x n_y x n_out), the final
        states (n_runs x n_z) and ``bad`` (n_runs,): the first output sample of each run with a
        non-finite value (that run stopped there), -1 when all are finite.  Each run is computed
        exactly as alone (same operations, same order), whatever ``threads``.
        """
        z = np.array(Z0, dtype=float, order="C", ndmin=2)
        n_runs = z.shape[0]
        if z.shape[1] != self.nz:
            raise ValueError(f"initial states have {z.shape[1]} entries, the loop has {self.nz}")
        if len(W) != n_runs:
            raise ValueError(f"{len(W)} input sets for {n_runs} runs")
        ptrs = np.empty((max(n_runs, 1), self.nw), dtype=np.uintp)
        strides = np.empty((max(n_runs, 1), self.nw), dtype=np.int64)
        keep = []
        n = n_steps
        for r, w in enumerate(W):
            p, s, rows, n = self.rows(w, n)
            ptrs[r], strides[r] = p, s
            keep.append(rows)
        n = n or 0
        th = np.ascontiguousarray(theta, dtype=float)
        th_stride = 0 if th.ndim == 1 else th.shape[1]
        if th.ndim == 2 and th.shape[0] != n_runs:
            raise ValueError(f"parameters of shape {th.shape} for {n_runs} runs")
        n_out = -(-n // decimation)
        if out is None:
            Y = np.empty((n_runs, self.ny, n_out))
        else:
            Y = out
            if Y.shape != (n_runs, self.ny, n_out) or Y.dtype != np.float64 or not Y.flags.c_contiguous:
                raise ValueError(f"output block of shape {Y.shape}, expected {(n_runs, self.ny, n_out)} float64")
        bad = np.empty(max(n_runs, 1), dtype=np.int64)
        flag = self._batch(n_runs, z.ctypes.data, ptrs.ctypes.data, strides.ctypes.data, th.ctypes.data, th_stride, n,
                           decimation, Y.ctypes.data, bad.ctypes.data, int(threads))
        del keep
        if flag:
            raise RuntimeError(f"compiled run loop returned {flag}")
        return Y, z, bad[:n_runs]


def _row(r) -> np.ndarray:
    """One input row as a contiguous float array; a zero-stride (constant) row as its one value."""
    r = np.asarray(r, dtype=float)
    if r.ndim == 1 and r.shape[0] > 1 and r.strides[0] == 0:
        return r[:1]
    return np.ascontiguousarray(r)


class NonFiniteOutput(ArithmeticError):
    """A run of a compiled loop produced a non-finite output (``run``: its index, ``sample``: the output sample)."""

    def __init__(self, run: int, sample: int):
        super().__init__(f"run {run}: non-finite output at sample {sample}")
        self.run, self.sample = run, sample


@contextlib.contextmanager
def _build_lock(folder: Path | None, stem: str):
    """An exclusive lock on building ``stem`` in the shared cache ``folder`` (``fcntl.flock`` on ``.stem.lock``).

    Yields True when another process held it (it was building the same library: look in the cache again),
    False otherwise.  Two pytest-xdist workers, or two of the tracer's fit processes, that need the same
    library on a fresh machine then build it once; the other waits and loads the published file (verified
    like any cached one).  Without a usable lock (no ``fcntl``, an unwritable folder) each builds, as before:
    the publishing is atomic either way, so this saves processor time and decides nothing.
    """
    fd = None
    waited = False
    try:
        import fcntl

        if folder is not None:
            fd = os.open(folder / f".{stem}.lock", os.O_RDWR | os.O_CREAT, 0o644)
            try:
                fcntl.flock(fd, fcntl.LOCK_EX | fcntl.LOCK_NB)
            except BlockingIOError:
                waited = True
                fcntl.flock(fd, fcntl.LOCK_EX)
    except (ImportError, OSError):
        if fd is not None:
            os.close(fd)
        fd, waited = None, False
    try:
        yield waited
    finally:
        if fd is not None:
            os.close(fd)  # releases the lock


def _find_or_build(functions, stem_tag: str, driver: str, flags: tuple[str, ...], load, edit=None):
    """Generate the C code of ``functions`` (+ ``driver``), find it in the cache (verified) or build it, load it.

    ``load(path, source_sha)`` returns the loaded object, or None when the file
    does not load or is another build's.  Returns ``(object or None, info)``.
    """
    cc = shutil.which(os.environ.get("CC", "gcc")) or shutil.which("cc")
    t0 = time.perf_counter()
    with tempfile.TemporaryDirectory(prefix="thsa-build-") as tmp:
        cg = ca.CodeGenerator(f"{stem_tag}.c", {"with_header": False})
        for f in functions:
            cg.add(f)
        src_path = Path(cg.generate(tmp + os.sep))
        source = src_path.read_text()
        for old, new in _INLINE_MINMAX:
            source = source.replace(old, new)
        if edit is not None:
            source = edit(source)
        source += driver
        source_sha = hashlib.sha256((source + " ".join(flags) + ca.__version__).encode()).hexdigest()
        source += f'\nconst char* thsa_source_sha256(void) {{ return "{source_sha}"; }}\n'
        src_path.write_text(source)
        codegen_s = time.perf_counter() - t0
        info = {"compiled": False, "cached": False, "codegen_s": codegen_s, "compile_s": 0.0, "path": "", "cache": ""}
        stem = f"{stem_tag}_{source_sha[:24]}"
        try:
            shared = cache_dir()
        except OSError as exc:
            shared = None
            _note_once("cache-unwritable", f"compiled-simulator cache folder cannot be created ({exc}): "
                                           "using a temporary folder for this run")

        def cached():
            for where in ("shared", "private"):
                folder = shared if where == "shared" else _private_dir()
                if folder is None:
                    continue
                lib, manifest = folder / f"{stem}.so", folder / f"{stem}.json"
                if lib.exists() and _verified(lib, manifest, source_sha):
                    obj = load(lib, source_sha)
                    if obj is not None:
                        info.update(compiled=True, cached=True, path=str(lib), cache=where)
                        return obj
            return None

        obj = cached()
        if obj is not None:
            return obj, info
        with _build_lock(shared, stem) as waited:
            # another process (a pytest-xdist worker, a tracer's fit process) was building the same library:
            # it is in the cache now, loaded and verified as any cached file (else built here as before)
            obj = cached() if waited else None
            if obj is not None:
                return obj, info
            return _build(cc, flags, tmp, src_path, source_sha, stem, shared, load, info)


def _build(cc, flags, tmp, src_path, source_sha, stem, shared, load, info):
    """Compile the generated source, check the build, publish it to the cache and load it (see _find_or_build)."""
    if cc is None:
        info["error"] = "no C compiler found (set CC)"
        _note_once("no-cc", "no C compiler found (set CC): simulating with casadi's interpreter, "
                            "about 20x slower")
        return None, info
    t1 = time.perf_counter()
    built = Path(tmp) / f"{stem}.so"
    try:
        proc = subprocess.run([cc, *flags, "-fPIC", "-shared", str(src_path), "-o", str(built), "-lm"],
                              capture_output=True, text=True)
        failed = proc.returncode != 0
        error = proc.stderr[-2000:]
    except OSError as exc:
        failed, error = True, str(exc)
    obj = None if failed or not built.is_file() else load(built, source_sha)
    if obj is None:
        info["error"] = error or f"{cc} wrote no loadable library"
        _note_once(f"bad-cc-{cc}", f"the C compiler {cc} did not build a loadable simulator "
                                   f"({(error.strip().splitlines() or ['empty or broken output'])[-1][:200]}): "
                                   "simulating with casadi's interpreter, about 20x slower")
        return None, info
    info["compile_s"] = time.perf_counter() - t1
    lib_sha = _sha256_file(built)
    meta = json.dumps({"source_sha256": source_sha, "library_sha256": lib_sha,
                       "library_size": built.stat().st_size, "casadi": ca.__version__,
                       "compiler": cc, "flags": list(flags)}, indent=1)
    (Path(tmp) / f"{stem}.json").write_text(meta, encoding="utf-8")
    for where in ("shared", "private"):
        folder = shared if where == "shared" else _private_dir()
        if folder is None:
            continue
        lib, manifest = folder / f"{stem}.so", folder / f"{stem}.json"
        try:
            _publish(built, lib)  # library first: a manifest never names a missing library
            _publish(Path(tmp) / f"{stem}.json", manifest)
        except OSError as exc:
            if where == "shared":
                _note_once("cache-unwritable", f"compiled-simulator cache {folder} is not writable "
                                               f"({exc.strerror}): using a temporary folder for this run")
            continue
        loaded = load(lib, source_sha)
        if loaded is not None:
            info.update(compiled=True, path=str(lib), cache=where)
            return loaded, info
    info.update(compiled=True, path=str(built), cache="")
    return obj, info  # loaded from the build folder; the file stays mapped after the folder goes


def compile_run_loop(sample: ca.Function, sample_x: ca.Function, *, flags: tuple[str, ...] = FLAGS):
    """Generate, compile (or find in the cache, verified) and load the run loop.

    The parts of a control period that depend on the parameters alone (``theta``) are
    extracted (``casadi.extract_parametric``) into ``thsa_pre(theta) -> q``, computed once per run;
    the period reads them from ``q`` (the same operations on the same values: the same bits).
    ``sample_x`` must be ``sample`` without its second output.

    Returns
    -------
    loop : RunLoop or None
        None when no working C compiler is available (the caller then uses
        casadi's interpreter; a note says so once on stderr).
    info : dict
        ``{"compiled", "cached", "codegen_s", "compile_s", "path", "cache", "error"?}``;
        ``cache`` is ``"shared"``, ``"private"`` (unwritable cache) or ``""``.
    """
    z, w, theta = sample.sx_in()
    z_next, y = sample.call([z, w, theta])
    nz_out = z_next.numel()
    ret, symbols, parametric = ca.extract_parametric(ca.vertcat(z_next, y), theta)
    q = ca.vertcat(*symbols) if symbols else ca.SX(0, 1)
    par = ca.vertcat(*parametric) if parametric else ca.SX(0, 1)
    # common subexpressions computed once (the same operations on the same values: the same bits)
    opts = {"cse": True}
    f_pre = ca.Function("thsa_pre", [theta], [par], opts)
    f1 = ca.Function("thsa_sample", [z, w, theta, q], [ret[:nz_out], ret[nz_out:]], opts)
    f2 = ca.Function("thsa_sample_x", [z, w, theta, q], [ret[:nz_out]], opts)
    dims = (sample.size1_in(0), sample.size1_in(1), sample.size1_out(1))
    return _find_or_build([f_pre, f1, f2], "thsa_run", _DRIVER, flags, lambda lib, sha: _load(lib, sha, dims),
                          edit=_no_null_checks)


def _no_null_checks(source: str) -> str:
    """The run loop's driver always passes every argument and result buffer, so casadi's check of the
    pointer at every access (``arg[2]? arg[2][90] : 0``, ``if (res[0]!=0) res[0][3]=...``) goes: the
    same arithmetic on the same values (the same bits), 15-20 % less time per period (measured).
    Only the run loop's library is edited; the Functions of :func:`compile_functions` are called by
    casadi, which may pass null pointers."""
    source = re.sub(r"arg\[(\d+)\]\? arg\[\1\]\[(\d+)\] : 0", r"arg[\1][\2]", source)
    return re.sub(r"if \(res\[(\d+)\]!=0\) res\[\1\]\[", r"res[\1][", source)


def _load_external(lib: Path, source_sha: str, names: list[str]):
    """casadi ``external`` Functions of a verified library (its embedded source hash checked first)."""
    try:
        probe = ctypes.CDLL(str(lib))
        fn = probe.thsa_source_sha256
        fn.restype = ctypes.c_char_p
        if fn().decode("ascii", "replace") != source_sha:
            return None
        return [ca.external(n, str(lib)) for n in names]
    except (OSError, AttributeError, RuntimeError):
        return None


def compile_functions(functions: list[ca.Function], tag: str, *, flags: tuple[str, ...] = FLAGS):
    """casadi Functions compiled to C in one library, through the same verified cache as the run loop.

    Returns ``(list of casadi external Functions or None, info)``; None (with a
    note on stderr) when no working C compiler is available, and the caller
    keeps the uncompiled Functions.
    """
    names = [f.name() for f in functions]
    return _find_or_build(list(functions), tag, "", flags, lambda lib, sha: _load_external(lib, sha, names))


def library_files(path: str | os.PathLike) -> dict[str, bytes]:
    """The bytes of a cached library and of its manifest, by file name, to ship to another machine.

    Returns ``{}`` when ``path`` is not a verified library of the cache layout
    (``<tag>_<hash>.so`` with its ``.json`` beside it).
    """
    lib = Path(path)
    manifest = lib.with_suffix(".json")
    try:
        meta = json.loads(manifest.read_text(encoding="utf-8"))
        if not _verified(lib, manifest, meta.get("source_sha256")):
            return {}
        return {lib.name: lib.read_bytes(), manifest.name: manifest.read_bytes()}
    except (OSError, ValueError, AttributeError):
        return {}


def install_library(files: dict[str, bytes]) -> bool:
    """Put shipped library files (:func:`library_files`) into this machine's cache, atomically.

    A library already there and verified is kept.  The shipped bytes are
    checked against their manifest before they are published; whether they
    load here (same architecture, same casadi) is checked when they are used,
    as for any cached file, which rebuilds from the generated source
    otherwise.  Returns True when the library is in the cache.
    """
    libs = [n for n in files if n.endswith(".so") and "/" not in n and not n.startswith(".")]
    if len(libs) != 1 or libs[0][:-3] + ".json" not in files:
        return False
    name = libs[0]
    meta_name = name[:-3] + ".json"
    try:
        meta = json.loads(files[meta_name].decode("utf-8"))
        folder = cache_dir()
    except (OSError, ValueError, UnicodeDecodeError):
        return False
    if not isinstance(meta, dict) or not str(meta.get("source_sha256", "")) or \
            not name.endswith(f"_{str(meta.get('source_sha256'))[:24]}.so"):
        return False
    lib, manifest = folder / name, folder / meta_name
    if lib.exists() and _verified(lib, manifest, meta.get("source_sha256")):
        return True
    data = files[name]
    if len(data) != meta.get("library_size") or hashlib.sha256(data).hexdigest() != meta.get("library_sha256"):
        return False
    with tempfile.TemporaryDirectory(prefix="thsa-ship-") as tmp:
        for n in (name, meta_name):
            (Path(tmp) / n).write_bytes(files[n])
        try:
            _publish(Path(tmp) / name, lib)
            _publish(Path(tmp) / meta_name, manifest)
        except OSError:
            return False
    return True
