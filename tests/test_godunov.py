"""Godunov's numerical Hamiltonian for separable Hamiltonians (``reach/numerics/solver.py``): which models get it, the flux's
consistency and monotonicity, and what it buys on the point mass against the exact reference."""

from __future__ import annotations

import numpy as np
import pytest

from softreach.reach import get_model
from softreach.reach.numerics.budget_surface import RunningCost
from softreach.reach.numerics.exact_pointmass import exact_mask
from softreach.reach.numerics.grid import Grid
from softreach.reach.numerics.held import HeldControl
from softreach.reach.problem import BudgetAugmented, classical_problem
from softreach.reach.numerics.solver import HamiltonianOperator, SolverSettings, godunov_hamiltonian, separable


def _grid_points(model, n=7):
    lo, hi = model.domain
    axes = [np.linspace(a, b, n) for a, b in zip(lo, hi)]
    return np.meshgrid(*axes, indexing="ij")


def test_which_hamiltonians_are_separable():
    pm = get_model("pointmass")
    x = _grid_points(pm)
    assert separable(pm, x)
    xz = np.meshgrid(*[np.linspace(a, b, 5) for a, b in zip((-20, -5, 0), (20, 20, 1))], indexing="ij")
    assert separable(BudgetAugmented(pm, 1e-3), xz)
    assert separable(RunningCost(pm, 1e-3), x)
    assert separable(HeldControl(pm), x)
    # the Dubins car: the turn rate enters theta' only, each wind component one position equation
    dubins = get_model("dubins")
    assert separable(dubins, _grid_points(dubins, 5))
    # the glider's angle of attack enters the speed and the flight-path equations at once
    glider = get_model("glider")
    assert not separable(glider, _grid_points(glider, 5))


def test_godunov_on_a_coupled_model_is_refused_and_auto_falls_back():
    model = get_model("glider")
    grid = Grid(model.domain[0], model.domain[1], (9, 9, 9), periodic=model.periodic_axes())
    problem = classical_problem(model)
    with pytest.raises(ValueError, match="separable"):
        HamiltonianOperator(problem, grid, SolverSettings(dissipation="godunov", backend="numpy"))
    assert not HamiltonianOperator(problem, grid, SolverSettings(dissipation="auto", backend="numpy")).godunov
    pm = get_model("pointmass")
    g2 = Grid(pm.domain[0], pm.domain[1], (9, 9))
    assert HamiltonianOperator(classical_problem(pm), g2, SolverSettings(dissipation="auto", backend="numpy")).godunov


def _fluxes(rng, n=2000):
    """Godunov's and local Lax-Friedrichs' fluxes of the point mass on random states and one-sided co-states."""
    pm = get_model("pointmass")
    x = [rng.uniform(-20, 20, n), rng.uniform(-5, 20, n)]
    pm_, pp = ([rng.normal(0, 3, n) * rng.choice([0.01, 1, 10], n) for _ in range(2)] for _ in range(2))
    god, _ = godunov_hamiltonian(pm, 0.0, x, (1.0, 1.0), pm_, pp)
    p_bar = [0.5 * (a + b) for a, b in zip(pm_, pp)]
    alpha = pm.dissipation(0.0, x, [np.minimum(a, b) for a, b in zip(pm_, pp)],
                           [np.maximum(a, b) for a, b in zip(pm_, pp)])
    llf = pm.hamiltonian(0.0, x, p_bar) + sum(0.5 * a * (r - l) for a, l, r in zip(alpha, pm_, pp))
    return pm, x, pm_, pp, god, llf


def test_godunov_flux_is_consistent_and_no_more_dissipative_than_lax_friedrichs():
    rng = np.random.default_rng(1)
    pm, x, pm_, pp, god, llf = _fluxes(rng)
    # consistency: equal one-sided slopes give the Hamiltonian itself
    same, _ = godunov_hamiltonian(pm, 0.0, x, (1.0, 1.0), pm_, pm_)
    np.testing.assert_allclose(same, pm.hamiltonian(0.0, x, pm_), rtol=1e-12, atol=1e-9)
    # both fluxes lie on the same side of the central value H(p_bar); Godunov's is the closer one
    h_bar = pm.hamiltonian(0.0, x, [0.5 * (a + b) for a, b in zip(pm_, pp)])
    opening = np.all([l <= r for l, r in zip(pm_, pp)], axis=0)
    closing = np.all([l >= r for l, r in zip(pm_, pp)], axis=0)
    assert opening.sum() > 100 and closing.sum() > 100
    assert np.all(god[opening] <= llf[opening] + 1e-9)
    assert np.all(god[closing] >= llf[closing] - 1e-9)


