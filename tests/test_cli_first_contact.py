"""The command line on first contact (issue 39): every option explained, one clear line for a wrong table, start,
policy or seed, Ctrl-C of ``train`` saved and resumable, a user's model found from the current directory, and a
first compile that says what it is doing. Tables here are tiny (11 x 11 x 9) and training runs a few rollouts."""

from __future__ import annotations

import argparse
import json
import sys
import textwrap
from pathlib import Path

import pytest
from cell_plans import without_cells

from softreach.cli import build_parser, main

TINY = ["--grid", "11", "11", "--budget-points", "9", "--snapshots", "3", "--accuracy", "low", "--compile", "no",
        "--quiet"]


@pytest.fixture(scope="module")
def tiny_table(tmp_path_factory) -> Path:
    """A continuous-time point-mass table, 11 x 11 x 9 (what `softreach solve pointmass` writes, coarser)."""
    path = tmp_path_factory.mktemp("first_contact") / "pointmass.srt"
    assert main(["solve", "pointmass", *TINY, "--out", str(path)]) == 0
    return path


def _one_line_error(capsys) -> str:
    err = capsys.readouterr().err.strip()
    assert "Traceback" not in err and len(err.splitlines()) == 1, err
    return err


# ------------------------------------------------------------------------------------------------ help, version

def _subparsers(parser: argparse.ArgumentParser) -> dict[str, argparse.ArgumentParser]:
    (sub,) = [a for a in parser._actions if isinstance(a, argparse._SubParsersAction)]
    return dict(sub.choices)


def test_every_option_of_every_subcommand_has_help():
    subs = _subparsers(build_parser())
    assert {"solve", "plot", "study", "compile", "train", "evaluate", "demo", "sweep"} <= set(subs)
    missing = [f"{name} {a.option_strings[0] if a.option_strings else a.dest}"
               for name, p in subs.items() for a in p._actions
               if not isinstance(a, argparse._HelpAction) and (not a.help or a.help == argparse.SUPPRESS
                                                               or not a.help.strip())]
    assert missing == []


@pytest.mark.parametrize("command,option,words", [
    ("solve", "--backend", ["numpy"]), ("solve", "--dtype", ["float32", "table"]),
    ("plot", "table", ["softreach solve"]), ("plot", "--t", ["seconds"]),
    ("evaluate", "--wind", ["default"]), ("demo", "--seed", ["evaluation seed", "--eval-seed"]),
])
def test_the_options_the_issue_named_say_what_they_do(command, option, words):
    p = _subparsers(build_parser())[command]
    (action,) = [a for a in p._actions if option in a.option_strings or a.dest == option]
    for w in words:
        assert w in action.help, (option, action.help)


def test_version(capsys):
    from importlib.metadata import version

    with pytest.raises(SystemExit) as stop:
        main(["--version"])
    assert stop.value.code == 0
    assert capsys.readouterr().out.strip() == f"softreach {version('softreach')}"


# ------------------------------------------------------------------------------------------------ solve, plot, compile

def test_a_resumed_solve_says_it_resumed(tmp_path, capsys, monkeypatch):
    from softreach.reach.tables.table import TableWriter

    out = tmp_path / "pm.srt"
    real = TableWriter.write_snapshot
    calls = []

    def interrupt_after_two(self, field, k, value):
        calls.append(field)
        if len(calls) == 3:  # V's first two snapshots are on disk, then Ctrl-C
            raise KeyboardInterrupt
        return real(self, field, k, value)

    monkeypatch.setattr(TableWriter, "write_snapshot", interrupt_after_two)
    assert main(["solve", "pointmass", *TINY, "--out", str(out)]) == 130
    assert "resume" in capsys.readouterr().err and not out.exists()
    monkeypatch.setattr(TableWriter, "write_snapshot", real)
    assert main(["solve", "pointmass", *TINY, "--out", str(out)]) == 0
    std = capsys.readouterr()
    assert "resuming the interrupted solve" in std.err and "V 2/3" in std.err and "W_eps 0/3" in std.err
    assert "(resumed: the interrupted run's solver time included)" in std.out
    # a fresh solve says nothing of the kind
    assert main(["solve", "pointmass", *TINY, "--out", str(tmp_path / "other.srt")]) == 0
    std = capsys.readouterr()
    assert "resuming the interrupted solve" not in std.err and "(resumed:" not in std.out


def test_compile_says_which_table_it_needs(tiny_table, capsys, monkeypatch):
    # the point mass has cells: a continuous-time table ranks for them, at the model's control period
    assert main(["compile", str(tiny_table)]) == 0
    assert "pointmass's filter" in capsys.readouterr().out
    # a model without cells has no certificate: refused, naming what to add
    without_cells(monkeypatch)
    assert main(["compile", str(tiny_table)]) == 2
    err = _one_line_error(capsys)
    assert "cell_shape = (cells per state axis" in err and "docs/models.md" in err


