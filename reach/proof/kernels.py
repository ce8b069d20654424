"""Compiled loops behind the safety filter's decisions, one row at a time, where numpy's fixed cost per call would
dwarf the arithmetic: the table's interpolant at a point and the certificate at a state, which rank; the cells'
cover test and plans (:mod:`softreach.reach.proof.cell_certificate`), which prove. They allocate nothing, so the
compiled decision (:mod:`softreach.filters.compiled`) runs them without numba's reference counting (``_nrt=False``)."""

from __future__ import annotations

import math

import numpy as np

from ..jit import njit

#: tolerance of the grid checks [cells] and time-span checks [s] (:data:`softreach.reach.tables.interpolation.TOL`)
TOL = 1e-9


def frozen(a: np.ndarray) -> np.ndarray:
    """A read-only view of ``a``: numba compiles once per writability, so loaded (memory-mapped) and made arrays
    both reach the loops read-only, and each loop compiles once."""
    view = np.asarray(a).view()
    view.flags.writeable = False
    return view


@njit(inline="always")
def snapshot(times, t):
    """``(k, wt)``: the snapshot interval ``[times[k], times[k + 1]]`` of ``t`` and the later snapshot's weight,
    clamped to ``[0, 1]`` (:func:`softreach.reach.tables.interpolation.snapshot_pair`)."""
    n_t = len(times)
    if n_t == 1:
        return 0, 0.0
    t_first, t_last = times[0], times[n_t - 1]
    if t_first <= t < t_last:
        # the last snapshot at or before t, guessed as if evenly spaced, the walk exact for any spacing
        k = min(int((t - t_first) / (t_last - t_first) * (n_t - 1)), n_t - 2)
        while times[k] > t:
            k -= 1
        while times[k + 1] <= t:
            k += 1
    else:
        k = np.searchsorted(times, t, side="right") - 1
        k = min(max(k, 0), n_t - 2)
    t0 = times[k]
    wt = min(max((t - t0) / (times[k + 1] - t0), 0.0), 1.0)
    return k, wt


@njit(forceinline=True)
def _blend(a, b, f):
    """``(1 - f) a + f b``, a node of weight 0 left out: an infinite node (:func:`~softreach.reach.proof.lookahead.
    surface_fields`) counts only where its weight is positive, not as the NaN of ``0 * inf``."""
    if f == 0.0:
        return a
    if f == 1.0:
        return b
    return (1.0 - f) * a + f * b


@njit
def point_scratch(D):
    """Work space of :func:`point_value` for ``D`` axes: the ``2**D`` corner values and flat indices."""
    return np.empty(1 << D), np.empty(1 << D, np.int64)


@njit(inline="always")
def point_value(field, t, x, buf, node):
    """The table's multilinear interpolant at ``x`` at time ``t`` (:func:`softreach.reach.tables.interpolation.
    interpolate`), blended linearly between the snapshots around ``t``; ``+inf`` off the grid. ``buf`` and ``node``:
    :func:`point_scratch`."""
    flat, times, shape, glo, ghi, h, inv_h, periodic = field
    D = len(shape)
    for a in range(D):
        if not periodic[a]:
            s = (x[a] - glo[a]) / h[a]
            tol = TOL * max(1.0, shape[a])
            if not (s >= -tol and s <= shape[a] - 1 + tol):
                return np.inf
    k, wt = snapshot(times, t)
    size = 1 << D
    for q in range(size):
        node[q] = 0
    # each axis adds its lower or its upper node's share of the flat indices
    stride = 1
    for a in range(D - 1, -1, -1):
        if periodic[a]:
            cell = int(math.floor(((x[a] - glo[a]) * inv_h[a]) % shape[a]))
            n0, n1 = cell % shape[a], (cell + 1) % shape[a]
        else:
            S = min((min(max(x[a], glo[a]), ghi[a]) - glo[a]) * inv_h[a], shape[a] - 1.0)
            n0 = min(int(S), shape[a] - 2)
            n1 = min(n0 + 1, shape[a] - 1)
        bit = 1 << (D - 1 - a)
        for q in range(size):
            node[q] += (n1 if q & bit else n0) * stride
        stride *= shape[a]
    for q in range(size):
        v = flat[k, node[q]]
        buf[q] = (1.0 - wt) * v + wt * flat[k + 1, node[q]] if wt > 0.0 else v
    n = size
    for a in range(D):
        if periodic[a]:
            S = ((x[a] - glo[a]) * inv_h[a]) % shape[a]
            f = S - math.floor(S)
        else:
            S = min((min(max(x[a], glo[a]), ghi[a]) - glo[a]) * inv_h[a], shape[a] - 1.0)
            f = S - min(int(S), shape[a] - 2)
        n //= 2
        for i in range(n):
            buf[i] = _blend(buf[i], buf[n + i], f)
    return buf[0]


