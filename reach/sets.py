"""Implicit functions of sets: a set is ``{x : fn(x) <= 0}``, ``fn`` Lipschitz.

The reach-avoid value takes maxima and minima of several such functions, so their *scales* matter: where two
of them meet, the larger decides. Every function here is a signed distance in the units of its coordinates
divided by a per-coordinate ``scale`` (``(x_i - c_i) / scale_i``), which keeps it 1-Lipschitz in scaled
units. Models pick the scales and say which in their docstring.
"""

from __future__ import annotations

from typing import Sequence

from . import backend as B

Array = B.Array

INF = float("inf")


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
    if scale is None:
        scale = [1.0] * len(x)
    out = None
    for xi, l, h, s in zip(x, lo, hi, scale):
        terms = []
        if l != -INF:
            terms.append((l - xi) / s)
        if h != INF:
            terms.append((xi - h) / s)
        for term in terms:
            out = term if out is None else B.maximum(out, term)
    if out is None:
        raise ValueError("box() needs at least one finite bound")
    return out