@pytest.mark.parametrize("start,words", [
    ("--from=999,999:0.3", ["v=999 not in [-20, 20] m/s", "y=999 not in [-5, 20] m"]),
    ("--from=0,-6:0.3", ["y=-6 not in [-5, 20] m"]),
    ("--from=0,4:7", ["Q=7 must lie in [0, T] = [0, 1] s"]),
    ("--from=nan,4:0.3", ["v=nan"]),
])
def test_plot_refuses_a_start_outside_the_table(tiny_table, tmp_path, capsys, start, words):
    png = tmp_path / "fig.png"
    assert main(["plot", str(tiny_table), start, "--out", str(png)]) == 2
    err = _one_line_error(capsys)
    for w in words:
        assert w in err, err
    assert not png.exists()


def test_plot_takes_a_start_on_the_domain_edge_and_refuses_a_time_past_the_horizon(tiny_table, tmp_path, capsys):
    png = tmp_path / "fig.png"
    assert main(["plot", str(tiny_table), "--from=-20,20:0.3", "--out", str(png)]) == 0  # the corner is inside
    assert png.exists()
    assert main(["plot", str(tiny_table), "--t", "1.5", "--out", str(tmp_path / "late.png")]) == 2
    assert "--t 1.5 must lie in [0, T] = [0, 1] s" in _one_line_error(capsys)


CART = '''
from cart_motion import CartMotion

from softreach.reach import Model
from softreach.reach.dynamics import ControlAndDisturbanceAffine


class Cart(CartMotion, Model, ControlAndDisturbanceAffine):
    control_units = ("m/s^2",)
    disturbance_units = ("m/s^2",)
    default_shape = (11, 11)
    default_budget_points = 9
    default_budgets = (0.0, 0.5)
    budget_scale = 2.0
    control_period = 0.05
    start_box = ((-1.5, -0.5), (1.5, 0.5))
    start_budget = (0.0, 1.0)

    def __init__(self, accel_max: float = 2.0):
        self.accel_max = accel_max
        self.control_bounds = ((-accel_max,), (accel_max,))
        self.disturbance_bounds = ((-0.5,), (0.5,))

    def parameters(self):
        return {"accel_max": self.accel_max}
'''


def test_a_model_in_the_current_directory_without_pythonpath(tmp_path, monkeypatch, capsys):
    """The console script does not put the current directory on sys.path (``python -m`` does): a class path
    must still be found there, by `solve` and by every later command that reads the table."""
    folder = tmp_path / "mine"
    folder.mkdir()
    (folder / "cart_first_contact.py").write_text(textwrap.dedent(CART))
    monkeypatch.setattr(sys, "path", [p for p in sys.path if p not in ("", ".", str(folder))])
    monkeypatch.delitem(sys.modules, "cart_first_contact", raising=False)
    monkeypatch.chdir(folder)
    args = ["--snapshots", "3", "--accuracy", "low", "--compile", "no", "--quiet"]
    assert main(["solve", "cart_first_contact:Cart", *args]) == 0
    assert (folder / "Cart.srt").is_file()
    # a later process: the module is imported afresh, the table names it "cart_first_contact:Cart"
    sys.modules.pop("cart_first_contact", None)
    sys.path[:] = [p for p in sys.path if p != str(folder)]
    assert main(["plot", "Cart.srt", "--out", "fig.png"]) == 0 and (folder / "fig.png").is_file()
    capsys.readouterr()
    # elsewhere the module cannot be found, and the error says where it was looked for
    sys.modules.pop("cart_first_contact", None)
    sys.path[:] = [p for p in sys.path if p != str(folder)]
    monkeypatch.chdir(tmp_path)
    with pytest.raises(SystemExit) as stop:  # argparse refuses the model argument
        main(["solve", "cart_first_contact:Cart", *args])
    assert stop.value.code == 2
    err = capsys.readouterr().err
    assert "cannot import module 'cart_first_contact'" in err and "current directory" in err


# ------------------------------------------------------------------------------------------------ train

from stable_baselines3.common.callbacks import CallbackList  # noqa: E402


def _interrupt_at(monkeypatch, calls: int) -> None:
    """Ctrl-C from inside learning, as a terminal delivers it: a KeyboardInterrupt at the ``calls``-th step."""
    from stable_baselines3.common.callbacks import BaseCallback

    import softreach.agents.callbacks as callbacks

    class CtrlC(BaseCallback):
        def _on_step(self) -> bool:
            if self.n_calls == calls:
                raise KeyboardInterrupt
            return True

    monkeypatch.setattr(callbacks, "progress_callback", lambda desc: CtrlC())


