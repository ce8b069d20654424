"""The landing environments as other code uses them: checkers, seeding, pickling, vector envs, SB3, rendering."""

from __future__ import annotations

import math
import pickle
import subprocess
import sys
import warnings

import numpy as np
import pytest

import gymnasium as gym

import softreach.envs  # noqa: F401  (registers the ids)
from softreach.envs import GliderLandingEnv, PointMassLandingEnv

PM = "softreach/PointMassLanding-v0"
GL = "softreach/GliderLanding-v0"
IDS = [PM, GL]


def rollout(env, actions, seed):
    """Observations, rewards, flags and the scalar part of the infos along a fixed action sequence."""
    obs, info = env.reset(seed=seed)
    out = [obs.tolist()]
    for a in actions:
        obs, r, term, trunc, info = env.step(a)
        out.append((obs.tolist(), r, term, trunc, info["budget"], info["cost"], info["wind"].tolist()))
        if term or trunc:
            obs, info = env.reset()
            out.append(obs.tolist())
    return out


@pytest.mark.parametrize("env_id", IDS)
@pytest.mark.parametrize("render_mode", [None, "rgb_array"])
def test_gymnasium_check_env_passes_without_warnings(env_id, render_mode):
    from gymnasium.utils.env_checker import check_env

    env = gym.make(env_id, render_mode=render_mode)
    with warnings.catch_warnings(record=True) as caught:
        warnings.simplefilter("always")
        check_env(env.unwrapped)
    assert [str(w.message) for w in caught] == []


@pytest.mark.parametrize("env_id", IDS)
def test_sb3_check_env_passes_without_warnings(env_id):
    from stable_baselines3.common.env_checker import check_env

    with warnings.catch_warnings(record=True) as caught:
        warnings.simplefilter("always")
        check_env(gym.make(env_id))
    assert [str(w.message) for w in caught] == []


@pytest.mark.parametrize("env_id", IDS)
def test_seeded_determinism_with_random_wind(env_id):
    actions = np.random.default_rng(0).uniform(-1, 1, (150, 1)).astype(np.float32)
    a = rollout(gym.make(env_id, wind="random"), actions, seed=123)
    b = rollout(gym.make(env_id, wind="random"), actions, seed=123)
    c = rollout(gym.make(env_id, wind="random"), actions, seed=124)
    assert a == b
    assert a[0] != c[0]


@pytest.mark.parametrize("env_cls", [PointMassLandingEnv, GliderLandingEnv])
def test_pickle_mid_episode_continues_identically(env_cls):
    env = env_cls(wind="random", render_mode="rgb_array")
    env.reset(seed=7)
    for _ in range(5):
        env.step(np.float32([0.1]))
    env.render()  # a live figure must not stop pickling
    clone = pickle.loads(pickle.dumps(env))
    assert clone._renderer is None
    for k in range(20):
        a = np.float32([math.sin(k)])
        ra, rb = env.step(a), clone.step(a)
        np.testing.assert_array_equal(ra[0], rb[0])
        assert ra[1:4] == rb[1:4]
        assert ra[4]["budget"] == rb[4]["budget"] and ra[4]["wind"] == rb[4]["wind"]
        if ra[2] or ra[3]:
            break
    assert clone.render().shape == env.render().shape
    env.close()
    clone.close()


@pytest.mark.process
def test_sync_and_async_vector_envs_agree_and_autoreset():
    actions = np.random.default_rng(1).uniform(-1, 1, (120, 3, 1)).astype(np.float32)
    results = {}
    for mode in ("sync", "async"):
        venv = gym.make_vec(PM, num_envs=3, vectorization_mode=mode, wind="random")
        obs, info = venv.reset(seed=[10, 11, 12])
        trace = [obs.copy()]
        ends = 0
        for a in actions:  # 120 steps > 100: every sub-env reaches its end and is reset automatically
            obs, rew, term, trunc, info = venv.step(a)
            assert obs.shape == (3, 4) and obs.dtype == np.float32
            assert rew.shape == (3,) and term.dtype == np.bool_ and trunc.dtype == np.bool_
            assert set(info) >= {"budget", "cost", "landed", "hard_violation", "wind"}
            ends += int(np.sum(term | trunc))
            trace.append((obs.copy(), rew.copy(), term.copy(), trunc.copy(), info["budget"].copy()))
        venv.close()
        assert ends >= 3
        results[mode] = trace
    for s, a in zip(results["sync"], results["async"]):
        for u, v in zip(s if isinstance(s, tuple) else (s,), a if isinstance(a, tuple) else (a,)):
            np.testing.assert_array_equal(u, v)


