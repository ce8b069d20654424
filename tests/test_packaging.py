"""Packaging: one import namespace, no bare top-level envs/reach/filters/agents module installed."""

from __future__ import annotations

import importlib.metadata as md


def test_sub_packages_import_under_softreach():
    import softreach.agents
    import softreach.envs
    import softreach.filters
    import softreach.reach

    assert softreach.reach.load_table and softreach.envs


def test_no_bare_top_level_package_is_installed():
    dist = md.distribution("softreach")
    top = (dist.read_text("top_level.txt") or "").split()
    files = [str(f) for f in (dist.files or [])]
    for bare in ("envs", "reach", "filters", "agents"):
        assert bare not in top
        assert not any(f.startswith(f"{bare}/") for f in files), bare
