"""The environments never use torch, so importing, making and stepping them must not import it (torch's import is
most of a second or more); and the package's public names still load on demand."""

from __future__ import annotations

import subprocess
import sys
import textwrap


def _run(code: str, timeout: float = 120) -> subprocess.CompletedProcess:
    """``code`` in a fresh interpreter (this one has torch loaded by other tests)."""
    return subprocess.run([sys.executable, "-c", textwrap.dedent(code)], capture_output=True, text=True,
                          timeout=timeout)


def test_import_envs_does_not_import_torch():
    done = _run("import softreach.envs, sys; assert 'torch' not in sys.modules, 'torch imported'; print('ok')")
    assert done.returncode == 0 and done.stdout.strip() == "ok", done.stderr


def test_make_reset_and_step_every_env_without_torch():
    done = _run("""
        import sys
        import gymnasium as gym
        import softreach.envs
        from softreach.reach.models import get_model
        for env_id in softreach.envs.ENV_IDS:
            kwargs = {"model": get_model("pointmass")} if env_id == "softreach/SoftReach-v0" else {}
            env = gym.make(env_id, **kwargs)
            env.reset(seed=0)
            obs, reward, terminated, truncated, info = env.step(env.action_space.sample())
            assert env.observation_space.contains(obs), (env_id, obs)
            assert "torch" not in sys.modules, f"torch imported by {env_id}"
            env.close()
        print("ok")
    """)
    assert done.returncode == 0 and done.stdout.strip() == "ok", done.stderr


def test_public_names_load_on_first_use():
    done = _run("""
        import sys
        import softreach.reach as reach
        from softreach.reach import (Grid, Model, ReachAvoidProblem, SolveConfig, SolverSettings, Table, TableError,
                                     budget_axis, classical_problem, get_model, load_table, soft_problem, solve,
                                     solve_table)
        from softreach.reach.numerics.compute import solve_table as defined
        assert solve_table is defined and reach.solve_table is defined
        assert set(reach.__all__) <= set(dir(reach))
        try:
            reach.no_such_name
        except AttributeError as err:
            assert "no_such_name" in str(err)
        else:
            raise AssertionError("an unknown name must raise AttributeError")
        print("ok")
    """)
    assert done.returncode == 0 and done.stdout.strip() == "ok", done.stderr


def test_the_filter_decides_without_torch(pointmass_held_table):
    """A process that filters an environment needs no torch: it costs the filter's user seconds at start-up. A tensor
    can only come from a process that imported torch, so the filter asks for it only there."""
    done = _run(f"""
        import sys
        import numpy as np
        import gymnasium as gym
        import softreach.envs
        from softreach.filters import SafetyFilter
        env = SafetyFilter(gym.make("softreach/PointMassLanding-v0"), {str(pointmass_held_table.path)!r})
        env.reset(seed=0)
        env.step(np.zeros(1, np.float32))
        assert "torch" not in sys.modules, "torch imported"
        from softreach.filters import VecSafetyFilter
        assert VecSafetyFilter.__name__ == "VecSafetyFilter" and "torch" in sys.modules
        print("ok")
    """, timeout=900)  # it compiles the filter where this run's warm-up has not (conftest.py)
    assert done.returncode == 0 and done.stdout.strip() == "ok", done.stderr
