"""Implicit functions of sets: a set is ``{x : fn(x) <= 0}``, ``fn`` Lipschitz.

The reach-avoid value takes maxima and minima of several such functions, so their *scales* matter: where two
of them meet, the larger decides. Every function here is a signed distance in the units of its coordinates
divided by a per-coordinate ``scale`` (``(x_i - c_i) / scale_i``), which keeps it 1-Lipschitz in scaled
units. Models pick the scales and say which in their docstring.
"""

from __future__ import annotations

from typing import Sequence

import numpy as np

from . import backend as B

Array = B.Array

INF = float("inf")
_ndarray = np.ndarray


def box(x: Sequence[Array], lo: Sequence[float], hi: Sequence[float], scale: Sequence[float] | None = None) -> Array:
    """Implicit function of the box ``{lo <= x <= hi}`` in the max (Chebyshev) form.

    Components with ``lo = -inf`` or ``hi = +inf`` are unbounded on that side. ``x`` is a sequence of arrays
    (one per coordinate, broadcastable); the result broadcasts over them.

    :param x: state components
    :param lo: lower bounds per component
    :param hi: upper bounds per component
    :param scale: positive divisor per component (default 1)
    :return: ``max_i max((lo_i - x_i)/s_i, (x_i - hi_i)/s_i)``; negative strictly inside
    """
    # max_i max(lo_i - x_i, x_i - hi_i) / s_i: dividing by s_i > 0 is monotone (after rounding too), so each
    # component is divided once rather than each term, and without scales once in all: the same values.
    out = None
    for xi, l, h, s in zip(x, lo, hi, (1.0,) * len(lo) if scale is None else scale):  # a tuple: torch.compile traces it
        if l != -INF:
            term = B.maximum(l - xi, xi - h) if h != INF else l - xi
        elif h != INF:
            term = xi - h
        else:
            continue
        if scale is not None:
            if s > 0:
                term = term / s
            else:  # s <= 0 is no valid scale: each side divided by s, then the larger (no check here)
                term = _max_terms((l - xi) / s if l != -INF else None, (xi - h) / s if h != INF else None)
        out = term if out is None else B.maximum(out, term)
    if out is None:
        raise ValueError("box() needs at least one finite bound")
    if scale is None and not (type(out) is _ndarray and out.dtype.kind == "f"):
        out = out / 1.0  # the default scale 1: integer inputs give a float result, as with a scale
    return out


def _max_terms(a, b):
    """The larger of two terms, either of which may be missing (``None``)."""
    if a is None:
        return b
    return a if b is None else B.maximum(a, b)
