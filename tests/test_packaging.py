"""Packaging: one import namespace, no bare top-level envs/reach/filters/agents module installed."""

from __future__ import annotations

import subprocess
import sys


def test_sub_packages_import_under_softreach_and_no_bare_names(tmp_path):
    # run outside the repository so that the source folders on the current directory cannot be found
    code = (
        "import importlib.util as u, pathlib, softreach.reach, softreach.envs, softreach.filters, softreach.agents\n"
        "ours = str(pathlib.Path(softreach.reach.__file__).resolve().parents[1])\n"
        "bare = [n for n in ('envs', 'reach', 'filters', 'agents') if u.find_spec(n) is not None "
        "and str(pathlib.Path(u.find_spec(n).origin or '').resolve()).startswith(ours)]\n"
        "print('BARE', bare)\n"
    )
    r = subprocess.run([sys.executable, "-c", code], cwd=tmp_path, capture_output=True, text=True)
    assert r.returncode == 0, r.stderr
    assert "BARE []" in r.stdout, r.stdout