def test_ctrl_c_saves_the_policy_and_resume_continues_it(tmp_path, monkeypatch, capsys):
    from softreach.agents import config
    from softreach.agents.train import load_policy

    out = tmp_path / "run"
    # rollouts of 16 steps x 2 envs = 32; Ctrl-C at the 120th vector step (240 steps: every env has finished an
    # episode of at most 100 steps) is inside the eighth rollout
    monkeypatch.setitem(config._DEFAULTS, ("pointmass", "ppo"),
                        config.Defaults(config.RunConfig(), config.PPOConfig(n_steps=16, batch_size=32)))
    cmd = ["train", "pointmass", "--timesteps", "320", "--n-envs", "2", "--eval-freq", "0", "--out", str(out)]
    _interrupt_at(monkeypatch, 120)
    assert main(cmd) == 130
    err = capsys.readouterr().err
    assert "Traceback" not in err
    assert f"--resume {out / 'model.zip'}" in err and "interrupted after 240 of 320 steps" in err
    cfg = json.loads((out / "config.json").read_text())
    assert cfg["status"] == "interrupted" and cfg["timesteps"] == 240
    saved = load_policy(out / "model.zip")
    assert saved.num_timesteps == 240 and saved.softreach_model == "pointmass"
    weights = {k: v.clone() for k, v in saved.policy.state_dict().items()}
    monitor = out / "monitor" / "train-0.monitor.csv"
    before = monitor.read_text()
    assert len(before.splitlines()) >= 3  # its JSON line, the column names, at least one episode

    # resume: it continues from step 240 (not from 0) up to 320 in whole rollouts: 240 + 3 x 32 = 336
    monkeypatch.setattr("softreach.agents.callbacks.progress_callback", lambda desc: CallbackList([]))
    assert main(cmd + ["--resume", str(out / "model.zip")]) == 0
    text = capsys.readouterr().out
    assert "trained 96 steps" in text and "resumed from" in text and "336 in all" in text
    cfg = json.loads((out / "config.json").read_text())
    assert cfg["status"] == "done" and cfg["timesteps"] == 336 and cfg["timesteps_at_start"] == 240
    final = load_policy(out / "model.zip")
    assert final.num_timesteps == 336
    assert any((final.policy.state_dict()[k] != w).any() for k, w in weights.items())  # it learned further
    assert monitor.read_text().startswith(before)  # the first part's episodes are kept, not overwritten


def test_resume_refuses_another_models_run(tmp_path, capsys):
    run = tmp_path / "run"
    run.mkdir()
    (run / "model.zip").write_bytes(b"")
    (run / "config.json").write_text(json.dumps({"schema": "softreach.train/1", "model": "glider", "algo": "ppo"}))
    assert main(["train", "pointmass", "--resume", str(run / "model.zip"), "--out", str(tmp_path / "x")]) == 2
    assert "that run trained glider with ppo, this one pointmass with ppo" in _one_line_error(capsys)


def test_train_refuses_a_filter_without_cells_and_warns_of_rounded_steps(tiny_table, monkeypatch):
    from softreach.agents.commands import train_notes
    from softreach.agents.train import TrainSpec

    # the point mass has cells, which certify whatever table ranks the candidates: nothing to say of the table
    notes = train_notes(TrainSpec(filter=str(tiny_table), timesteps=256, n_envs=8))
    assert len(notes) == 1
    assert "n_steps x n_envs = 256 x 8 = 2,048 steps, so --timesteps 256 trains 2,048 steps" in notes[0]
    assert train_notes(TrainSpec(timesteps=4096, n_envs=8)) == []
    # a model without cells has no certificate: refused before any training, naming what to add
    without_cells(monkeypatch)
    with pytest.raises(ValueError, match=r"--filter .*cell_shape = \(cells per state axis"):
        train_notes(TrainSpec(filter=str(tiny_table), timesteps=4096, n_envs=8))


@pytest.mark.parametrize("algo,asked,n_envs", [("ppo", 20, 2), ("sac", 5, 2)])
def test_the_announced_step_count_is_what_sb3_trains(tmp_path, algo, asked, n_envs):
    """``planned_steps`` against SB3 itself: a short run learns exactly the count the note announces."""
    from softreach.agents.config import defaults, planned_steps, with_overrides
    from softreach.agents.train import TrainSpec, train

    over = {"n_steps": 8, "batch_size": 16} if algo == "ppo" else {"learning_starts": 0, "buffer_size": 1000}
    res = train(TrainSpec(algo=algo, timesteps=asked, n_envs=n_envs, out=str(tmp_path / algo), progress=False,
                          run_overrides={"eval_freq": 0, "checkpoint_freq": 0}, algo_overrides=over))
    expected = planned_steps(asked, with_overrides(defaults("pointmass", algo).algo, **over), n_envs)
    assert res.timesteps == expected and expected > asked


# ------------------------------------------------------------------------------------------------ evaluate, demo

