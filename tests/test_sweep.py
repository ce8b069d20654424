"""softreach sweep: a tiny grid in local processes and on a local Ray instance; failures, kills and resume."""

from __future__ import annotations

import contextlib
import json
import os
import signal
import threading
import time
from collections.abc import Iterator
from pathlib import Path

import pytest

os.environ.setdefault("OMP_NUM_THREADS", "1")
import stable_baselines3  # noqa: F401

from softreach.agents.sweep import SweepSpec, load_sweep_file  # noqa: E402
from softreach.agents.sweep_cli import run_sweep  # noqa: E402
from softreach.agents.sweep_exec import connect_ray  # noqa: E402
from softreach.agents.sweep_report import COLUMNS, read_table  # noqa: E402

#: one PPO update of 2 x 64 steps, one periodic evaluation (so best_model.zip exists)
TINY = {"run": {"eval_freq": 128, "eval_episodes": 1, "checkpoint_freq": 0}, "ppo": {"n_steps": 64, "batch_size": 64,
                                                                                   "n_epochs": 1}}
#: SB3's PPO refuses batch_size 1 when it is built: a run that fails inside the worker, past the sweep's checks
BROKEN = {"ppo": {"batch_size": 1}}


def tiny_spec(table: str, **kw) -> SweepSpec:
    base = dict(models=("pointmass",), algos=("ppo",), rules=("switch",), budgets=((0.0, 0.6),), winds=("random",),
                seeds=(0,), variants={"tiny": {}, "broken": BROKEN}, tables={"pointmass": str(table)},
                timesteps=128, n_envs=2, overrides=TINY, eval_winds=("adversarial",), eval_budgets=(0.3,),
                eval_filters=("on", "off"), episodes=2)
    return SweepSpec(**{**base, **kw})


def check_table(res, spec: SweepSpec, out: Path) -> dict[tuple[str, str], dict[str, str]]:
    """The CSV on disk has one row per run and evaluation, with each run's config; returns rows by (variant,
    eval_filter)."""
    rows = read_table(out / "results.csv")
    assert list(rows[0]) == list(COLUMNS)
    runs = spec.runs()
    assert len(rows) == len(runs) * 2 == len(res["rows"])
    assert sorted((r["run_id"], r["eval_filter"]) for r in rows) == sorted((run.run_id, f) for run in runs
                                                                          for f in ("on", "off"))
    for r in rows:
        run = next(x for x in runs if x.run_id == r["run_id"])
        assert (r["model"], r["algo"], r["rule"], r["budget"], r["wind"], r["variant"], r["seed"]) == \
            (run.model, run.algo, run.rule, "0:0.6", run.wind, run.variant, str(run.seed))
        assert (r["eval_wind"], r["eval_budget"], r["episodes"]) == ("adversarial", "0.3", "2")
    return {(r["variant"], r["eval_filter"]): r for r in rows}


def check_done_row(r: dict[str, str], filtered: bool) -> None:
    assert r["status"] == "done" and r["error"] == ""
    assert r["checkpoint"] == "best_model.zip"  # the periodic evaluation left one
    v, lo, hi = (float(r[f"landing_rate_{k}"]) for k in ("value", "low", "high"))
    assert 0 <= lo <= v <= hi <= 1 and r["landing_rate_n"] == "2"
    assert int(r["outcomes_landed"]) + int(r["outcomes_hard_violation"]) + int(r["outcomes_timeout"]) == 2
    assert float(r["return_low"]) <= float(r["return_mean"]) <= float(r["return_high"])
    if filtered:  # the filter keeps every start inside RA~_Q in C1; without it nothing is promised
        assert r["hard_violation_rate_count"] == "0" and r["intervention_rate_mean"] != ""
    else:
        assert r["intervention_rate_mean"] == ""


@pytest.fixture(scope="module")
def local_sweep(tmp_path_factory, pointmass_table_path):
    """The tiny sweep in one local process: ``(spec, out, result, rows as first written, log lines)``."""
    spec = tiny_spec(pointmass_table_path)
    out = tmp_path_factory.mktemp("sweep") / "sweep"
    lines: list[str] = []
    res = run_sweep(spec, out, workers=1, log=lines.append)
    return spec, out, res, check_table(res, spec, out), lines


