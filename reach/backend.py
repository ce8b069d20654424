"""Array backends: numpy and torch share one code path.

The solver and the models are written against the small set of operations that numpy and torch spell the
same way (``+ - * /``, ``abs``, ``where``, ``sin``, ...). The few that differ live here, so that models
stay backend-agnostic and a torch tensor on a GPU never makes a round trip through numpy.
"""

from __future__ import annotations

import sys
from typing import Any

import numpy as np

Array = Any


def _loaded_torch():
    """torch if some module has imported it, else ``None``: no tensor exists before torch is imported, so the
    numpy-only users (the envs) never pay torch's import."""
    return sys.modules.get("torch")


def _import_torch():
    """torch, imported now if needed; a clear error where it is not installed."""
    try:
        import torch
    except ImportError as err:  # pragma: no cover - exercised only without torch
        raise ImportError("backend='torch' needs PyTorch; install softreach with its base dependencies") from err
    return torch

_ndarray = np.ndarray
#: numpy's ``clip`` ufunc: ``np.clip`` of a float array with two bounds ends in it after a few Python-level
#: dispatch steps that cost more than the clip itself on small arrays (``None`` where numpy does not expose it)
_clip_ufunc = getattr(getattr(getattr(np, "_core", None), "umath", None), "clip", None)


def is_torch(x: Any) -> bool:
    """:return: whether ``x`` is a torch tensor."""
    torch = sys.modules.get("torch")
    return torch is not None and isinstance(x, torch.Tensor)


def namespace(*xs: Any):
    """The array module (``numpy`` or ``torch``) that the first array argument belongs to."""
    for x in xs:
        if is_torch(x):
            return _loaded_torch()
    return np


def maximum(a: Array, b: Array | float) -> Array:
    """Elementwise max; ``b`` may be a Python scalar (``torch.maximum`` refuses scalars)."""
    if type(a) is _ndarray and (type(b) is _ndarray or type(b) is float):  # the common numpy case, checked first
        return np.maximum(a, b)
    if is_torch(a) or is_torch(b):
        torch = _loaded_torch()
        if not is_torch(a):
            a, b = b, a
        if not is_torch(b):
            return torch.clamp(a, min=float(b))
        return torch.maximum(a, b)
    return np.maximum(a, b)


def minimum(a: Array, b: Array | float) -> Array:
    """Elementwise min; ``b`` may be a Python scalar."""
    if type(a) is _ndarray and (type(b) is _ndarray or type(b) is float):
        return np.minimum(a, b)
    if is_torch(a) or is_torch(b):
        torch = _loaded_torch()
        if not is_torch(a):
            a, b = b, a
        if not is_torch(b):
            return torch.clamp(a, max=float(b))
        return torch.minimum(a, b)
    return np.minimum(a, b)


def clip(a: Array, lo: float, hi: float) -> Array:
    """Elementwise clip to ``[lo, hi]``."""
    if (_clip_ufunc is not None and type(a) is _ndarray and a.dtype.kind == "f" and lo is not None
            and hi is not None):
        return _clip_ufunc(a, lo, hi)  # what np.clip calls for a float array and two bounds, without the detour
    if is_torch(a):
        return _loaded_torch().clamp(a, min=lo, max=hi)
    return np.clip(a, lo, hi)


def where(cond: Array, a: Array | float, b: Array | float) -> Array:
    """``where`` that accepts Python scalars for either branch under both backends."""
    if is_torch(cond):
        torch = _loaded_torch()
        if not is_torch(a):
            a = torch.as_tensor(a, dtype=_float_dtype(b, cond), device=cond.device)
        if not is_torch(b):
            b = torch.as_tensor(b, dtype=a.dtype, device=cond.device)
        return torch.where(cond, a, b)
    return np.where(cond, a, b)


def _float_dtype(other: Any, cond: Any):
    if is_torch(other):
        return other.dtype
    return _loaded_torch().get_default_dtype()


def concatenate(arrays: list[Array], axis: int) -> Array:
    """Concatenate along ``axis``."""
    if is_torch(arrays[0]):
        return _loaded_torch().cat(arrays, dim=axis)
    return np.concatenate(arrays, axis=axis)


def to_numpy(x: Array) -> np.ndarray:
    """A numpy view or copy of ``x`` (copies only off the CPU)."""
    if is_torch(x):
        return x.detach().cpu().numpy()
    return np.asarray(x)


def max_value(x: Array | float) -> float:
    """The maximum of ``x`` as a Python float (a scalar passes through)."""
    if isinstance(x, (int, float)):
        return float(x)
    if is_torch(x):
        return float(x.max().item())
    return float(np.max(x))


def resolve_dtype(backend: str, dtype: str):
    """Map ``("torch"|"numpy", "float32"|"float64")`` to the backend's dtype object."""
    if dtype not in ("float32", "float64"):
        raise ValueError(f"dtype must be 'float32' or 'float64', got {dtype!r}")
    if backend == "torch":
        return getattr(_import_torch(), dtype)
    if backend == "numpy":
        return np.dtype(dtype)
    raise ValueError(f"backend must be 'numpy' or 'torch', got {backend!r}")


def asarray(x: Any, backend: str, dtype: str = "float64", device: str = "cpu") -> Array:
    """Convert ``x`` to an array of the chosen backend, dtype and device."""
    dt = resolve_dtype(backend, dtype)
    if backend == "torch":
        torch = _import_torch()
        if device.startswith("cuda") and not torch.cuda.is_available():
            raise RuntimeError(f"device={device!r} was requested but torch sees no CUDA device")
        return torch.as_tensor(np.asarray(x) if not is_torch(x) else x, dtype=dt, device=device)
    if device != "cpu":
        raise ValueError(f"the numpy backend runs on the CPU only; got device={device!r} (use backend='torch')")
    return np.asarray(x, dtype=dt)


def __getattr__(name: str) -> Any:
    """``backend.torch``: the torch module, imported on first use (the solver's torch paths read it)."""
    if name == "torch":
        return _import_torch()
    raise AttributeError(f"module {__name__!r} has no attribute {name!r}")
