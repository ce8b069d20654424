"""The glider in agents/: an evaluation without the filter certifies its starts with the landing checks of the
environment's own SafetyFilter (the glider checks landing at 2 instants per period, and its shipped cells are for
those 2), so the rows alone and under the filter share their certified starts."""

from __future__ import annotations

from types import SimpleNamespace

import pytest

import softreach.filters as filters_pkg
from softreach.agents.envs import make_env
from softreach.agents.evaluate import certifier


class _RecordingFilter:
    """Stands in for ValueFilter: records how the certifier built it (no table, no cells)."""

    made: list[dict] = []

    def __init__(self, table, dt, **kwargs):
        self.table, self.dt, self.kwargs = table, dt, kwargs
        self.sampled = self.certifiable = True
        _RecordingFilter.made.append({"dt": dt, **kwargs})


@pytest.mark.parametrize("model", ["glider", "pointmass"])
def test_certifier_without_filter_uses_the_environments_landing_checks(model, monkeypatch):
    _RecordingFilter.made = []
    monkeypatch.setattr(filters_pkg, "ValueFilter", _RecordingFilter)
    env = make_env(model, wind="random")
    try:
        base = env.unwrapped
        assert base.n_substeps > 1  # otherwise the default of 1 check would pass this test by accident
        vf = certifier(SimpleNamespace(path="unused.srt"), env)
        assert isinstance(vf, _RecordingFilter)
        assert _RecordingFilter.made == [{"dt": float(base.dt), "model": base.model, "target_checks": base.n_substeps}]
    finally:
        env.close()
