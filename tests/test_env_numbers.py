"""The environments' own numbers against the boxes the filter proves with, for the three built-in systems, as
``benchmarks/env_error.py`` measures them: the states at a period's end against the end box widened by
``Lookahead.slack``, and RK4's stage states, where the env reads the budget's rate, against the boxes the filter
charges the budget by, widened by ``Lookahead.stage_slack`` (docs/filters.md, "Sound to the last bit")."""

from __future__ import annotations

import importlib.util
from pathlib import Path

import pytest

from softreach.reach import get_model

_PATH = Path(__file__).resolve().parents[1] / "benchmarks" / "env_error.py"


def _measure(name: str, starts: int, seed: int) -> dict:
    spec = importlib.util.spec_from_file_location("env_error", _PATH)
    mod = importlib.util.module_from_spec(spec)
    spec.loader.exec_module(mod)
    return mod.measure(name, starts, seed)


@pytest.mark.parametrize("name", ["pointmass", "glider", "dubins"])
def test_the_envs_states_and_stages_lie_in_the_filters_widened_boxes(name):
    """No tolerance beyond the slacks. Dubins's end states lie off the exact motion's end box by RK4's error, up to
    ``2 rk4_error``, which the rounding alone does not cover; the point mass's middle stages off the exact motion by
    up to ``h^2 / 8`` times the acceleration along the altitude, which its state slack does not cover: some lie
    beyond them, so the test tells the slacks' parts apart."""
    model = get_model(name)
    r = _measure(name, 100, 1)
    states, stages = r["slacks"]
    assert r["end"]["runs"] > 0 and r["stage"]["runs"] > 0
    assert r["end"]["covered"] == r["end"]["runs"], (r["end"]["worst"], states)
    assert r["stage"]["covered"] == r["stage"]["runs"], (r["stage"]["worst"], stages)
    h = model.control_period / model.substeps
    if name == "pointmass":
        assert (r["stage"]["worst"] > states).any() and r["stage"]["worst"][1] > 0.5 * model.rk4_stage_error(h)[1]
    if name == "dubins":
        assert r["end"]["worst"][:2].max() > 0.5 * model.substeps * model.rk4_error(h)[0]