@pytest.mark.process
def test_local_sweep_table_failure_and_resume(local_sweep, pointmass_table_path):
    spec, out, res, rows, lines = local_sweep
    assert (res["runs"], res["skipped"], res["ran"]) == (2, 0, 2)
    check_done_row(rows[("tiny", "on")], filtered=True)
    check_done_row(rows[("tiny", "off")], filtered=False)
    for f in ("on", "off"):  # the failed run is in the table with its error, not dropped
        bad = rows[("broken", f)]
        assert bad["status"] == "failed" and "batch_size" in bad["error"] and bad["error"].startswith("train:")
        assert bad["landing_rate_value"] == ""
    assert res["status"] == {"done": 2, "failed": 2, "killed": 0, "missing": 0}
    report = (out / "report.md").read_text()
    assert "## Runs that did not finish" in report and "batch_size" in report
    assert "Evaluated checkpoint: `best_model.zip` in 2 rows" in report
    assert (out / "plots" / "landing_rate.png").stat().st_size > 1000
    assert json.loads((out / "sweep.json").read_text())["schema"] == "softreach.sweep/1"

    # rerun: the finished run is skipped (no retraining: its model and result are untouched), the failed one retried
    good = next(r for r in spec.runs() if r.variant == "tiny")
    model = out / "runs" / good.run_id / "train" / "model.zip"
    stamp = (model.stat().st_mtime_ns, (out / "runs" / good.run_id / "result.json").read_text())
    res2 = run_sweep(spec, out, workers=1, log=lines.append)
    assert (res2["skipped"], res2["ran"]) == (1, 1)
    assert (model.stat().st_mtime_ns, (out / "runs" / good.run_id / "result.json").read_text()) == stamp
    assert check_table(res2, spec, out)[("tiny", "on")] == rows[("tiny", "on")]
    assert any("1 already done, 1 to run" in line for line in lines)

    # a new evaluation budget evaluates the trained policy again without retraining it
    spec3 = tiny_spec(pointmass_table_path, variants={"tiny": {}}, eval_budgets=(0.3, 0.6))
    res3 = run_sweep(spec3, out, workers=1, log=lines.append)
    assert res3["status"]["done"] == 4 and model.stat().st_mtime_ns == stamp[0]


@contextlib.contextmanager
def killing_when_started(marker: Path) -> Iterator[list[int]]:
    """While the block runs, SIGKILL the process that writes ``marker`` (a run's running.json) as soon as it appears,
    from a thread that watches until the block ends (however long the run takes to start on a loaded machine); the
    yielded list receives its pid."""
    killed: list[int] = []
    done = threading.Event()

    def watch():
        while not done.is_set() and not killed:
            try:
                pid = json.loads(marker.read_text())["pid"]
            except (OSError, ValueError):
                time.sleep(0.02)
                continue
            os.kill(pid, signal.SIGKILL)
            killed.append(pid)

    threading.Thread(target=watch, daemon=True).start()
    try:
        yield killed
    finally:
        done.set()


def check_killed(res, spec: SweepSpec, out: Path, killed: list[int], message: str) -> None:
    """The killed run (the first) is reported killed with ``message``; the next run still ran (and failed)."""
    assert killed, "the first run never started"
    by = {(r["variant"], r["eval_filter"]): r for r in res["rows"]}
    for f in ("on", "off"):
        assert by[("tiny", f)]["status"] == "killed" and message in by[("tiny", f)]["error"]
        assert by[("broken", f)]["status"] == "failed" and "batch_size" in by[("broken", f)]["error"]
    assert json.loads((out / "runs" / spec.runs()[0].run_id / "result.json").read_text())["status"] == "killed"


