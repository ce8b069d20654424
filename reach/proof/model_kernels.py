"""A model's compiled enclosure and set maxima as the safety filter calls them, through a C callback's address
(:func:`held_box_address`, :func:`set_max_address`): numba keys its disk cache by a function argument's identity, so
an argument would compile again in every process. Also the set-maximum kernel of box-distance sets."""

from __future__ import annotations

import math
from typing import Any

import numba as nb
import numpy as np
from llvmlite import ir
from numba import types
from numba.extending import intrinsic

from .blocks import default_threads, run_in_blocks
from ..jit import njit

_P = types.CPointer(types.float64)
#: the fewest rows an enclosure thread takes: enough that a row's cost outweighs handing a block to a thread
ENCLOSE_MIN_ROWS = 4096
#: the C signature of :func:`held_box_address`'s callbacks: ``(params, x_lo, x_hi, a, s0, s1, lo, hi)``
HELD_BOX_SIGNATURE = types.void(_P, _P, _P, _P, types.float64, types.float64, _P, _P)
_CALLBACKS: dict[Any, Any] = {}


def held_box_address(model: Any) -> int:
    """The address of a C callback running ``model.held_box_kernel`` for :func:`call_held_box` (built once)."""
    kernel, n, m, k = model.held_box_kernel, model.state_dim, model.control_dim, len(model.held_box_params)
    key = (kernel, n, m, k)
    if key not in _CALLBACKS:
        @nb.cfunc(HELD_BOX_SIGNATURE)
        def callback(params, x_lo, x_hi, a, s0, s1, lo, hi):
            kernel(nb.carray(params, k), nb.carray(x_lo, n), nb.carray(x_hi, n), nb.carray(a, m), s0, s1,
                   nb.carray(lo, n), nb.carray(hi, n))

        _CALLBACKS[key] = callback  # kept alive: its address is used by compiled code
    return _CALLBACKS[key].address


def _call_by_address(returns: Any):
    """Code calling the C function at the first argument's address with the others (arrays as data pointers)."""
    def codegen(context, builder, signature, args):
        values = [context.make_array(ty)(context, builder, val).data if isinstance(ty, types.Array) else val
                  for ty, val in zip(signature.args[1:], args[1:])]
        ret = ir.VoidType() if returns is None else context.get_value_type(returns)
        fn = builder.inttoptr(args[0], ir.FunctionType(ret, [v.type for v in values]).as_pointer())
        out = builder.call(fn, values)
        return context.get_dummy_value() if returns is None else out

    return codegen


@intrinsic
def call_held_box(typingctx, address, params, x_lo, x_hi, a, s0, s1, lo, hi):
    """Call the callback at ``address`` (:func:`held_box_address`) on contiguous 1-d arrays, filling ``lo``, ``hi``."""
    return types.void(address, params, x_lo, x_hi, a, s0, s1, lo, hi), _call_by_address(None)


@njit(nogil=True)
def held_box_rows(address, params, x_lo, x_hi, a, s0, s1, lo, hi):
    """:func:`call_held_box` for every row (2-d C-contiguous arrays; ``s0``, ``s1`` one time per row)."""
    for r in range(x_lo.shape[0]):
        call_held_box(address, params, x_lo[r], x_hi[r], a[r], s0[r], s1[r], lo[r], hi[r])


