"""The inputs and outputs of :meth:`~softreach.filters.ValueFilter.filter`: numpy or torch in, the same out."""

from __future__ import annotations

import sys
from typing import Any

import numpy as np

from softreach.reach.backend import is_torch
from softreach.reach.inputs import check_finite, column, points, to_numpy


def clip_unit(a: np.ndarray) -> np.ndarray:
    """``a`` clipped to ``[-1, 1]`` (the normalised action range) in its own dtype, without ``np.clip``'s wrapper; the
    bounds are Python floats, cheaper than numpy scalars made at each call (numpy before 2 may promote a 0-d ``a``)."""
    return np.minimum(np.maximum(a, -1.0), 1.0).astype(a.dtype, copy=False)


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
    wrong shape or a non-finite entry (:mod:`softreach.reach.inputs`)."""
    xs, single, x_tensor = points(x, n, "x", state_names)
    N = len(xs)
    tt, zz = column(t, N, "t"), column(z, N, "z")
    act = tensor = None
    if action is not None:
        act, tensor = to_numpy(action)
        if act.ndim == 1 and single:
            act = act[None, :]
        if act.shape != (N, m):
            raise ValueError(f"action must have shape ({N}, {m})" + (f" or ({m},)" if single else "")
                             + f" to match x, got {tuple(np.shape(action))}")
        check_finite(act, "action")
    return tt, xs, zz, act, single, tensor if tensor is not None else x_tensor