def test_godunov_holds_a_valley_where_lax_friedrichs_raises_it():
    """At ``v`` between the limits the controller can hold ``v`` against any wind (60 > 10 + g): in a valley of the
    value along ``v`` the Godunov flux of the ``v`` row is exactly 0, the local Lax-Friedrichs one is positive."""
    pm = get_model("pointmass")
    n = 50
    x = [np.full(n, -10.0), np.full(n, 5.0)]
    pm_ = [-np.linspace(0.1, 5, n), np.zeros(n)]
    pp = [np.linspace(0.1, 5, n), np.zeros(n)]
    god, _ = godunov_hamiltonian(pm, 0.0, x, (1.0, 1.0), pm_, pp)
    np.testing.assert_allclose(god, 0.0, atol=1e-12)
    alpha = pm.dissipation(0.0, x, [np.minimum(a, b) for a, b in zip(pm_, pp)],
                           [np.maximum(a, b) for a, b in zip(pm_, pp)])
    llf = pm.hamiltonian(0.0, x, [0.5 * (a + b) for a, b in zip(pm_, pp)]) + 0.5 * alpha[0] * (pp[0] - pm_[0])
    assert np.all(llf > 1.0)


def test_godunov_flux_is_monotone():
    """Nonincreasing in ``p-``, nondecreasing in ``p+`` (the backward-time form), so the scheme is monotone under
    the CFL bound."""
    rng = np.random.default_rng(2)
    pm, x, pm_, pp, god, _ = _fluxes(rng)
    for axis in range(2):
        for side, sign in ((pm_, -1.0), (pp, 1.0)):
            bumped = [c.copy() for c in side]
            bumped[axis] = bumped[axis] + rng.uniform(0, 2, len(god))
            args = (bumped, pp) if side is pm_ else (pm_, bumped)
            moved, _ = godunov_hamiltonian(pm, 0.0, x, (1.0, 1.0), *args)
            assert np.all(sign * (moved - god) >= -1e-9), (axis, sign)


def test_budget_surface_with_godunov_is_sound_and_tighter(tmp_path):
    """On the point mass at ``41 x 41``: no node claimed that the exact reference proves infeasible, at any budget,
    and at least every node that local Lax-Friedrichs claims (less viscosity along the rides of the limits)."""
    from softreach.reach import load_table
    from softreach.reach.numerics.compute import SolveConfig, solve_table

    claimed = {}
    for dissipation in ("local", "godunov"):
        path = tmp_path / f"q-{dissipation}.srt"
        cfg = SolveConfig(shape=(41, 41), budget_points=0, snapshots=3, budget_surface=True,
                          settings=SolverSettings.from_accuracy("very_high", dissipation=dissipation))
        solve_table(get_model("pointmass"), cfg, path, progress=False)
        table = load_table(path)
        assert table.header["fields"]["Q_min"]["settings"]["dissipation"] == dissipation
        claimed[dissipation] = {q: table.set_mask(0.0, q) for q in (0.0, 0.06, 0.3, 0.6)}
        for q, mask in claimed[dissipation].items():
            assert not (mask & ~exact_mask(table, q)).any(), (dissipation, q)
    gained = 0
    for q in claimed["local"]:
        assert np.all(claimed["godunov"][q] >= claimed["local"][q]), q
        gained += int(claimed["godunov"][q].sum() - claimed["local"][q].sum())
    assert gained > 0


def test_w_eps_with_godunov_is_sound_to_one_cell_and_no_looser(pointmass_table, tmp_path):
    """The fixture's ``W_eps`` solve (41 x 41 x 45, ENO2/RK2) again with Godunov's flux: a node claimed outside the
    exact set lies next to it (the fixture's own criterion, ``tests/test_exact_pointmass.py``), and the symmetric
    difference to the exact sets is no larger than Lax-Friedrichs' at any budget."""
    from scipy.ndimage import distance_transform_cdt

    from softreach.reach import SolveConfig, load_table, solve_table
    from softreach.reach.numerics.exact_pointmass import grade

    path = tmp_path / "pm-godunov.srt"
    cfg = SolveConfig(shape=(41, 41), budget_points=45, snapshots=11,
                      settings=SolverSettings.from_accuracy("medium", dtype="float32", compile=False,
                                                            dissipation="godunov"))
    solve_table(get_model("pointmass"), cfg, path, progress=False)
    table = load_table(path)
    budgets = (0.0, 0.06, 0.3, 0.6)
    ours, theirs = grade(table, budgets), grade(pointmass_table, budgets)
    for q in budgets:
        exact = exact_mask(table, q)
        unsound = table.set_mask(0.0, q) & ~exact
        assert (distance_transform_cdt(~exact, metric="chessboard")[unsound] <= 1).all(), q
        assert ours[q]["symmetric_difference"] <= theirs[q]["symmetric_difference"] + 1e-9, q
