"""The cells the package ships (``reach/proof/cells/``) are what a fresh build gives, and a filter on a new machine uses
them instead of building, through the memory-mapped cache."""

from __future__ import annotations

import json
from pathlib import Path

import numpy as np
import pytest

from softreach.filters import ValueFilter
from softreach.reach.proof import cell_certificate
from softreach.reach.proof.cell_certificate import PACKAGED, CellCertificate, cell_key
from softreach.reach.proof.lookahead import Lookahead

from cell_plans import recheck

#: every file is rechecked here, and one of the point mass's is rebuilt whole (the glider's and Dubins's take
#: minutes to build; tests/test_glider_cells.py and tests/test_dubins_cells.py fly what they claim)
FILES = sorted(PACKAGED.glob("cells-*.npz"))
#: the test table of each model, solved for the packaged cells' period and candidates
TABLES = {"pointmass": "pointmass_held_table", "glider": "glider_held_table", "dubins": "dubins_held_table"}


def test_the_package_ships_the_default_cells():
    # the point mass: the filter's default target_checks (1) and the environment's (its 10 sub-steps); the glider
    # and Dubins: their environment's 2 sub-steps (SafetyFilter's)
    keys = [json.loads(str(np.load(f)["key"])) for f in sorted(PACKAGED.glob("cells-*.npz"))]
    assert sorted((k["model"], k["game"], k["target_checks"]) for k in keys) == [
        ("dubins", "land", 2), ("glider", "land", 2), ("pointmass", "land", 1), ("pointmass", "land", 10)]


@pytest.mark.parametrize("path", FILES, ids=lambda p: p.name)
def test_packaged_cells_are_what_the_recursion_gives(path, request):
    """Every packaged file, at 2,000 random cells and every sample: the least good budget index and the plan are
    those one step of the game's recursion gives from the file's own later samples, and at ``T`` those of the
    game. At every cell that would make the file the build's own answer; a file built by other code, or for other
    enclosures, candidates or budget bounds, disagrees at some of them."""
    stored = CellCertificate.load(path)
    table = request.getfixturevalue(TABLES[stored.key["model"]])
    la = Lookahead.from_table(table, table.model, table.control_period, table.eps,
                              target_checks=stored.key["target_checks"])
    # 2,000 random cells, and up to 50 of each kind the file claims (bad at t = 0, good at some sample by a plan of
    # each length) that the random ones may miss where such cells are few
    rng = np.random.default_rng(0)
    steps = stored.steps + 1
    good = np.asarray(stored.m).reshape(steps, -1) < stored.never
    hold_all = np.asarray(stored.hold).reshape(steps, -1)
    kinds = [~good[0]] + [((hold_all == h) & good).any(axis=0) for h in stored.key["holds"]]
    flat = np.unique(np.r_[rng.choice(good.shape[1], 2000, replace=False),
                           *(rng.permutation(np.nonzero(k)[0])[:50] for k in kinds)])
    m, action, hold = recheck(stored, la, flat)
    for name, got in (("m", m), ("action", action), ("hold", hold)):
        np.testing.assert_array_equal(got, np.asarray(getattr(stored, name)).reshape(steps, -1)[:, flat],
                                      err_msg=name)
    with pytest.raises(ValueError, match=r"'target_checks': \(3, "):
        recheck(stored, Lookahead.from_table(table, table.model, table.control_period, table.eps,
                                                       target_checks=3), flat[:10])
    # the sample holds good cells and bad ones, and plans of every length the file uses (more than one)
    assert 50 <= (m[0] < stored.never).sum() <= len(flat) - 50
    used = {h for h, k in zip(stored.key["holds"], kinds[1:]) if k.any()}
    assert len(used) >= 2 and set(np.unique(hold[:-1][m[:-1] < stored.never])) == used


