"""Upwind approximations of first derivatives: first order, ENO2, WENO3 and WENO5.

Each scheme maps the first differences ``D_k = (u_{k+1} - u_k) / dx`` of a padded line to the left (``D-``) and
right (``D+``) derivatives at every node. Formulas follow Osher & Fedkiw, *Level Set Methods* (2003), §3.3-3.4.
Arrays are numpy or torch; slicing is along one axis and everything else broadcasts.
"""

from __future__ import annotations

from typing import Callable

from .. import backend as B

Array = B.Array


def _take(u: Array, axis: int, start: int, stop: int) -> Array:
    index = [slice(None)] * u.ndim
    index[axis] = slice(start, stop)
    return u[tuple(index)]


def pad(u: Array, axis: int, width: int, boundary: str) -> Array:
    """Add ``width`` ghost nodes at both ends of ``axis``.

    :param boundary: ``"periodic"``; ``"extrapolate"`` (linear); ``"extrapolate_away"`` (linear, with the slope's
        sign chosen so that ghost values move away from zero: where the edge value is positive, the ghosts are
        positive and rising, so no safe set can enter through the boundary); ``"constant"`` (the edge value); or a
        pair ``(rule at the low end, rule at the high end)`` of the non-periodic rules
    """
    n = u.shape[axis]
    if boundary == "periodic":
        return B.concatenate([_take(u, axis, n - width, n), u, _take(u, axis, 0, width)], axis)
    lo_rule, hi_rule = (boundary, boundary) if isinstance(boundary, str) else boundary
    first, second = _take(u, axis, 0, 1), _take(u, axis, 1, 2)
    last, before = _take(u, axis, n - 1, n), _take(u, axis, n - 2, n - 1)
    left = [ghost(lo_rule, first, second, k) for k in range(width, 0, -1)]
    right = [ghost(hi_rule, last, before, k) for k in range(1, width + 1)]
    return B.concatenate(left + [u] + right, axis)


def ghost(rule: str, edge: Array, inner: Array, k: int) -> Array:
    """The ``k``-th ghost value (``k = 1`` next to the edge) beyond an end with values ``edge``, then ``inner``,
    under a non-periodic ``rule`` of :func:`pad`."""
    return edge + k * _ghost_slope(rule, edge, edge - inner)


def _ghost_slope(rule: str, edge: Array, slope: Array) -> Array:
    """The outward step of the ghost values at one end under ``rule`` (see :func:`pad`)."""
    if rule == "extrapolate":
        return slope
    if rule == "extrapolate_away":
        return abs(slope) * B.where(edge >= 0, 1.0 + 0 * edge, -1.0 + 0 * edge)
    if rule == "constant":
        return 0 * slope
    raise ValueError(f"unknown boundary {rule!r}; use 'extrapolate', 'extrapolate_away', 'constant' or 'periodic'")


def first_order(d: list[Array]) -> tuple[Array, Array]:
    """One-sided differences. ``d[k]`` is ``D`` shifted by ``k`` (ghost width 1)."""
    return d[0], d[1]


def eno2(d: list[Array]) -> tuple[Array, Array]:
    """Second-order ENO (ghost width 2): the smoother of two parabolas."""
    dm, dp = d[1], d[2]
    c_left = _smaller(d[1] - d[0], d[2] - d[1])
    c_right = _smaller(d[2] - d[1], d[3] - d[2])
    return dm + 0.5 * c_left, dp - 0.5 * c_right


def _smaller(a: Array, b: Array) -> Array:
    return B.where(abs(a) <= abs(b), a, b)


def weno3(d: list[Array]) -> tuple[Array, Array]:
    """Third-order WENO (ghost width 2)."""
    return _weno3_side(d[0], d[1], d[2]), _weno3_side(d[3], d[2], d[1])


