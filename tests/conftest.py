"""Shared fixtures (small solved tables, each solved once per run: :mod:`shared_tables`) and the run's warm-up.

The filter's first decision compiles it on an empty compiled-code cache, the suite's longest compile
(``benchmarks/first_compile.py filter`` measures it). The modules that make the filter decide run after those that do
not, and while those run, a process of its own (:mod:`warm_up`) compiles the filter and solves the glider's shared
held table, so that the compile takes the machine's other core instead of stalling the run. A test of a module that
makes the filter decide waits until the warm-up is done (it then loads the compiled code); if the warm-up fails, that
test compiles the filter itself, as it would without one.

With ``pytest -n 2`` (pytest-xdist) the two workers share the tables and the one warm-up (started by the first
worker). Every process runs on one thread (``OMP_NUM_THREADS=1`` unless set, and always in a worker).
"""

from __future__ import annotations

import os
import re
import subprocess
import sys
from pathlib import Path

import pytest

WORKER = os.environ.get("PYTEST_XDIST_WORKER")
# one thread per process: the tests and the warm-up (or two workers and the warm-up) already share the machine's cores
if WORKER:
    os.environ["OMP_NUM_THREADS"] = "1"
else:
    os.environ.setdefault("OMP_NUM_THREADS", "1")
# softreach solve compiles the filter in the background where the cache lacks it: here the warm-up does (tests that
# test that set it themselves)
os.environ["SOFTREACH_COMPILE_AHEAD"] = "0"

from shared_tables import run_root, solved  # noqa: E402  (after the thread setting, before torch is imported)
from warm_up import phase_lock  # noqa: E402

#: a module that surely makes a filter decide: such modules run last and wait for the warm-up (one with them starts
#: it). A module that decides without saying so here loses no work either: the warm-up holds the compile-ahead lock
#: while it compiles the filter (:func:`softreach.reach.jit.compiling_ahead`), so such a test waits for it and loads
#: the result instead of compiling it too
DECIDES = re.compile(r"ValueFilter\(|SafetyFilter\(|_held_table|\baudit\(|\bevaluate\(|filter_table=|\[\"compile\"")
#: the most a test waits for the warm-up [s]: past that it compiles the filter itself
WAIT_S = 1200.0


def _phases(text: str) -> list[str]:
    """The warm-up phases a module's tests wait for."""
    if not DECIDES.search(text):
        return []
    return ["pointmass", "glider"] if "glider" in text else ["pointmass"]


def _module_phases(item: pytest.Item) -> list[str]:
    """The warm-up phases the module of ``item`` waits for (none: it does not surely make a filter decide)."""
    path = Path(item.fspath)
    cache = item.config.stash.setdefault(_TEXTS, {})
    if path not in cache:
        cache[path] = _phases(path.read_text())
    return cache[path]


_TEXTS = pytest.StashKey[dict]()
_WARM_UP = pytest.StashKey[subprocess.Popen]()
_WAITED: set[str] = set()


def pytest_collection_modifyitems(session: pytest.Session, config: pytest.Config, items: list[pytest.Item]) -> None:
    """Modules that make the filter decide last (each module's tests stay together and in order), and the warm-up
    started when a test surely makes the filter decide and other tests can run meanwhile."""
    first_seen: dict[Path, int] = {}
    for item in items:
        first_seen.setdefault(Path(item.fspath), len(first_seen))
    items.sort(key=lambda it: (bool(_module_phases(it)), first_seen[Path(it.fspath)]))
    phases = sorted({p for it in items for p in _module_phases(it)}, key=["pointmass", "glider"].index)
    if (not phases or all(_module_phases(it) for it in items)
            or WORKER not in (None, "gw0") or config.option.collectonly):
        return
    root = run_root(config._tmp_path_factory)  # type: ignore[attr-defined]
    log = open(root / "warm_up.log", "w")
    proc = subprocess.Popen([sys.executable, str(Path(__file__).with_name("warm_up.py")), str(root), *phases],
                            stdout=subprocess.PIPE, stderr=log, text=True, env={**os.environ, "OMP_NUM_THREADS": "1"})
    assert proc.stdout is not None
    if proc.stdout.readline().strip() != "locked":  # it failed before holding its locks: the tests compile
        proc.wait()
        return
    config.stash[_WARM_UP] = proc


def pytest_runtest_setup(item: pytest.Item) -> None:
    """A test of a module that makes the filter decide waits until the warm-up has compiled it (at once if there is
    none)."""
    for phase in _module_phases(item):
        if phase not in _WAITED:
            _WAITED.add(phase)
            lock = phase_lock(run_root(item.config._tmp_path_factory), phase)  # type: ignore[attr-defined]
            try:
                with lock.acquire(timeout=WAIT_S):
                    pass
            except TimeoutError:
                pass


def pytest_sessionfinish(session: pytest.Session) -> None:
    proc = session.config.stash.get(_WARM_UP, None)
    if proc is not None and proc.poll() is None:
        proc.terminate()
        proc.wait()


@pytest.fixture(scope="session", autouse=True)
def sb3_log_folder(tmp_path_factory):
    """SB3 makes a folder for the logger of every ``learn`` given none, in the system's temporary folder, and keeps
    it: the tests' go under this run's temporary folder instead (SB3 reads ``SB3_LOGDIR``)."""
    os.environ["SB3_LOGDIR"] = str(tmp_path_factory.mktemp("sb3"))


@pytest.fixture(scope="session")
def pointmass_table(tmp_path_factory):
    """A coarse point-mass table with V and W_eps (41 x 41 x 45, ENO2/RK2, 11 snapshots)."""
    from softreach.reach import load_table

    return load_table(solved("pointmass_small", run_root(tmp_path_factory)))


@pytest.fixture(scope="session")
def pointmass_table_path(pointmass_table):
    return pointmass_table.path


@pytest.fixture(scope="session")
def pointmass_held_table(tmp_path_factory):
    """A coarse point-mass table of the sampled-data game (actions held 0.01 s): 41 x 41 x 45, ENO2/RK2."""
    from softreach.reach import load_table

    return load_table(solved("pointmass_held", run_root(tmp_path_factory)))


@pytest.fixture(scope="session")
def glider_held_table(tmp_path_factory):
    """A coarse glider table of the sampled-data game (0.1 s), 21 x 15 x 13 x 9, ENO2 / RK2: the filter's proofs
    come from its cells (the packaged ones), so the tests that use it need the table only to rank and search."""
    from softreach.reach import load_table

    return load_table(solved("glider_held", run_root(tmp_path_factory)))


@pytest.fixture(scope="session")
def dubins_table(tmp_path_factory):
    """A coarse Dubins table with V and W_eps (25 x 25 x 16 x 15, heading periodic, ENO2/RK2, 8 snapshots)."""
    from softreach.reach import load_table

    return load_table(solved("dubins_small", run_root(tmp_path_factory)))


@pytest.fixture(scope="session")
def dubins_held_table(tmp_path_factory):
    """A coarse Dubins table of the sampled-data game (turn rate held 0.1 s): 21 x 21 x 12 x 12, ENO2/RK2."""
    from softreach.reach import load_table

    return load_table(solved("dubins_held", run_root(tmp_path_factory)))
