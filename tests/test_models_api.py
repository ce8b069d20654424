"""The public model API: the registry, a user's model by ``module:Class`` (the docs/models.md example, run as
written), the generic environment, and ``dubins`` through solve, plot, the filter, train and evaluate."""

from __future__ import annotations

import json
import re
import shlex
from pathlib import Path

import gymnasium as gym
import numpy as np
import pytest

import softreach.envs  # noqa: F401
from softreach.cli import main
from softreach.reach import get_model, registry

from cell_plans import run_certified_episode

DOC = Path(__file__).resolve().parents[1] / "docs" / "models.md"


def _blocks(kind: str) -> list[str]:
    return re.findall(rf"```{kind}\n(.*?)```", DOC.read_text(), flags=re.S)


# ------------------------------------------------------------------------------------------ registry

def test_registry_maps_names_to_classes_env_ids_and_cli_choices():
    names = registry.model_names()
    assert {"pointmass", "glider", "dubins"} <= set(names)
    assert registry.env_id("pointmass") == "softreach/PointMassLanding-v0"
    assert registry.env_id("glider") == "softreach/GliderLanding-v0"
    assert registry.env_id("dubins") == registry.GENERIC_ENV_ID == "softreach/SoftReach-v0"
    for name in names:
        assert registry.env_id(name) in gym.registry
        assert registry.model_class(name).name == name
    # a class path names the same class as the short name
    cls = registry.model_class("softreach.reach.models.dubins:Dubins")
    assert cls is registry.model_class("dubins")
    assert registry.spec_of(get_model("dubins")) == "dubins"
    from softreach.agents.config import ENV_IDS, MODELS

    assert set(MODELS) == set(names) and ENV_IDS == registry.env_ids()


@pytest.mark.parametrize("spec, message", [
    ("nosuchmodel", "nosuchmodel"),
    ("no_such_module_xyz:Model", "no_such_module_xyz"),
    ("softreach.reach.models.dubins:NoSuchClass", "NoSuchClass"),
    ("softreach.reach.models.dubins:DubinsParams", "not a subclass"),
])
def test_bad_model_names_are_refused_naming_the_value(spec, message):
    with pytest.raises(ValueError, match=message):
        get_model(spec)


def test_cli_refuses_an_unknown_model_naming_it(capsys):
    with pytest.raises(SystemExit) as exc:
        main(["solve", "nosuchmodel"])
    assert exc.value.code == 2
    assert "nosuchmodel" in capsys.readouterr().err
    with pytest.raises(SystemExit):
        main(["train", "nosuchmodel"])


# ------------------------------------------------------------------------------------------ docs/models.md

def test_the_bring_your_own_system_example_runs_as_written(tmp_path, monkeypatch, capsys):
    """docs/models.md: the module, the shell commands (``softreach solve cart:Cart``, ``plot``) and the Python
    that simulates the table's policy in the generic env, each run as the page shows it."""
    module, usage = _blocks("python")
    assert module.startswith("# cart.py")
    (tmp_path / "cart.py").write_text(module)
    monkeypatch.syspath_prepend(str(tmp_path))
    monkeypatch.chdir(tmp_path)
    commands = [line for line in _blocks("bash")[0].splitlines() if line.startswith("softreach ")]
    assert [c.split()[1] for c in commands] == ["solve", "plot"]
    for line in commands:
        assert main(shlex.split(line)[1:] + (["--quiet"] if " solve " in f" {line} " else [])) == 0
    assert (tmp_path / "cart.png").stat().st_size > 10_000
    from softreach.reach import load_table

    table = load_table(tmp_path / "cart.srt")
    assert table.model_metadata["class"] == "cart:Cart"
    # the budget buys states: RA~_1 is larger than RA~_0, which is the classical set up to a cell's worth
    assert table.set_mask(0.0, 1.0).sum() > table.set_mask(0.0, 0.0).sum() > 0
    exec(compile(usage, "docs/models.md", "exec"), {})
    out = capsys.readouterr().out
    assert re.search(r"RA~_0\.5 holds \d+ grid nodes", out)
    assert re.search(r"(reached|failed) using [\d.]+ s of budget", out)


# ------------------------------------------------------------------------------------------ generic env

def test_generic_env_with_the_point_mass_steps_as_its_landing_env():
    """SoftReach-v0 is the landing envs' machinery: with the point mass (same period, sub-steps, starts and
    budgets, declared on the model) it gives the same observations, rewards and ends as PointMassLanding-v0."""
    a = gym.make("softreach/SoftReach-v0", model=get_model("pointmass"), wind="random", budget_resolution=1e-6)
    b = gym.make("softreach/PointMassLanding-v0", wind="random")
    rng = np.random.default_rng(0)
    for seed in range(3):
        oa, _ = a.reset(seed=seed)
        ob, _ = b.reset(seed=seed)
        np.testing.assert_array_equal(oa, ob)
        done = False
        while not done:
            act = rng.uniform(-1, 1, 1).astype(np.float32)
            oa, ra, ta, ua, ia = a.step(act)
            ob, rb, tb, ub, ib = b.step(act)
            np.testing.assert_array_equal(oa, ob)
            assert ra == rb and ta == tb and ua == ub and ia["landed"] == ib["landed"]
            done = ta or ua


