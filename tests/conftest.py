"""Shared fixtures: small solved tables (seconds to compute) reused across test modules."""

from __future__ import annotations

import os

import pytest

os.environ.setdefault("OMP_NUM_THREADS", "2")


@pytest.fixture(scope="session")
def pointmass_table(tmp_path_factory):
    """A coarse point-mass table with V and W_eps (41 x 41 x 45, ENO2/RK2, 11 snapshots)."""
    from softreach.reach import SolveConfig, SolverSettings, get_model, load_table, solve_table

    path = tmp_path_factory.mktemp("tables") / "pointmass_small.srt"
    model = get_model("pointmass")
    cfg = SolveConfig(shape=(41, 41), budget_points=45, settings=SolverSettings.from_accuracy("medium", dtype="float32", compile=False),
                      snapshots=11)
    solve_table(model, cfg, path, progress=False)
    return load_table(path)


@pytest.fixture(scope="session")
def pointmass_table_path(pointmass_table):
    return pointmass_table.path


@pytest.fixture(scope="session")
def pointmass_held_table(tmp_path_factory):
    """A coarse point-mass table of the sampled-data game (actions held 0.01 s): 41 x 41 x 45, ENO2/RK2."""
    from softreach.reach import SolveConfig, SolverSettings, get_model, load_table, solve_table

    path = tmp_path_factory.mktemp("tables") / "pointmass_held.srt"
    cfg = SolveConfig(shape=(41, 41), budget_points=45, control_period=0.01,
                      settings=SolverSettings.from_accuracy("medium", dtype="float32", compile=False))
    solve_table(get_model("pointmass"), cfg, path, progress=False)
    return load_table(path)


@pytest.fixture(scope="session")
def glider_held_table(tmp_path_factory):
    """A coarse glider table of the sampled-data game (0.1 s), 21 x 15 x 13 x 9, ENO2 / RK2: the filter's proofs
    come from its cells (the packaged ones), so the tests that use it need the table only to rank and search."""
    from softreach.reach import SolveConfig, SolverSettings, get_model, load_table, solve_table

    path = tmp_path_factory.mktemp("tables") / "glider_held.srt"
    cfg = SolveConfig(shape=(21, 15, 13), budget_points=9, control_period=0.1, consistency_samples=2000,
                      settings=SolverSettings.from_accuracy("medium", dtype="float32", compile=False))
    solve_table(get_model("glider"), cfg, path, progress=False, budgets=(0.0, 5.0, 10.0))
    return load_table(path)


@pytest.fixture(scope="session")
def dubins_table(tmp_path_factory):
    """A coarse Dubins table with V and W_eps (25 x 25 x 16 x 15, heading periodic, ENO2/RK2, 8 snapshots)."""
    from softreach.reach import SolveConfig, SolverSettings, get_model, load_table, solve_table

    path = tmp_path_factory.mktemp("tables") / "dubins_small.srt"
    cfg = SolveConfig(shape=(25, 25, 16), budget_points=15, snapshots=8,
                      settings=SolverSettings.from_accuracy("medium", dtype="float32", compile=False))
    solve_table(get_model("dubins"), cfg, path, progress=False)
    return load_table(path)


@pytest.fixture(scope="session")
def dubins_held_table(tmp_path_factory):
    """A coarse Dubins table of the sampled-data game (turn rate held 0.1 s): 21 x 21 x 12 x 12, ENO2/RK2."""
    from softreach.reach import SolveConfig, SolverSettings, get_model, load_table, solve_table

    path = tmp_path_factory.mktemp("tables") / "dubins_held.srt"
    cfg = SolveConfig(shape=(21, 21, 12), budget_points=12, control_period=0.1,
                      settings=SolverSettings.from_accuracy("medium", dtype="float32", compile=False))
    solve_table(get_model("dubins"), cfg, path, progress=False)
    return load_table(path)
