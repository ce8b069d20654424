"""The cells the package ships (``reach/cells/``) are what a fresh build gives, and a filter on a new machine uses
them instead of building."""

from __future__ import annotations

import json

import numpy as np
import pytest

from softreach.filters import ValueFilter
from softreach.reach import cell_certificate
from softreach.reach.cell_certificate import PACKAGED, CellCertificate, cell_key
from softreach.reach.lookahead import Lookahead

FILES = sorted(PACKAGED.glob("cells-*.npz"))


def test_the_package_ships_the_default_point_mass_cells():
    # the filter's default target_checks (1) and the environment's (its 10 sub-steps), both games
    keys = [json.loads(str(np.load(f)["key"])) for f in FILES]
    assert sorted((k["model"], k["game"], k["target_checks"]) for k in keys) == [
        ("pointmass", "land", 1), ("pointmass", "land", 10), ("pointmass", "safe", 1), ("pointmass", "safe", 10)]


@pytest.mark.slow
@pytest.mark.parametrize("path", FILES, ids=lambda p: p.name)
def test_packaged_cells_equal_a_fresh_build(path, pointmass_held_table):
    stored = CellCertificate.load(path)
    table = pointmass_held_table
    la = Lookahead.from_table(table, table.model, table.control_period, table.eps,
                              target_checks=stored.key["target_checks"])
    key = cell_key(la, stored.shape, game=stored.game, holds=stored.key["holds"])
    assert key == stored.key  # the test table's candidates, period and horizon are the default ones
    fresh = CellCertificate.build(la, stored.shape, game=stored.game, holds=stored.key["holds"])
    for name in ("m", "action", "hold", "lo", "hi"):
        np.testing.assert_array_equal(getattr(fresh, name), getattr(stored, name), err_msg=name)


def test_a_new_machine_reads_the_packaged_cells_without_building(pointmass_held_table, tmp_path, monkeypatch):
    monkeypatch.setenv("SOFTREACH_CACHE", str(tmp_path / "empty"))

    def no_build(*args, **kwargs):
        raise AssertionError("built cells although the package ships them")

    monkeypatch.setattr(cell_certificate.CellCertificate, "build", no_build)
    vf = ValueFilter(pointmass_held_table, 0.01, target_checks=10)
    assert vf.landing_cells is not None and vf.safe_cells is not None
    assert vf.landing_cells.key["target_checks"] == 10
    assert not (tmp_path / "empty").exists()  # nothing written either
