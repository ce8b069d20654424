"""``softreach solve --held`` takes a model's held_shape / held_budget_points; the continuous game and an explicit
``--grid`` / ``--budget-points`` do not."""

from __future__ import annotations

import pytest

from softreach.cli import main
from softreach.reach.numerics import compute


@pytest.fixture
def configs(monkeypatch):
    seen = []

    def fake_solve(model, cfg, out, **kw):  # records what would be solved, solves nothing
        seen.append(cfg)
        raise SystemExit(0)

    monkeypatch.setattr(compute, "solve_table", fake_solve)
    return seen


@pytest.mark.parametrize("argv, shape, nz", [
    (["--held"], (51, 51), 56),                                     # the point mass's held_shape
    (["--control-period", "0.02"], (51, 51), 56),                   # a period implies the held game
    ([], (101, 101), 111),                                          # the continuous game keeps default_shape
    (["--held", "--grid", "61", "61"], (61, 61), 56),               # an explicit grid wins, per argument
    (["--held", "--budget-points", "67"], (51, 51), 67),
])
def test_held_solve_default_grid(configs, tmp_path, argv, shape, nz):
    with pytest.raises(SystemExit):
        main(["solve", "pointmass", *argv, "--quiet", "--out", str(tmp_path / "t.srt")])
    assert configs[-1].shape == shape and configs[-1].budget_points == nz


def test_model_without_held_shape_keeps_its_default(configs, tmp_path):
    from softreach.reach.models import get_model

    g = get_model("glider")
    assert getattr(g, "held_shape", None) is None
    with pytest.raises(SystemExit):
        main(["solve", "glider", "--held", "--quiet", "--out", str(tmp_path / "g.srt")])
    assert configs[-1].shape == tuple(g.default_shape) and configs[-1].budget_points == g.default_budget_points