@pytest.mark.process
def test_killed_worker_is_reported(tmp_path, pointmass_table_path):
    """A local worker killed mid-run: that run is reported killed, the others run in a fresh pool."""
    spec = tiny_spec(pointmass_table_path)
    out = tmp_path / "sweep"
    with killing_when_started(out / "runs" / spec.runs()[0].run_id / "running.json") as killed:
        res = run_sweep(spec, out, workers=1, log=lambda _: None)
    check_killed(res, spec, out, killed, "worker process died")


@pytest.fixture(scope="module")
def local_ray():
    """A local Ray instance with one CPU for this module's Ray tests, started as ``softreach sweep --ray local``
    starts one; the sweeps below join it (``--ray auto``)."""
    ray, started = connect_ray("local", 1)
    assert started
    yield ray
    ray.shutdown()


@pytest.mark.process
def test_killed_ray_worker_is_reported(tmp_path, pointmass_table_path, local_ray):
    spec = tiny_spec(pointmass_table_path)
    out = tmp_path / "sweep"
    with killing_when_started(out / "runs" / spec.runs()[0].run_id / "running.json") as killed:
        res = run_sweep(spec, out, ray="auto", log=lambda _: None)
    check_killed(res, spec, out, killed, "WorkerCrashedError")


@pytest.mark.process
def test_sweep_on_local_ray(tmp_path, pointmass_table_path, local_sweep, local_ray):
    """The same sweep as Ray tasks: the same table, the same numbers (training and evaluation are seeded), the
    workers at the driver's priority."""
    spec = tiny_spec(pointmass_table_path)
    out = tmp_path / "sweep_ray"
    res = run_sweep(spec, out, ray="auto", log=lambda _: None)
    rows = check_table(res, spec, out)
    check_done_row(rows[("tiny", "on")], filtered=True)
    assert rows[("broken", "on")]["status"] == "failed" and "batch_size" in rows[("broken", "on")]["error"]
    local = local_sweep[3]
    for key in rows:  # every column but the timings and the run folder agrees with the local run
        differ = {c for c in COLUMNS if rows[key][c] != local[key][c]}
        assert differ <= {"train_wall_s", "eval_wall_s"}, differ
    result = json.loads((out / "runs" / spec.runs()[0].run_id / "result.json").read_text())
    assert result["status"] == "done" and result["pid"] != os.getpid()  # ran in a Ray worker process
    # at the driver's priority: Ray's own default, niceness 15, starves the runs on a shared machine
    assert local_ray.get(local_ray.remote(lambda: os.nice(0)).remote()) == os.nice(0)


def test_bad_input_names_the_value(tmp_path, pointmass_table_path):
    with pytest.raises(ValueError, match="'plane'"):
        tiny_spec(pointmass_table_path, models=("plane",)).check()
    with pytest.raises(ValueError, match="needs a table for pointmass"):
        tiny_spec(pointmass_table_path, tables={}).check()
    with pytest.raises(ValueError, match="n_stepz"):
        tiny_spec(pointmass_table_path, variants={"typo": {"ppo": {"n_stepz": 3}}}).check()
    with pytest.raises(ValueError, match="1.5"):
        tiny_spec(pointmass_table_path, budgets=(1.5,)).check()
    with pytest.raises(ValueError, match="workers"):
        run_sweep(tiny_spec(pointmass_table_path), tmp_path / "w", workers=0)
    bad = tmp_path / "bad.json"
    bad.write_text(json.dumps({"modles": ["pointmass"]}))
    with pytest.raises(ValueError, match="modles"):
        load_sweep_file(bad)


