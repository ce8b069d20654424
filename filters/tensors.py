"""Inputs of :meth:`~softreach.filters.ValueFilter.filter` checked and converted: numpy or torch in, the same out."""

from __future__ import annotations

import math
import sys
from typing import Any

import numpy as np

from softreach.reach.backend import is_torch


def to_numpy(v: Any) -> tuple[np.ndarray, Any]:
    """A float64 numpy copy of ``v`` and the tensor it came from (``None`` for non-tensors)."""
    if is_torch(v):
        torch = sys.modules["torch"]
        return v.detach().to("cpu", torch.float64).numpy(), v
    return np.asarray(v, dtype=np.float64), None


def finite(arr: np.ndarray) -> bool:
    """Whether every entry of ``arr`` (float) is finite; a step's few in Python, cheaper than numpy's call."""
    if arr.size <= 8:
        return all(map(math.isfinite, arr.ravel().tolist()))
    return bool(np.isfinite(arr).all())


def clip_unit(a: np.ndarray) -> np.ndarray:
    """``a`` clipped to ``[-1, 1]`` (the normalised action range) in its own dtype, without ``np.clip``'s wrapper."""
    return np.minimum(np.maximum(a, a.dtype.type(-1.0)), a.dtype.type(1.0))


def first_bad(arr: np.ndarray) -> str:
    """The first non-finite entry of ``arr`` and where it is, for an error message."""
    bad = ~np.isfinite(arr)
    if arr.ndim == 2:
        row = int(np.nonzero(bad.any(axis=1))[0][0])
        return f"{arr[row].tolist()} at row {row}"
    if arr.ndim == 1:
        i = int(np.nonzero(bad)[0][0])
        return f"{arr[i]!r} at index {i}"
    return repr(float(arr))


def to_torch(applied: np.ndarray, info: dict[str, Any], ref: Any, action: Any):
    """Convert the outputs to tensors on the reference tensor's device, in its floating dtype."""
    torch = sys.modules["torch"]
    dtype = ref.dtype if ref.dtype.is_floating_point else torch.float32
    dtype_a = action.dtype if is_torch(action) and action.dtype.is_floating_point else dtype
    kinds = {"active": torch.bool, "reason": torch.int64, "optimal_action": dtype_a}
    dev = ref.device
    out = {key: torch.as_tensor(np.asarray(v), dtype=kinds.get(key, dtype), device=dev) for key, v in info.items()}
    return torch.as_tensor(np.asarray(applied), dtype=dtype_a, device=dev), out


def batch_inputs(t: Any, x: Any, z: Any, action: Any | None, n: int, m: int, state_names: Any):
    """The filter's inputs as a float64 numpy batch ``(t (N,), x (N, n), z (N,), action (N, m) or None, single, ref)``;
    ``single``: ``x`` was one state; ``ref``: the tensor the outputs follow (``None``: numpy). ``ValueError`` names a
    wrong shape or a non-finite entry."""
    xs, x_tensor = to_numpy(x)
    single = xs.ndim == 1
    if single:
        xs = xs[None, :]
    if xs.ndim != 2 or xs.shape[1] != n:
        raise ValueError(f"x must have shape (N, {n}) or ({n},) (states {state_names}), got {tuple(np.shape(x))}")
    N = len(xs)
    cols = []
    for name, v in (("t", t), ("z", z)):
        arr = to_numpy(v)[0].reshape(-1)
        if arr.size == 1:
            arr = np.full(N, float(arr[0]))
        if arr.shape != (N,):
            raise ValueError(f"{name} must be a scalar or have shape ({N},), got {tuple(np.shape(v))}")
        cols.append(arr)
    tt, zz = cols
    for name, arr in (("x", xs), ("t", tt), ("z", zz)):
        if not finite(arr):
            raise ValueError(f"{name} must be finite, got {first_bad(arr)}")
    act = tensor = None
    if action is not None:
        act, tensor = to_numpy(action)
        if act.ndim == 1 and single:
            act = act[None, :]
        if act.ndim != 2 or act.shape != (N, m):
            raise ValueError(f"action must have shape ({N}, {m})" + (f" or ({m},)" if single else "")
                             + f" to match x, got {tuple(np.shape(action))}")
        if not finite(act):
            raise ValueError(f"action must be finite, got {first_bad(act)}")
    ref = tensor if tensor is not None else x_tensor
    return tt, xs, zz, act, single, ref