def held_boxes(model: Any, x_lo: Any, x_hi: Any, a: Any, s0: Any, s1: Any) -> tuple[np.ndarray, np.ndarray]:
    """``(lo, hi)`` holding every state at some time in ``[s0, s1]`` of a held period from ``[x_lo, x_hi]``, by the
    filter's own ``held_box_kernel``; ``s0``, ``s1`` broadcast against the rows (``(P, 1)``: per piece and row)."""
    n, m = model.state_dim, model.control_dim
    x_lo, x_hi, a = (np.asarray(v, dtype=np.float64) for v in (x_lo, x_hi, a))
    shape = np.broadcast_shapes(x_lo.shape[:-1], x_hi.shape[:-1], a.shape[:-1], np.shape(s0), np.shape(s1))

    def rows(v: Any, k: int) -> np.ndarray:
        return np.ascontiguousarray(np.broadcast_to(v, shape + (k,)).reshape(-1, k))

    size = int(np.prod(shape))
    lo, hi = np.empty((size, n)), np.empty((size, n))
    address, params = held_box_address(model), np.ascontiguousarray(model.held_box_params, dtype=np.float64)
    args = (rows(x_lo, n), rows(x_hi, n), rows(a, m), rows(np.asarray(s0, dtype=np.float64)[..., None], 1)[:, 0],
            rows(np.asarray(s1, dtype=np.float64)[..., None], 1)[:, 0], lo, hi)
    # the rows are independent and the loop releases the GIL: one block a thread
    run_in_blocks(lambda i, j: held_box_rows(address, params, *(v[i:j] for v in args)), size, default_threads(),
                  ENCLOSE_MIN_ROWS)
    return lo.reshape(shape + (n,)), hi.reshape(shape + (n,))


#: the index of each set function in a set-maximum kernel's ``which``
SET_INDEX = {"target": 0, "hard_constraint": 1, "soft_constraint": 2}
#: the C signature of :func:`set_max_address`'s callbacks: ``(params, which, lo, hi) -> largest value``
SET_MAX_SIGNATURE = types.float64(_P, types.int64, _P, _P)


@njit(inline="always")
def box_distance_max(params, offset, lo, hi):
    """The largest value over ``[lo, hi]`` of :func:`~softreach.reach.sets.box` with bounds and scales from
    ``params[offset:]``, exactly its largest at the corners; ``-inf`` if no axis is bounded, NaN for a failed box."""
    n = len(lo)
    out = -np.inf
    for a in range(n):
        b_lo, b_hi, scale = params[offset + a], params[offset + n + a], params[offset + 2 * n + a]
        if b_lo != -np.inf:
            term = max(b_lo - lo[a], hi[a] - b_hi) if b_hi != np.inf else b_lo - lo[a]
        elif b_hi != np.inf:
            term = hi[a] - b_hi
        else:
            continue
        if math.isnan(term):
            return np.nan
        out = max(out, term / scale)
    return out


@njit
def boxes_set_max(params, which, lo, hi):
    """The set-maximum kernel of a model whose sets are all box distances (:func:`box_params`)."""
    return box_distance_max(params, 3 * len(lo) * which, lo, hi)


def box_params(boxes: dict[str, Any], n: int) -> np.ndarray:
    """:func:`boxes_set_max`'s numbers for ``{"target": (lo, hi[, scale]), ...}``; scale 1 by default (exact)."""
    out = []
    for name in SET_INDEX:
        box = boxes[name]
        scale = box[2] if len(box) > 2 else (1.0,) * n
        for part in (box[0], box[1], scale):
            if len(part) != n:
                raise ValueError(f"set box {name!r}: {part!r} has {len(part)} entries for {n} state components")
            out.extend(float(v) for v in part)
    return np.array(out, dtype=np.float64)


def set_max_address(model: Any) -> int:
    """The address of a C callback running ``model.set_max_kernel`` for :func:`call_set_max` (built once)."""
    kernel, n, k = model.set_max_kernel, model.state_dim, len(model.set_max_params)
    key = ("sets", kernel, n, k)
    if key not in _CALLBACKS:
        @nb.cfunc(SET_MAX_SIGNATURE)
        def callback(params, which, lo, hi):
            return kernel(nb.carray(params, k), which, nb.carray(lo, n), nb.carray(hi, n))

        _CALLBACKS[key] = callback  # kept alive: its address is used by compiled code
    return _CALLBACKS[key].address


@intrinsic
def call_set_max(typingctx, address, params, which, lo, hi):
    """Call the callback at ``address`` (:func:`set_max_address`): set ``which``'s largest value over ``[lo, hi]``."""
    return types.float64(address, params, which, lo, hi), _call_by_address(types.float64)


@njit
def set_max_rows(address, params, which, lo, hi, out):
    """:func:`call_set_max` for every row of ``lo``, ``hi`` (``(N, n)``, C-contiguous)."""
    for r in range(lo.shape[0]):
        out[r] = call_set_max(address, params, which, lo[r], hi[r])