def test_toml_file_and_cli_dry_run(tmp_path, pointmass_table_path, capsys):
    from softreach.cli import main

    f = tmp_path / "grid.toml"
    f.write_text(f'models = ["pointmass"]\nrules = ["none", "switch"]\nbudgets = ["0:0.6", 0.3]\nseeds = [0, 1]\n'
                 f'timesteps = 128\n[tables]\npointmass = "{pointmass_table_path}"\n[overrides.ppo]\nn_steps = 64\n')
    spec = load_sweep_file(f)
    assert spec.budgets == ((0.0, 0.6), 0.3) and len(spec.runs()) == 8
    assert {r.table for r in spec.runs() if r.rule == "none"} == {None}  # no filter, random wind: no table
    assert main(["sweep", str(f), "--seeds", "3", "--set", "ppo.batch_size=32", "--out", str(tmp_path / "o"),
                 "--dry-run"]) == 0
    text = capsys.readouterr().out
    assert "4 runs" in text and text.count("todo") == 4 and "-s3-" in text
    assert not (tmp_path / "o").exists()
    assert main(["sweep", str(f), "--set", "ppo.n_steps", "--dry-run"]) == 2
    assert "SECTION.FIELD=VALUE" in capsys.readouterr().err


@pytest.mark.process
def test_ctrl_c_says_how_to_resume(tmp_path, pointmass_table_path):
    """SIGINT to the whole process group (what a terminal's Ctrl-C does) while a run is in flight: exit 130, the
    resume command on stderr, the workers gone, the table written with the unfinished runs as missing."""
    import subprocess
    import sys

    f = tmp_path / "tiny.json"
    # long enough that the signal finds it training (a 128-step run can finish before the signal arrives)
    f.write_text(json.dumps(tiny_spec(pointmass_table_path, variants={"tiny": {}}, timesteps=20_000).to_dict()))
    out = tmp_path / "sweep"
    # a terminal's Ctrl-C: the test may itself run as a background job, whose SIGINT is ignored and inherited
    proc = subprocess.Popen([sys.executable, "-m", "softreach.cli", "sweep", str(f), "--out", str(out)],
                            stdout=subprocess.PIPE, stderr=subprocess.PIPE, text=True, start_new_session=True,
                            env={**os.environ, "OMP_NUM_THREADS": "1"},
                            preexec_fn=lambda: signal.signal(signal.SIGINT, signal.SIG_DFL))
    # until its run starts, however loaded the machine (a process that ends first fails the next line)
    while not list(out.glob("runs/*/running.json")) and proc.poll() is None:
        time.sleep(0.05)
    worker = json.loads(next(out.glob("runs/*/running.json")).read_text())["pid"]
    os.killpg(proc.pid, signal.SIGINT)
    _, err = proc.communicate(timeout=60)
    assert proc.returncode == 130, err
    assert "interrupted after 0 of 1 runs" in err
    assert f"softreach sweep {out / 'sweep.json'} --out {out}" in err
    assert [r["status"] for r in read_table(out / "results.csv")] == ["missing", "missing"]
    time.sleep(0.5)
    status = Path(f"/proc/{worker}/status")
    if Path("/proc").is_dir():  # the worker was ended, not left training (a zombie counts as ended)
        assert not status.exists() or "\tZ" in status.read_text().split("State:")[1].splitlines()[0]


def test_docs_sweep_file_loads():
    """The sweep file shown in docs/agents.md is a valid sweep: 2 rules x 2 budgets x 2 variants x 3 seeds."""
    import re

    docs = (Path(__file__).resolve().parents[1] / "docs" / "agents.md").read_text()
    block = re.search(r"```toml\n(# grid\.toml.*?)```", docs, re.S).group(1)
    import tomllib

    spec = SweepSpec.from_dict(tomllib.loads(block))
    runs = spec.runs()
    assert len(runs) == 24 and len({r.run_id for r in runs}) == 24
    assert {r.run_overrides.get("intervention_penalty") for r in runs} == {None, 0.0}
    assert all(r.run_overrides["eval_freq"] == 10000 for r in runs)


@pytest.mark.process
def test_cli_exit_status_when_a_run_fails(tmp_path, pointmass_table_path, capsys):
    from softreach.cli import main

    f = tmp_path / "broken.json"
    f.write_text(json.dumps(tiny_spec(pointmass_table_path, variants={"broken": BROKEN}).to_dict()))
    assert main(["sweep", str(f), "--out", str(tmp_path / "o")]) == 1
    cap = capsys.readouterr()
    assert "2 failed" in cap.out and f"softreach sweep {tmp_path / 'o' / 'sweep.json'}" in cap.err