@njit(forceinline=True)
def usable_budget(z, z_top, z_left, t):
    """The budget at which a table is read: ``z``, at most ``z_top`` (conservative: ``W_eps`` falls with the
    budget) and the time left ``z_left - t`` (``z_left`` the horizon of a budget surface, else ``+inf``)."""
    return min(z, z_top, max(z_left - t, 0.0))


@njit(inline="always")
def certificate_row(W, z_top, z_floor, z_left, V, has_V, t, x, z, point, buf, node):
    """``D(t, x, z) = min(V~(t, x), W~(t, x, z))``, ``W~`` read at :func:`usable_budget`; ``+inf`` off the grid or
    time span, below the table's budget (``W``) or at a negative one (``V``), or where not finite."""
    times = W[1]
    if not (t >= times[0] - TOL and t <= times[-1] + TOL):
        return np.inf
    n = len(x)
    for a in range(n):
        point[a] = x[a]
    point[n] = usable_budget(z, z_top, z_left, t)
    w = point_value(W, t, point, buf, node)
    out = w if (z >= z_floor and math.isfinite(w)) else np.inf
    if has_V:
        v = point_value(V, t, x, buf, node)
        if z >= 0 and math.isfinite(v):
            out = min(out, v)
    return out


@njit
def certificate_rows(W, z_top, z_floor, z_left, V, has_V, t, x, z, out):
    """:func:`certificate_row` for every row."""
    n = x.shape[1]
    point = np.empty(n + 1)
    buf, node = point_scratch(n + 1)
    for r in range(len(x)):
        out[r] = certificate_row(W, z_top, z_floor, z_left, V, has_V, t[r], x[r], z[r], point, buf, node)


@njit
def step_index(t, dt, steps):
    """The sample index whose cells cover ``t``: ``ceil(t / dt)``, whose plans land by ``T`` from ``t`` too (the
    motion does not depend on time)."""
    return min(max(math.ceil(t / dt - 1e-9), 0), steps)


@njit
def budget_floor(z, dz, top):
    """The budget cell whose lower end lies at or below ``z`` (at most ``top``); ``-1`` at a negative budget."""
    if not z >= 0.0:
        return -1
    j = math.floor(min(z, top * dz) / dz + 1e-12)
    if j * dz > z:  # float guard: the cell's lower end lies at or below z
        j -= 1
    return j


#: the outward allowance of a box along a periodic axis, in ulps ``u`` of its period ``P = hi - lo``
#: (``CellCertificate.wrap``), for boxes within a period of the grid's ends. The environment wraps a state ``x`` to
#: ``lo + (x - lo) % P`` (:meth:`~softreach.reach.problem.Model.wrap_state`): three roundings, at most ``3 u``. The
#: float period differs from the motion's (``2 pi``: ``u / 2``) and from ``n`` cell widths (``u``). :func:`cell_span`'s
#: ``floor((x - lo) / width)`` rounds by at most ``3 u`` at the box's end and at the wrapped state each. So a state
#: wrapped from a box lies in a cell that the box widened by ``11 u`` touches, read modulo the cells; 16 leaves room.
WRAP_ULPS = 16


@njit(forceinline=True)
def _float_boxes(f, g, lo, hi, clo, width, first, last):
    """``f`` and ``g`` (cell indices that ``floor((lo - clo) / width)`` and ``floor((hi - clo) / width)`` gave) moved,
    within ``[first, last]``, to cells whose float boxes, ``clo + i * width`` to ``clo + (i + 1) * width`` as the
    builder computes them (:func:`~softreach.reach.proof.cell_game.cell_boxes`), hold ``lo`` and ``hi``: the quotient
    may round across an edge."""
    while f > first and clo + f * width > lo:
        f -= 1
    while f < last and clo + (f + 1) * width < lo:
        f += 1
    while g < last and clo + (g + 1) * width < hi:
        g += 1
    while g > first and clo + g * width > hi:
        g -= 1
    return f, g


