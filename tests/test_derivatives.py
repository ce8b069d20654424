"""Upwind derivative schemes and the time stepper on problems with known solutions."""

from __future__ import annotations

import math

import numpy as np
import pytest

from softreach.reach.numerics.derivatives import SCHEMES, upwind_derivatives

EXPECTED_ORDER = {"first": 1, "eno2": 2, "weno3": 2, "weno5": 4}  # weno3 is 3rd order only where smooth enough


@pytest.mark.parametrize("scheme", sorted(SCHEMES))
def test_linear_function_is_differentiated_exactly(scheme):
    x = np.linspace(-1, 2, 31)
    u = 3.0 * x - 1.0
    for boundary in ("extrapolate", "extrapolate_away"):
        dm, dp = upwind_derivatives(u, 0, x[1] - x[0], scheme, boundary)
        if boundary == "extrapolate":
            np.testing.assert_allclose(dm, 3.0, atol=1e-9)
            np.testing.assert_allclose(dp, 3.0, atol=1e-9)
        else:  # away-from-zero ghosts change only the ends
            np.testing.assert_allclose(dm[3:-3], 3.0, atol=1e-9)


@pytest.mark.parametrize("scheme", sorted(SCHEMES))
def test_convergence_order_on_a_smooth_periodic_function(scheme):
    errors = []
    for n in (32, 64, 128):
        x = np.arange(n) * 2 * math.pi / n
        dm, dp = upwind_derivatives(np.sin(x), 0, x[1] - x[0], scheme, "periodic")
        errors.append(max(np.abs(dm - np.cos(x)).max(), np.abs(dp - np.cos(x)).max()))
    rates = [math.log2(a / b) for a, b in zip(errors, errors[1:])]
    assert min(rates) > EXPECTED_ORDER[scheme] - 0.3, (scheme, errors, rates)


def test_weno5_is_non_oscillatory_at_a_kink():
    x = np.linspace(-1, 1, 41)
    u = np.abs(x)
    dm, dp = upwind_derivatives(u, 0, x[1] - x[0], "weno5", "extrapolate")
    assert np.all(np.abs(dm) <= 1 + 1e-6) and np.all(np.abs(dp) <= 1 + 1e-6)


def test_float32_flat_regions_give_finite_weno_weights():
    import torch

    u = torch.zeros(5, 40, dtype=torch.float32)
    dm, dp = upwind_derivatives(u, 1, 0.1, "weno5", "extrapolate_away")
    assert torch.isfinite(dm).all() and torch.isfinite(dp).all()


def test_unknown_scheme_and_too_short_axis_are_refused():
    with pytest.raises(ValueError, match="unknown scheme 'weno7'"):
        upwind_derivatives(np.zeros(10), 0, 1.0, "weno7")
    with pytest.raises(ValueError, match="at least 4 nodes"):
        upwind_derivatives(np.zeros(3), 0, 1.0, "weno5")


def test_constant_and_per_end_ghost_rules():
    from softreach.reach.numerics.derivatives import pad

    u = np.array([[3.0, 1.0, -1.0, -2.0]])
    ghosts = pad(u, 1, 2, ("extrapolate_away", "constant"))[0]
    # low end (3, slope 2 outward, positive edge): rising away from zero; high end: the edge value repeated
    assert ghosts.tolist() == [7.0, 5.0, 3.0, 1.0, -1.0, -2.0, -2.0, -2.0]
    with pytest.raises(ValueError, match="unknown boundary 'flat'"):
        pad(u, 1, 2, ("constant", "flat"))


def test_a_set_that_reaches_the_grid_edge_is_refused(tmp_path):
    """A domain equal to the hard-constraint box puts states of the set on the grid's edge, where ghosts
    extrapolated away from a negative value would invent safety beyond the grid: the solve stops and says so."""
    from softreach.reach import SolveConfig, SolverSettings, get_model, solve_table

    model = get_model("pointmass")
    cfg = SolveConfig(shape=(31, 31), budget_points=20, classical_only=True, snapshots=3, domain=model.hard_box,
                      settings=SolverSettings.from_accuracy("low", dtype="float32", compile=False))
    with pytest.raises(ValueError, match="edge of axis 'y'.*Enlarge the domain along 'y'"):
        solve_table(model, cfg, tmp_path / "tight.srt", progress=False)