@pytest.mark.parametrize("table", ["pointmass_held_table", "glider_held_table", "dubins_held_table"])
def test_a_new_machine_reads_the_packaged_cells_without_building(table, request, tmp_path, monkeypatch):
    table = request.getfixturevalue(table)
    cache = tmp_path / "empty"
    monkeypatch.setenv("SOFTREACH_CACHE", str(cache))

    def no_build(*args, **kwargs):
        raise AssertionError("built cells although the package ships them")

    monkeypatch.setattr(cell_certificate.CellCertificate, "build", no_build)
    # what SafetyFilter asks: landing checked at the environment's sub-step ends
    vf = ValueFilter(table, table.control_period, target_checks=table.model.substeps)
    assert vf.landing_cells is not None and vf.safe_cells is None
    assert vf.landing_cells.key["target_checks"] == table.model.substeps
    # the package's cells were unpacked into the cache, one folder, and are read memory-mapped (the cache also holds
    # compiled code where the filter compiled in it)
    assert sorted(p.name.split("-")[2] for p in cache.glob("cells-*")) == ["land"]
    assert isinstance(vf.landing_cells.m.base, np.memmap) and isinstance(vf.landing_cells.hold.base, np.memmap)
    # a later filter reads the cache alone, not the package's file
    load = CellCertificate.load

    def from_the_cache(path, key=None):
        assert Path(path).is_dir(), f"read {path} again"
        return load(path, key)

    monkeypatch.setattr(CellCertificate, "load", staticmethod(from_the_cache))
    again = ValueFilter(table, table.control_period, target_checks=table.model.substeps)
    np.testing.assert_array_equal(again.landing_cells.m, vf.landing_cells.m)


def test_a_damaged_cache_folder_is_replaced(pointmass_held_table, tmp_path, monkeypatch):
    monkeypatch.setenv("SOFTREACH_CACHE", str(tmp_path))
    expected = np.array(ValueFilter(pointmass_held_table, 0.01).landing_cells.m)  # a copy, not the mapped file
    folder = next(p for p in tmp_path.iterdir() if "-land-" in p.name)
    (folder / "m.npy").write_bytes((folder / "m.npy").read_bytes()[:1000])
    with pytest.warns(UserWarning, match=f"rebuilding the cells: {folder}"):
        again = ValueFilter(pointmass_held_table, 0.01)
    np.testing.assert_array_equal(again.landing_cells.m, expected)
    assert (folder / "m.npy").stat().st_size > 1000


def test_cells_unpacked_from_another_package_file_are_replaced(pointmass_held_table, tmp_path, monkeypatch):
    """An upgrade whose package ships other cells for the same key: the cache then holds the installed package's,
    not the ones unpacked before it."""
    import shutil

    monkeypatch.setenv("SOFTREACH_CACHE", str(tmp_path / "cache"))
    package = tmp_path / "package"
    package.mkdir()
    for f in FILES:
        shutil.copy(f, package / f.name)
    monkeypatch.setattr(cell_certificate, "PACKAGED", package)
    table = pointmass_held_table
    first = ValueFilter(table, table.control_period)
    shipped = cell_certificate.cache_file(first.landing_cells.key, package)
    old = CellCertificate.load(shipped)
    # the next version's file: one good cell at t = 0 now never good
    m = np.array(old.m)
    good = int(np.flatnonzero(m[0] < old.never)[0])
    m[0].flat[good] = old.never
    CellCertificate(old.lo, old.hi, m, old.action, old.hold, old.candidates, old.dt, old.dz, old.horizon,
                    old.key).save(shipped)
    again = ValueFilter(table, table.control_period)
    assert again.landing_cells.m[0].flat[good] == old.never
    assert first.landing_cells.m[0].flat[good] < old.never  # the first filter's mapped cache was the old file


def test_cells_built_by_other_code_are_built_again(pointmass_held_table, tmp_path, monkeypatch):
    """Cells the package does not ship are built on the machine and keyed by the code that built them: the same code
    reads the cache, another version of the package builds them again."""
    monkeypatch.setenv("SOFTREACH_CACHE", str(tmp_path))
    table = pointmass_held_table
    la = Lookahead.from_table(table, table.model, 0.01, table.eps, target_checks=3)  # checks the package lacks
    builds = []

    def build(lookahead, shape, dz=None, holds=(1,), span_cap=32):
        # a stand-in build whose cells say which build made them
        builds.append(shape)
        key = cell_key(lookahead, shape, dz, holds, span_cap)
        m = np.full((round(lookahead.horizon / lookahead.dt) + 1,) + tuple(shape), len(builds), np.int16)
        lo, hi = lookahead.model.hard_box
        return CellCertificate(lo, hi, m, np.zeros(m.shape, np.int8), np.ones(m.shape, np.int8),
                               lookahead.candidates, lookahead.dt, key["dz"], lookahead.horizon, key)

    monkeypatch.setattr(CellCertificate, "build", staticmethod(build))
    first = cell_certificate.cached(la, (3, 4))
    assert len(builds) == 1 and (first.m == 1).all()
    assert (cell_certificate.cached(la, (3, 4)).m == 1).all() and len(builds) == 1
    monkeypatch.setattr(cell_certificate, "source_stamp", lambda: "another version of the package")
    again = cell_certificate.cached(la, (3, 4))
    assert len(builds) == 2 and (again.m == 2).all()