@njit(forceinline=True)
def cell_span(lo, hi, clo, width, n, periodic, pad):
    """The cells ``[first, last]`` that ``[lo, hi]`` touches along one axis of ``n`` cells, and whether it lies on
    the grid along it; the first and last cells' float boxes hold ``lo`` and ``hi`` (:func:`_float_boxes`). A
    non-periodic axis clamps the range to the grid. Along a periodic axis the box is widened by ``pad``
    (:data:`WRAP_ULPS`; 0 for a state the environment has wrapped already), is on the grid within a period of either
    end (where the allowance holds), and its range may run past either end, read modulo ``n`` (one of ``n`` cells or
    more: all, once)."""
    if periodic:
        lo, hi = lo - pad, hi + pad
        f = math.floor((lo - clo) / width)
        g = math.floor((hi - clo) / width)
        if not (f >= -n and g < 2 * n):
            return 0, 0, False
        f, g = _float_boxes(int(f), int(g), lo, hi, clo, width, -n, 2 * n - 1)
        return (0, n - 1, True) if g - f + 1 >= n else (f, g, True)
    f = math.floor((lo - clo) / width)
    g = math.floor((hi - clo) / width)
    on = lo >= clo and hi <= clo + n * width
    fi = int(min(max(f, 0.0), n - 1.0)) if math.isfinite(f) else 0
    gi = int(min(max(g, 0.0), n - 1.0)) if math.isfinite(g) else 0
    fi, gi = _float_boxes(fi, gi, lo, hi, clo, width, 0, n - 1)
    return fi, max(fi, gi), on


@njit(inline="always")
def cover_row(cells, t, lo, hi, z):
    """Whether every (closed) cell the box ``[lo, hi]`` touches (:func:`cell_span`, widened along periodic axes) is
    good at sample time ``t`` with budget ``z``: on the grid, ``t`` not past the horizon, ``z``'s budget cell at
    least each cell's lowest good index in ``m``. Cells are read as runs along the last axis, the other axes' spans
    recomputed per run so that nothing is allocated (``cells``: :attr:`~softreach.reach.proof.cell_certificate.
    CellCertificate.kernel_args`)."""
    m, shape, clo, width, periodic, wrap, dt, dz, top, steps, horizon = cells
    D = len(shape)
    on, runs, run_lo, run_hi = True, 1, 0, 0
    for a in range(D):
        fi, gi, on_a = cell_span(lo[a], hi[a], clo[a], width[a], shape[a], periodic[a], wrap[a])
        on = on and on_a
        if a == D - 1:
            run_lo, run_hi = fi, gi
        else:
            runs *= gi - fi + 1
    if not on or not t <= horizon + 1e-9 * dt:
        return False
    k = step_index(t, dt, steps)
    floor = budget_floor(z, dz, top)
    # the first cell that needs more budget decides; a periodic axis's range is read modulo its cells
    n_run = shape[D - 1]
    for p in range(runs):
        rest, off, stride = p, 0, n_run
        for a in range(D - 2, -1, -1):
            fi, gi, _ = cell_span(lo[a], hi[a], clo[a], width[a], shape[a], periodic[a], wrap[a])
            span = gi - fi + 1
            off += ((fi + rest % span) % shape[a]) * stride
            rest //= span
            stride *= shape[a]
        for c in range(run_lo, run_hi + 1):
            if int(m[k, off + c % n_run]) > floor:
                return False
    return True


@njit(inline="always")
def plan_row(cells, action, hold, t, x):
    """The plan ``(candidate index, periods)`` of the cell holding ``x`` at time ``t`` (read modulo the cells along a
    periodic axis); ``(-1, 0)`` off the grid or where no budget suffices
    (:meth:`~softreach.reach.proof.cell_certificate.CellCertificate.plan`)."""
    m, shape, clo, width, periodic, wrap, dt, dz, top, steps, horizon = cells
    off, stride = 0, 1
    for a in range(len(shape) - 1, -1, -1):
        fi, _, on = cell_span(x[a], x[a], clo[a], width[a], shape[a], periodic[a], 0.0)
        if not on:
            return -1, 0
        off += (fi % shape[a]) * stride
        stride *= shape[a]
    k = step_index(t, dt, steps)
    j = int(action[k, off])
    return (j, int(hold[k, off])) if j >= 0 else (-1, 0)


@njit
def plan_rows(cells, action, hold, t, x, out_action, out_hold):
    """:func:`plan_row` for every row."""
    for r in range(len(x)):
        out_action[r], out_hold[r] = plan_row(cells, action, hold, t[r], x[r])


@njit
def cover_rows(cells, t, lo, hi, z, out):
    """:func:`cover_row` for every row."""
    for r in range(len(lo)):
        out[r] = cover_row(cells, t[r], lo[r], hi[r], z[r])
