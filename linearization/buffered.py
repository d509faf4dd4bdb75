"""Evaluate a casadi Function straight into numpy arrays (casadi's buffer interface).

Calling a casadi ``Function`` on numpy arrays returns ``DM`` objects; turning a ``DM`` into a numpy array goes
through a Python list of its elements (``DM.full``), about 0.1 us per element, which for a mapped call over a
grid or a Jacobian of a few thousand entries costs more than the evaluation itself.  :func:`call_dense`
evaluates the same Function with casadi's ``Function.buffer`` instead: the arguments are read from, and the
results written to, numpy memory.  The numbers are the same, bit for bit (the same evaluation; only the copy
differs).

Examples
--------
>>> import casadi as ca, numpy as np
>>> x = ca.SX.sym("x", 2)
>>> f = ca.Function("f", [x], [ca.vertcat(x[0] * x[1], x[0] + x[1])])
>>> out, = call_dense(f, np.array([2.0, 3.0]))
>>> out.ravel().tolist()
[6.0, 5.0]
"""

from __future__ import annotations

import casadi as ca
import numpy as np

__all__ = ["call_dense"]


def call_dense(f: ca.Function, *args) -> list[np.ndarray]:
    """``f(*args)`` as numpy arrays, each of its output's shape ``(rows, columns)``.

    Through casadi's buffer interface when every argument has exactly its input's size and every input and
    output is dense; otherwise (a broadcast argument, a sparse input or output, a casadi without the buffer
    interface) through an ordinary call, converted with :func:`numpy.asarray` (sparse outputs densified).
    The values are the same either way.
    """
    if len(args) != f.n_in():
        raise ValueError(f"{f.name()} takes {f.n_in()} arguments, got {len(args)}")
    flat = []
    for i, a in enumerate(args):
        a = np.asarray(a, dtype=float)
        shape = f.size_in(i)
        vector = 1 in shape
        fits = a.size == f.numel_in(i) and (a.shape == shape or (vector and (a.ndim <= 1 or 1 in a.shape)))
        if not fits or a.ndim > 2 or not f.sparsity_in(i).is_dense():
            return _plain(f, args)
        # casadi's dense layout is column-major: a (rows, columns) array read column by column
        flat.append(np.ascontiguousarray(a.ravel(order="F")))
    if not all(f.sparsity_out(j).is_dense() for j in range(f.n_out())) or not hasattr(f, "buffer"):
        return _plain(f, args)
    outs = [np.empty(f.numel_out(j)) for j in range(f.n_out())]
    buf, trigger = f.buffer()
    for i, a in enumerate(flat):
        buf.set_arg(i, memoryview(a))
    for j, o in enumerate(outs):
        buf.set_res(j, memoryview(o))
    trigger()
    return [o.reshape(f.size_out(j), order="F") for j, o in enumerate(outs)]


def _plain(f: ca.Function, args) -> list[np.ndarray]:
    res = f(*args)
    res = [res] if f.n_out() == 1 else list(res)
    return [np.asarray(ca.densify(r), dtype=float).reshape(f.size_out(j)) for j, r in enumerate(res)]