def test_evaluate_says_a_policy_file_is_missing_before_anything_else(tmp_path, capsys):
    missing = tmp_path / "nonexistent.zip"
    assert main(["evaluate", "pointmass", "--policy", str(missing), "--episodes", "2"]) == 2
    err = _one_line_error(capsys)
    assert f"policy file {missing} does not exist" in err and "table" not in err


def test_evaluate_names_the_model_a_policy_was_trained_for(tmp_path, capsys):
    import gymnasium as gym
    from stable_baselines3 import PPO

    import softreach.envs  # noqa: F401

    policy = PPO("MlpPolicy", gym.make("softreach/PointMassLanding-v0"), n_steps=8, batch_size=8, device="cpu")
    policy.softreach_model = "pointmass"  # what softreach train records in every policy it saves
    policy.save(tmp_path / "pm.zip")
    assert main(["evaluate", "glider", "--policy", str(tmp_path / "pm.zip"), "--wind", "none", "--starts", "env",
                 "--episodes", "1", "--quiet"]) == 2
    err = _one_line_error(capsys)
    assert "was trained for pointmass, not glider: observations Box(4,) where glider's environment has Box(5,)" in err


def test_demo_seed_is_the_evaluation_seed_unless_eval_seed_is_given(monkeypatch, tmp_path, capsys):
    import softreach.agents.demo as demo

    seen = {}

    def fake_demo(**kwargs):
        seen.update(kwargs)
        report = tmp_path / "report.md"
        report.write_text("# report\n\n## Plots\n")
        return {"report": report}

    monkeypatch.setattr(demo, "run_demo", fake_demo)
    assert main(["demo", "--seed", "7", "--out", str(tmp_path)]) == 0
    assert seen["seed"] == 7 and seen["eval_seed"] == 7
    assert "training seed 7; evaluation seed 7" in capsys.readouterr().out
    assert main(["demo", "--seed", "7", "--eval-seed", "0", "--out", str(tmp_path)]) == 0
    assert seen["seed"] == 7 and seen["eval_seed"] == 0
    assert "evaluation seed 0" in capsys.readouterr().out


# ------------------------------------------------------------------------------------------------ first compile

def test_a_first_torch_compile_announces_itself_once(tmp_path, monkeypatch, capsys):
    import torch

    from softreach.reach.numerics import compute

    monkeypatch.setattr(compute._CompileNotice, "said", False)
    empty = tmp_path / "inductor"
    notice = compute.compile_notice()
    monkeypatch.setattr(notice, "cache_dir", lambda: str(empty))
    torch._dynamo.reset()
    with notice:
        f = torch.compile(lambda x: x * 2 + 1, backend="eager")  # dynamo's start, without the C++ build
        f(torch.ones(3))
        g = torch.compile(lambda x: x - 1, backend="eager")
        g(torch.ones(3))
    err = capsys.readouterr().err
    assert err.count("softreach: compiling the solver with torch.compile, once per machine") == 1
    assert f"about {compute.COLD_COMPILE_S:.0f} s" in err and str(empty) in err
    # outside a solve nothing is said
    torch._dynamo.reset()
    monkeypatch.setattr(compute._CompileNotice, "said", False)
    h = torch.compile(lambda x: x + 3, backend="eager")
    h(torch.ones(3))
    assert "torch.compile" not in capsys.readouterr().err


def test_a_first_filtered_decision_announces_its_compile(monkeypatch, capsys, tiny_table):
    from types import SimpleNamespace

    from softreach.agents import envs
    from softreach.filters import SafetyFilter

    assert envs.filter_code_cached() in (True, False)  # numba's cache is readable here
    monkeypatch.setattr(envs, "_announced", False)
    monkeypatch.setattr(envs, "filter_code_cached", lambda: False)
    def with_compiled_filter(env, table, rule, margin):
        """The filter make_env wraps, as one with a compiled decision looks to the announcement (a real one
        compiles at its first decision, minutes on a cold cache)."""
        stub = SafetyFilter.__new__(SafetyFilter)
        stub.env, stub.value_filter = env, SimpleNamespace(compiled=object())
        return stub

    monkeypatch.setattr(envs, "safety_filter", with_compiled_filter)
    monkeypatch.setattr(envs, "filter_code_cached", lambda: True)
    envs.make_env("pointmass", filter_table=str(tiny_table))
    assert "numba" not in capsys.readouterr().err  # cached: nothing to say
    monkeypatch.setattr(envs, "filter_code_cached", lambda: False)
    for _ in range(2):
        envs.make_env("pointmass", filter_table=str(tiny_table))
    err = capsys.readouterr().err
    assert err.count("the safety filter's first decision compiles it with numba") == 1  # once per process
    assert f"about {envs.FILTER_COMPILE_S:.0f} s" in err and "softreach compile TABLE" in err
