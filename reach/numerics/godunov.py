"""Godunov's numerical Hamiltonian for a separable Hamiltonian, and the test of separability
(:mod:`softreach.reach.numerics.solver`'s module docstring gives the scheme)."""

from __future__ import annotations

from typing import Any, Sequence

import numpy as np

from .. import backend as B

Array = B.Array


def _axis_costates(x: Sequence[Array], i: int, sign: float) -> list[Any]:
    """The co-state ``sign e_i`` as components broadcastable against the grid ``x``."""
    return [sign if j == i else 0.0 for j in range(len(x))]


def godunov_hamiltonian(dynamics: Any, t: float, x: Sequence[Array], dx: Sequence[float], lefts: Sequence[Array],
                        rights: Sequence[Array]) -> tuple[Array, Any]:
    """Godunov's numerical Hamiltonian of a separable ``H`` (module docstring) and the CFL speed
    ``sum_i max(|H(e_i)|, |H(-e_i)|) / dx_i`` (the largest ``|dH/dp_i|``) at every node, as
    :meth:`HamiltonianOperator.numerical_hamiltonian`.

    :param lefts: ``p-_i`` per axis; ``rights``: ``p+_i``; each on the grid
    """
    zero = [0.0] * len(x)
    h0 = dynamics.hamiltonian(t, x, zero)
    out = h0 + 0 * lefts[0]
    speed: Any = 0.0
    for i, (pm, pp) in enumerate(zip(lefts, rights)):
        up = dynamics.hamiltonian(t, x, _axis_costates(x, i, 1.0)) - h0      # slope of H_i for p_i > 0
        down = h0 - dynamics.hamiltonian(t, x, _axis_costates(x, i, -1.0))  # slope of H_i for p_i < 0

        def h_i(p):
            return B.where(p > 0, up * p, down * p)

        hm, hp = h_i(pm), h_i(pp)
        # H_i is piecewise linear with its one kink at 0 (H_i(0) = 0): its extrema over an interval are at the
        # ends or at 0 when 0 is inside
        straddles = (pm < 0) & (pp > 0)
        crosses = (pp < 0) & (pm > 0)
        hi = B.where(straddles, B.maximum(B.maximum(hm, hp), 0 * hm), B.maximum(hm, hp))
        lo = B.where(crosses, B.minimum(B.minimum(hm, hp), 0 * hm), B.minimum(hm, hp))
        out = out + B.where(pm <= pp, hi, lo)
        speed = speed + B.maximum(abs(up), abs(down)) / dx[i]
    return out, speed


def separable(dynamics: Any, x: Sequence[Array], samples: int = 4, seed: int = 0) -> bool:
    """Is ``H(t, x, p) = H(t, x, 0) + sum_i H(t, x, p_i e_i)`` on the grid ``x``? Checked at ``t = 0``, at every node,
    for ``samples`` random co-states with components of mixed signs and sizes: a Hamiltonian where one input enters
    two state equations couples their co-states and fails at almost every node."""
    rng = np.random.default_rng(seed)
    zero = [0.0] * len(x)
    h0 = np.asarray(B.to_numpy(dynamics.hamiltonian(0.0, x, zero)), dtype=np.float64)
    for _ in range(samples):
        p = [float(v) for v in rng.normal(size=len(x)) * rng.choice([1.0, 10.0], size=len(x))]
        whole = np.asarray(B.to_numpy(dynamics.hamiltonian(0.0, x, p)), dtype=np.float64)
        parts, scale = h0, np.abs(whole) + np.abs(h0)
        for i, pi in enumerate(p):
            hi = np.asarray(B.to_numpy(dynamics.hamiltonian(0.0, x, [pi if j == i else 0.0 for j in range(len(x))])),
                            dtype=np.float64)
            parts, scale = parts + (hi - h0), scale + np.abs(hi)
        if not np.all(np.abs(whole - parts) <= 1e-9 * (1.0 + scale)):
            return False
    return True
