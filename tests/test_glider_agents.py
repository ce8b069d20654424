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


class _RecordingSafetyFilter:
    """Stands in for SafetyFilter: keeps the shared core it is handed."""

    def __init__(self, env, *, value_filter):
        self.env, self.value_filter = env, value_filter


@pytest.mark.parametrize("model", ["glider", "pointmass"])
def test_shared_filter_core_uses_the_environments_landing_checks(model, monkeypatch):
    """The core ``safety_filter`` shares is the one SafetyFilter builds for itself: landing checked at the
    environment's sub-step ends (with 1 check the glider's shipped cells do not apply and are built first)."""
    import softreach.agents.tables as tables_mod

    _RecordingFilter.made = []
    monkeypatch.setattr(filters_pkg, "ValueFilter", _RecordingFilter)
    monkeypatch.setattr(filters_pkg, "SafetyFilter", _RecordingSafetyFilter)
    monkeypatch.setattr(tables_mod, "as_table", lambda t: t)
    monkeypatch.setattr(tables_mod, "_FILTER_CACHE", {})
    table = SimpleNamespace(path=f"{model}-unused.srt")
    envs = [make_env(model, wind="random") for _ in range(2)]
    try:
        base = envs[0].unwrapped
        assert base.n_substeps > 1
        wrapped = [tables_mod.safety_filter(e, table) for e in envs]
        assert _RecordingFilter.made == [{"dt": float(base.dt), "margin": None, "rule": "switch", "model": base.model,
                                          "target_checks": base.n_substeps}]
        assert wrapped[0].value_filter is wrapped[1].value_filter  # one core for both environments
    finally:
        for e in envs:
            e.close()


def test_certifier_takes_the_filter_of_the_same_table_file(monkeypatch):
    """A sweep loads the table again for each evaluation; the certifier still uses the environment's filter core
    (its cells, its compiled decision) rather than building a second one for the same file."""
    made = []
    monkeypatch.setattr(filters_pkg, "ValueFilter", lambda *a, **k: made.append(k))
    core = SimpleNamespace()
    filt = SimpleNamespace(table=SimpleNamespace(path="runs/../runs/glider-held.srt"), value_filter=core)
    monkeypatch.setattr("softreach.agents.evaluate.unwrap_filter", lambda env: filt)
    assert certifier(SimpleNamespace(path="runs/glider-held.srt"), env=None) is core
    assert made == []
    # another file: its own certifier
    vf = SimpleNamespace()
    monkeypatch.setattr(filters_pkg, "ValueFilter", lambda *a, **k: vf)
    env = SimpleNamespace(unwrapped=SimpleNamespace(dt=0.1, model=None, n_substeps=2))
    assert certifier(SimpleNamespace(path="runs/other.srt"), env=env) is vf