def test_generic_env_checks_and_refuses_what_it_cannot_run():
    from gymnasium.utils.env_checker import check_env

    env = gym.make("softreach/SoftReach-v0", model=get_model("dubins"))
    check_env(env.unwrapped, skip_render_check=True)
    assert env.observation_space.shape == (5,)  # x, y, theta, budget z, time left
    with pytest.raises(ValueError, match="model="):
        gym.make("softreach/SoftReach-v0")
    no_starts = get_model("dubins")
    no_starts.start_box = None
    with pytest.raises(ValueError, match="start_box"):
        gym.make("softreach/SoftReach-v0", model=no_starts)
    with pytest.raises(ValueError, match="x=9.0"):
        env.reset(options={"state": [9.0, 0.0, 0.0]})


# ------------------------------------------------------------------------------------------ dubins via the CLI

def test_softreach_solve_and_plot_dubins(tmp_path, capsys):
    out = tmp_path / "d.srt"
    assert main(["solve", "dubins", "--grid", "21", "21", "12", "--budget-points", "12", "--accuracy", "medium",
                 "--snapshots", "5", "--out", str(out), "--quiet", "--threads", "1"]) == 0
    printed = capsys.readouterr().out
    measures = [float(v) for v in re.findall(r"RA~_Q measure, Q=[\d.]+: ([\d.]+)", printed)]
    assert len(measures) == 4 and measures == sorted(measures) and measures[-1] > measures[0]
    from softreach.reach import load_table

    table = load_table(out)
    assert table.grid("V").periodic == (False, False, True)
    png = tmp_path / "d.png"
    assert main(["plot", str(out), "--out", str(png), "--slice", "0"]) == 0
    assert png.stat().st_size > 20_000


def test_a_held_solve_takes_its_candidate_actions_from_the_model(tmp_path):
    """``held_levels`` lives on the model: the sampled-data solve (and so the filter, which takes its candidates from
    the table) holds that many evenly spaced values of each control, the box's ends among them."""
    from softreach.reach import SolveConfig, SolverSettings, load_table, solve_table

    model = get_model("dubins")
    model.held_levels = 3
    lo, hi = (float(v[0]) for v in model.control_bounds)
    cfg = SolveConfig(shape=(11, 11, 8), budget_points=8, control_period=0.1,
                      settings=SolverSettings.from_accuracy("low", dtype="float32", compile=False))
    solve_table(model, cfg, tmp_path / "d.srt", progress=False)
    held = load_table(tmp_path / "d.srt").header["fields"]["W_eps"]["held_controls"]
    assert sorted(a[0] for a in held) == pytest.approx([lo, 0.5 * (lo + hi), hi])
    with pytest.raises(ValueError, match="levels must be an integer >= 2, got 1"):
        model.held_candidates(1)


# ------------------------------------------------------------------------------------------ filter, train, evaluate

def test_safety_filter_on_the_generic_env_keeps_its_guarantee(dubins_held_table):
    """From certified starts, under random gusts and a random policy, the filtered Dubins vehicle keeps the promise
    its cells prove (``Dubins.cell_shape``; the coarse table only ranks candidates): every step certified, no hard
    violation, no overspend, every run lands."""
    from softreach.agents.tables import sample_inside
    from softreach.filters import SafetyFilter

    table = dubins_held_table
    env = SafetyFilter(gym.make("softreach/SoftReach-v0", model=get_model("dubins"), wind="random"), table)
    assert env.value_filter.landing_cells is not None
    rng = np.random.default_rng(0)
    env.action_space.seed(0)
    runs = 0
    for ep in range(40):
        q = float(rng.choice([0.0, 1.0, 2.0]))
        obs, info = env.reset(seed=ep, options={"state": sample_inside(table, q, rng).tolist(), "budget": q})
        if not info["certified"]:
            continue  # in the table's set, not in the cells'
        run_certified_episode(env, q)
        runs += 1
        if runs == 6:
            break
    assert runs == 6


def test_train_and_evaluate_dubins_smoke(tmp_path, dubins_held_table):
    run = tmp_path / "run"
    assert main(["train", "dubins", "--timesteps", "256", "--n-envs", "1", "--eval-freq", "0", "--wind", "none",
                 "--out", str(run), "--quiet"]) == 0
    config = json.loads((run / "config.json").read_text())
    assert config["env_id"] == "softreach/SoftReach-v0" and config["model"] == "dubins"
    assert config["timesteps"] >= 256
    report = tmp_path / "eval.json"
    assert main(["evaluate", "dubins", "--policy", str(run / "model.zip"), "--filter", str(dubins_held_table.path),
                 "--episodes", "3", "--starts", "inside", "--budget", "1.0", "--json", str(report), "--quiet"]) == 0
    res = json.loads(report.read_text())
    rows = res["episodes"]
    assert len(rows) == 3
    for row in rows:
        assert row["start_inside"] and not row["hard_violation"] and not row["over_budget"]
        assert row["touchdown_sink_rate"] is None  # the Dubins vehicle has no sink rate
