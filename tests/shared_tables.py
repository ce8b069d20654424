"""The small solved tables the tests share (the fixtures of ``tests/conftest.py``), each solved once per test run.

A table is solved into a folder that every pytest process of the run sees (the run's base temporary folder; the
workers of ``pytest -n`` share their parent's), under a file lock: the first process to ask solves it, the others wait
and load the file. So two workers, or a worker and the warm-up process (``tests/warm_up.py``), never solve the same
table twice. A table is written under a temporary name and renamed when complete, so that a failed solve leaves no
file that a later process would take for the table.
"""

from __future__ import annotations

import os
from pathlib import Path
from typing import Any

from filelock import FileLock

#: name -> (model, SolveConfig arguments, solve_table arguments); ENO2 / RK2 ("medium"), float32, with the compiled
#: CPU loops (the ``"fused"`` engine; the point mass's tables are bit for bit the eager ones), where :data:`SETTINGS`
#: does not say otherwise
TABLES: dict[str, tuple[str, dict[str, Any], dict[str, Any]]] = {
    # V and W_eps, 41 x 41 x 45, 11 snapshots
    "pointmass_small": ("pointmass", dict(shape=(41, 41), budget_points=45, snapshots=11), {}),
    # the sampled-data game, actions held 0.01 s, 41 x 41 x 45: the packaged cells' key (tests/test_packaged_cells.py)
    "pointmass_held": ("pointmass", dict(shape=(41, 41), budget_points=45, control_period=0.01), {}),
    # the sampled-data game, 0.1 s, 21 x 15 x 13 x 9: the filter's proofs come from its (packaged) cells, so the
    # tests that use it need the table only to rank and search
    "glider_held": ("glider", dict(shape=(21, 15, 13), budget_points=9, control_period=0.1),
                   dict(budgets=(0.0, 5.0, 10.0))),
    # V and W_eps, 25 x 25 x 16 x 15, heading periodic, 8 snapshots
    "dubins_small": ("dubins", dict(shape=(25, 25, 16), budget_points=15, snapshots=8), {}),
    # the sampled-data game, turn rate held 0.1 s, 21 x 21 x 12 x 12
    "dubins_held": ("dubins", dict(shape=(21, 21, 12), budget_points=12, control_period=0.1), {}),
    # the budget surface Q_min with V, 41 x 41, WENO5 / RK3 ("very_high", float64), 5 snapshots
    "pointmass_qmin": ("pointmass", dict(shape=(41, 41), budget_points=0, snapshots=5, budget_surface=True), {}),
}
#: the solver settings of a table whose own are not the default ones: ``SolverSettings.from_accuracy`` arguments
SETTINGS: dict[str, dict[str, Any]] = {"pointmass_qmin": dict(accuracy="very_high")}
_DEFAULT_SETTINGS = dict(accuracy="medium", dtype="float32", compile=True)


def run_root(factory: Any) -> Path:
    """The folder every process of this run shares: the base temporary folder of ``factory`` (a
    ``pytest.TempPathFactory``; its parent in a pytest-xdist worker)."""
    base = factory.getbasetemp()
    return base.parent if os.environ.get("PYTEST_XDIST_WORKER") else base


def lock(path: Path) -> FileLock:
    """The lock that guards ``path`` across processes (a file beside it)."""
    return FileLock(str(path) + ".lock")


def solved(name: str, root: Path) -> Path:
    """The path of table ``name`` (a key of :data:`TABLES`) in ``root``, solved there first if no process has yet."""
    from softreach.reach import SolveConfig, SolverSettings, get_model, solve_table

    model, config, extra = TABLES[name]
    path = Path(root) / f"{name}.srt"
    with lock(path):
        if not path.exists():
            part = path.with_name(f".{name}.{os.getpid()}.srt")
            settings = dict(SETTINGS.get(name, _DEFAULT_SETTINGS))
            cfg = SolveConfig(**config, settings=SolverSettings.from_accuracy(settings.pop("accuracy"), **settings))
            solve_table(get_model(model), cfg, part, progress=False, **extra)
            os.replace(part, path)
    return path
