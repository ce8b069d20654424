"""examples/torch_reinforce.py: a plain-PyTorch learner on the registered ids, as docs/agents.md shows it."""

from __future__ import annotations

import importlib.util
import math
import os
import subprocess
import sys
from pathlib import Path

import pytest

import torch

EXAMPLE = Path(__file__).resolve().parents[1] / "examples" / "torch_reinforce.py"
#: what a learner that knows nothing of softreach reads from every step's info
ENV_KEYS = {"landed", "hard_violation", "budget_used", "cost", "soft_violation", "is_success"}


@pytest.fixture(scope="module")
def example():
    spec = importlib.util.spec_from_file_location("torch_reinforce", EXAMPLE)
    mod = importlib.util.module_from_spec(spec)
    spec.loader.exec_module(mod)
    return mod


def test_example_imports_nothing_from_softreach_but_the_filter():
    text = EXAMPLE.read_text()
    imports = [line.strip() for line in text.splitlines() if line.strip().startswith(("import ", "from "))]
    assert [line for line in imports if "softreach" in line] == ["from softreach.filters import SafetyFilter"]
    assert "agents" not in text.replace("agent", "")  # no softreach.agents helper


@pytest.mark.parametrize("env_id", ["softreach.envs:softreach/PointMassLanding-v0",
                                    "softreach.envs:softreach/GliderLanding-v0"])
def test_reinforce_runs_on_the_registered_ids(example, env_id):
    torch.set_num_threads(1)
    stats = example.train(env_id, steps=300, batch_steps=150, seed=0, log=lambda _: None)
    assert stats["steps"] >= 300 and len(stats["losses"]) >= 2
    assert all(math.isfinite(x) for x in stats["losses"])
    assert all(math.isfinite(x) for x in stats["mean_returns"])
    assert ENV_KEYS <= stats["info_keys"], ENV_KEYS - stats["info_keys"]
    # the optimiser stepped: the log standard deviation left its initial -0.5
    assert not torch.allclose(stats["agent"].log_std.detach(), torch.tensor(-0.5))


def test_reinforce_under_the_filter(example, pointmass_table_path):
    stats = example.train(steps=200, batch_steps=100, filter_table=str(pointmass_table_path), log=lambda _: None)
    assert all(math.isfinite(x) for x in stats["losses"])
    assert {"filter_active", "applied_action"} | ENV_KEYS <= stats["info_keys"]


def test_example_script_runs(tmp_path):
    env = {**os.environ, "OMP_NUM_THREADS": "1"}
    r = subprocess.run([sys.executable, str(EXAMPLE), "--steps", "200", "--batch-steps", "100"], cwd=tmp_path,
                       capture_output=True, text=True, env=env, timeout=300)
    assert r.returncode == 0, r.stderr
    assert "losses finite: True" in r.stdout
    assert r.stdout.count("steps ") >= 2  # one line per update


def test_docs_excerpts_match_the_example():
    """Each code block that docs/agents.md marks as an excerpt of the example is a contiguous piece of the file
    (dedented as a whole), so the docs cannot drift from the code CI runs."""
    import re
    import textwrap

    docs = (EXAMPLE.parents[1] / "docs" / "agents.md").read_text()
    blocks = re.findall(r"<!-- excerpt of examples/torch_reinforce\.py[^>]*-->\n```python\n(.*?)```", docs, re.S)
    assert len(blocks) == 2
    code = EXAMPLE.read_text()
    for block in blocks:
        assert any(textwrap.indent(block, " " * k) in code for k in (0, 4, 8)), block[:80]
    assert 'gym.make(env_id' in blocks[0]