def _weno3_side(v1: Array, v2: Array, v3: Array, eps: float = 1e-6) -> Array:
    phi1 = 0.5 * (3 * v2 - v1)
    phi2 = 0.5 * (v2 + v3)
    a1 = (1.0 / 3.0) / (eps + (v2 - v1) ** 2) ** 2
    a2 = (2.0 / 3.0) / (eps + (v3 - v2) ** 2) ** 2
    return (a1 * phi1 + a2 * phi2) / (a1 + a2)


def weno5(d: list[Array]) -> tuple[Array, Array]:
    """Fifth-order WENO of Jiang & Peng (ghost width 3)."""
    return _weno5_side(d[0], d[1], d[2], d[3], d[4]), _weno5_side(d[5], d[4], d[3], d[2], d[1])


SIXTH = 1.0 / 6.0


def _weno5_side(v1: Array, v2: Array, v3: Array, v4: Array, v5: Array) -> Array:
    # the three parabolas' values over their common denominator, times its reciprocal: a division by a constant
    # costs a GPU or a CPU core several times a product
    phi1 = (2 * v1 - 7 * v2 + 11 * v3) * SIXTH
    phi2 = (-v2 + 5 * v3 + 2 * v4) * SIXTH
    phi3 = (2 * v3 + 5 * v4 - v5) * SIXTH
    s1 = 13.0 / 12 * (v1 - 2 * v2 + v3) ** 2 + 0.25 * (v1 - 4 * v2 + 3 * v3) ** 2
    s2 = 13.0 / 12 * (v2 - 2 * v3 + v4) ** 2 + 0.25 * (v2 - v4) ** 2
    s3 = 13.0 / 12 * (v3 - 2 * v4 + v5) ** 2 + 0.25 * (3 * v3 - 4 * v4 + v5) ** 2
    # scale-aware epsilon (Osher & Fedkiw eq. 3.38) so that the weights do not depend on the value's units
    # (the floor must stay representable in float32, where 1e-99 would underflow to 0 and give 0/0)
    eps = 1e-6 * B.maximum(B.maximum(B.maximum(v1 * v1, v2 * v2), B.maximum(v3 * v3, v4 * v4)), v5 * v5) + 1e-12
    a1 = 0.1 / (s1 + eps) ** 2
    a2 = 0.6 / (s2 + eps) ** 2
    a3 = 0.3 / (s3 + eps) ** 2
    return (a1 * phi1 + a2 * phi2 + a3 * phi3) / (a1 + a2 + a3)


#: name -> (ghost width, function of the shifted first differences)
SCHEMES: dict[str, tuple[int, Callable[[list[Array]], tuple[Array, Array]]]] = {
    "first": (1, first_order),
    "eno2": (2, eno2),
    "weno3": (2, weno3),
    "weno5": (3, weno5),
}


def upwind_derivatives(u: Array, axis: int, dx: float, scheme: str = "weno5", boundary: str = "extrapolate_away") -> tuple[Array, Array]:
    """Left and right derivative approximations of ``u`` along ``axis``.

    :param u: values on the grid
    :param axis: axis to differentiate along
    :param dx: grid spacing along ``axis``
    :param scheme: one of :data:`SCHEMES`
    :param boundary: see :func:`pad`
    :return: ``(D- u, D+ u)`` with the shape of ``u``
    """
    try:
        width, fn = SCHEMES[scheme]
    except KeyError:
        raise ValueError(f"unknown scheme {scheme!r}; choose from {sorted(SCHEMES)}") from None
    n = u.shape[axis]
    if n < width + 1 and boundary != "periodic":
        raise ValueError(f"scheme {scheme!r} needs at least {width + 1} nodes along axis {axis}, got {n}")
    up = pad(u, axis, width, boundary)
    # times 1/dx, as the compiled loops (reach/numerics/fused.py) multiply: both round alike
    diff = (_take(up, axis, 1, n + 2 * width) - _take(up, axis, 0, n + 2 * width - 1)) * (1.0 / dx)
    shifts = [_take(diff, axis, k, k + n) for k in range(2 * width)]
    return fn(shifts)
