"""The inputs of batched queries (a table's values, the safety filter's decisions) checked and converted: numpy or
torch in, float64 numpy arrays out; a wrong shape or a non-finite entry is refused by a ``ValueError`` naming it."""

from __future__ import annotations

import math
import sys
from typing import Any

import numpy as np

from .backend import is_torch


def to_numpy(v: Any) -> tuple[np.ndarray, Any]:
    """``v`` as a float64 numpy array (a copy of a tensor) and the tensor it came from (``None`` for others)."""
    if is_torch(v):
        torch = sys.modules["torch"]
        return v.detach().to("cpu", torch.float64).numpy(), v
    return np.asarray(v, dtype=np.float64), None


def check_finite(arr: np.ndarray, what: str) -> None:
    """Refuse a non-finite entry of the float array ``arr``, naming the first and where it is. A few entries (a
    step's) are checked in Python, cheaper than numpy's call."""
    if all(map(math.isfinite, arr.ravel().tolist())) if arr.size <= 8 else np.isfinite(arr).all():
        return
    bad = ~np.isfinite(arr)
    if arr.ndim == 2:
        row = int(np.nonzero(bad.any(axis=1))[0][0])
        where = f"{arr[row].tolist()} at row {row}"
    elif arr.ndim == 1:
        i = int(np.nonzero(bad)[0][0])
        where = f"{float(arr[i])!r} at index {i}"
    else:
        where = repr(float(arr))
    raise ValueError(f"{what} must be finite, got {where}")


def points(x: Any, n: int, what: str = "x", names: Any = None) -> tuple[np.ndarray, bool, Any]:
    """``x``, ``(N, n)`` or one point ``(n,)``, as ``(N, n)`` rows: ``(rows, whether one point, the tensor it came
    from or None)``; ``names`` (of the ``n`` axes) go into the message of a wrong shape."""
    arr, tensor = to_numpy(x)
    single = arr.ndim == 1
    if single:
        arr = arr[None, :]
    if arr.ndim != 2 or arr.shape[1] != n:
        axes = f" ({', '.join(names)})" if names else ""
        raise ValueError(f"{what} must have shape (N, {n}) or ({n},){axes}, got {tuple(np.shape(x))}")
    check_finite(arr, what)
    return arr, single, tensor


def column(v: Any, N: int, what: str) -> np.ndarray:
    """``v``, a scalar or ``N`` values, as ``(N,)``."""
    arr = to_numpy(v)[0].reshape(-1)
    if arr.size == 1:
        arr = np.full(N, float(arr[0]))
    if arr.shape != (N,):
        raise ValueError(f"{what} must be a scalar or have shape ({N},), got {tuple(np.shape(v))}")
    check_finite(arr, what)
    return arr
