"""Array aliases used in the signatures of :mod:`linearization`.

Imports numpy only; never imports ``thsa_control``.
"""

from __future__ import annotations

import numpy as np
import numpy.typing as npt

__all__ = ["Float1D", "Float2D", "Float3D", "Complex2D", "ArrayLike"]

#: One-dimensional float array (a vector of named signals).
Float1D = npt.NDArray[np.float64]
#: Two-dimensional float array (a matrix, or column-stacked points).
Float2D = npt.NDArray[np.float64]
#: Three-dimensional float array (a stack of matrices, point index first).
Float3D = npt.NDArray[np.float64]
#: Two-dimensional complex array (point x frequency).
Complex2D = npt.NDArray[np.complex128]
#: Anything numpy can turn into a float array.
ArrayLike = npt.ArrayLike