@pytest.mark.process
def test_async_vector_env_with_spawn_context():
    """A fresh interpreter per worker: the spec's entry point must import and register the package itself."""
    venv = gym.make_vec(GL, num_envs=2, vectorization_mode="async", vector_kwargs={"context": "spawn"})
    try:
        obs, _ = venv.reset(seed=0)
        assert obs.shape == (2, 5)
        obs, rew, term, trunc, info = venv.step(np.zeros((2, 1), dtype=np.float32))
        assert np.all(np.isfinite(obs)) and obs.shape == (2, 5)
    finally:
        venv.close()


def test_sb3_make_vec_env_and_short_training():
    from stable_baselines3 import PPO
    from stable_baselines3.common.env_util import make_vec_env

    venv = make_vec_env(PM, n_envs=2, seed=0, env_kwargs={"wind": "random"})
    obs = venv.reset()
    assert obs.shape == (2, 4)
    model = PPO("MlpPolicy", venv, n_steps=64, batch_size=64, n_epochs=1, seed=0, device="cpu")
    model.learn(total_timesteps=256)
    action, _ = model.predict(obs, deterministic=True)
    obs, rew, done, infos = venv.step(action)
    assert obs.shape == (2, 4) and len(infos) == 2 and "cost" in infos[0]
    venv.close()


# --------------------------------------------------------------------------------------------- rendering


@pytest.mark.parametrize("env_id", IDS)
def test_rgb_array_frames(env_id):
    env = gym.make(env_id, render_mode="rgb_array")
    env.reset(seed=0)
    first = env.render()
    assert first.shape == (400, 640, 3) and first.dtype == np.uint8
    assert first.std() > 10  # a drawing, not a blank canvas
    for _ in range(10):
        env.step(np.float32([0.5]))
    later = env.render()
    assert later.shape == first.shape and np.any(later != first)
    env.close()


def test_render_without_mode_warns_and_human_needs_display(monkeypatch):
    env = PointMassLandingEnv()
    env.reset(seed=0)
    with pytest.warns(UserWarning, match="render_mode"):
        assert env.render() is None
    monkeypatch.delenv("DISPLAY", raising=False)
    monkeypatch.delenv("WAYLAND_DISPLAY", raising=False)
    if sys.platform.startswith("linux"):
        with pytest.raises(RuntimeError, match="display"):
            PointMassLandingEnv(render_mode="human")
    with pytest.raises(ValueError, match="render_mode"):
        PointMassLandingEnv(render_mode="ansi")


def test_fresh_interpreter_module_colon_id_and_no_matplotlib_unless_rendering():
    """``gymnasium.make("softreach.envs:...")`` works without importing softreach first, and neither that nor
    stepping imports matplotlib; drawing a frame does."""
    code = (
        "import sys, numpy as np, gymnasium as gym\n"
        "for env_id in ('softreach.envs:softreach/PointMassLanding-v0', 'softreach/GliderLanding-v0'):\n"
        "    env = gym.make(env_id)\n"
        "    env.reset(seed=0)\n"
        "    env.step(np.zeros(1, dtype=np.float32))\n"
        "assert 'matplotlib' not in sys.modules, 'matplotlib imported without rendering'\n"
        "env = gym.make('softreach/PointMassLanding-v0', render_mode='rgb_array')\n"
        "env.reset(seed=0)\n"
        "assert 'matplotlib' not in sys.modules\n"
        "assert env.render().shape == (400, 640, 3)\n"
        "assert 'matplotlib' in sys.modules\n"
        "print('ok')\n"
    )
    out = subprocess.run([sys.executable, "-c", code], capture_output=True, text=True, timeout=120)
    assert out.returncode == 0, out.stderr
    assert out.stdout.strip() == "ok"
