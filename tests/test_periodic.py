"""Periodic state axes (an angle): the solver's derivatives wrap at the seam, interpolation wraps the coordinate
and never reports a periodic coordinate as outside, and a model's periodic flags reach the solved grid."""

from __future__ import annotations

import math

import numpy as np
import pytest

from softreach.reach import SolveConfig, get_model
from softreach.reach.numerics.compute import validate
from softreach.reach.numerics.derivatives import upwind_derivatives
from softreach.reach.numerics.grid import Grid
from softreach.reach.tables.interpolation import interpolate
from softreach.reach.problem import classical_problem
from softreach.reach.numerics.solver import HamiltonianOperator, SolverSettings


def test_a_models_periodic_axis_reaches_both_grids():
    state, aug = validate(get_model("dubins"), SolveConfig(shape=(9, 9, 16), budget_points=9), None)
    assert state.periodic == (False, False, True) and aug.periodic == (False, False, True, False)
    # N nodes on [lo, hi): the last node is one spacing before the seam, not on it
    assert state.axis(2)[-1] == pytest.approx(math.pi - 2 * math.pi / 16)


@pytest.mark.parametrize("scheme", ["eno2", "weno5"])
def test_derivative_of_sin_is_accurate_at_the_seam_on_the_solvers_grid(scheme):
    """The solver pads a periodic axis by wrapping: at the seam (first and last nodes) the derivative of
    ``sin(theta)`` is as accurate as inside; extrapolated ghosts (a non-periodic axis) are far off there."""
    n = 32
    state, _ = validate(get_model("dubins"), SolveConfig(shape=(9, 9, n), budget_points=9), None)
    op = HamiltonianOperator(classical_problem(get_model("dubins")), state,
                             SolverSettings(scheme=scheme, backend="numpy", dtype="float64"))
    assert op.boundaries[2] == "periodic"
    theta = state.axis(2)
    u = np.broadcast_to(np.sin(theta)[None, None, :], state.shape).copy()
    dm, dp = upwind_derivatives(u, 2, state.spacing[2], scheme, op.boundaries[2])
    exact = np.cos(theta)
    inside = np.abs(dm[0, 0, 4:-4] - exact[4:-4]).max()
    seam = max(np.abs(dm[0, 0, [0, -1]] - exact[[0, -1]]).max(), np.abs(dp[0, 0, [0, -1]] - exact[[0, -1]]).max())
    assert seam < 2 * inside + 1e-12 and seam < 0.02
    em, ep = upwind_derivatives(u, 2, state.spacing[2], scheme, "extrapolate_away")
    assert max(np.abs(em[0, 0, [0, -1]] - exact[[0, -1]]).max(), np.abs(ep[0, 0, [0, -1]] - exact[[0, -1]]).max()) > 0.1


def _periodic_grid():
    return Grid((0.0, -math.pi), (1.0, math.pi), (3, 8), periodic=(False, True))


def test_interpolation_wraps_the_periodic_coordinate():
    grid = _periodic_grid()
    rng = np.random.default_rng(0)
    values = rng.normal(size=(1,) + grid.shape)
    h = grid.spacing[1]
    last = grid.axis(1)[-1]
    # between the last node and the seam: the blend of the last and the first node
    q = np.array([[0.25, last + 0.25 * h]])  # halfway between the first two x nodes
    v, inside = interpolate(values, np.array([0.0]), grid, np.array([0.0]), q)
    expected = 0.5 * ((0.75 * values[0, 0, -1] + 0.25 * values[0, 0, 0]) + (0.75 * values[0, 1, -1] + 0.25 * values[0, 1, 0]))
    assert inside[0] and v[0] == pytest.approx(expected)
    # a whole number of periods away: the same value, and never "outside"
    for k in (-3, -1, 1, 5):
        vk, ink = interpolate(values, np.array([0.0]), grid, np.array([0.0]), q + [[0.0, 2 * math.pi * k]])
        assert ink[0] and vk[0] == pytest.approx(v[0], abs=1e-12)
    # the non-periodic axis still reports a query outside it
    _, out = interpolate(values, np.array([0.0]), grid, np.array([0.0]), np.array([[1.5, 0.0]]))
    assert not out[0]


def test_the_filters_compiled_interpolant_wraps_the_seam_as_the_table_does():
    """The filter's compiled read of a table (:func:`softreach.reach.proof.kernels.point_value`) at points on both
    sides of the seam, beyond it and several periods away, against the table's own interpolation."""
    from softreach.reach.proof.kernels import point_scratch, point_value
    from softreach.reach.proof.lookahead import kernel_field

    grid = _periodic_grid()
    rng = np.random.default_rng(1)
    values = rng.normal(size=(2,) + grid.shape)
    times = np.array([0.0, 1.0])
    field = kernel_field(values, times, grid)
    buf, node = point_scratch(2)
    last = grid.axis(1)[-1]
    thetas = np.r_[last + 0.3 * grid.spacing[1], -math.pi, math.pi, 3 * math.pi + 0.2, -7.0, rng.uniform(-9, 9, 20)]
    for th in thetas:
        x = np.array([rng.uniform(0, 1), th])
        t = float(rng.uniform(0, 1))
        want, inside = interpolate(values, times, grid, np.array([t]), x[None])
        assert inside[0]
        assert point_value(field, t, x, buf, node) == pytest.approx(want[0], abs=1e-12), th


def test_env_wraps_the_heading_and_follows_the_exact_circle():
    """A full left turn from (2.5, -3) heading east, no wind: the Dubins circle x = 2.5 + sin t,
    y = -2 - cos t, heading t wrapped into [-pi, pi)."""
    import gymnasium as gym

    import softreach.envs  # noqa: F401

    env = gym.make("softreach/SoftReach-v0", model=get_model("dubins"))
    obs, _ = env.reset(seed=0, options={"state": [2.5, -3.0, 2 * math.pi], "budget": 0.0})
    assert obs[2] == pytest.approx(0.0, abs=1e-6)  # the start's heading is wrapped too
    base = env.unwrapped
    for _ in range(66):
        obs, _, terminated, truncated, info = env.step(np.array([1.0], dtype=np.float32))
        assert not terminated and not truncated
        t = base.time
        x, y, th = base.state
        assert -math.pi <= th < math.pi
        assert x == pytest.approx(2.5 + math.sin(t), abs=1e-6) and y == pytest.approx(-2.0 - math.cos(t), abs=1e-6)
        assert math.cos(th) == pytest.approx(math.cos(t), abs=1e-9) and math.sin(th) == pytest.approx(math.sin(t), abs=1e-9)
    assert base.time > 2 * math.pi  # it went round once: the heading wrapped at t = pi
