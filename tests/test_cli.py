"""The command line: solve with a JSON summary, plot, and clear errors before any work on bad input."""

from __future__ import annotations

import json
import subprocess
import sys

import pytest

from softreach.cli import main


def test_solve_writes_table_and_summary(tmp_path, capsys):
    out, js = tmp_path / "pm.srt", tmp_path / "pm.json"
    rc = main(["solve", "pointmass", "--grid", "31", "31", "--budget-points", "23", "--accuracy", "medium",
               "--snapshots", "5", "--compile", "no", "--out", str(out), "--json", str(js), "--quiet"])
    assert rc == 0 and out.exists()
    s = json.loads(js.read_text())
    assert s["budgets"] == [0.0, 0.06, 0.3, 0.6]
    assert len(s["soft_measure"]) == 4 and s["soft_measure"] == sorted(s["soft_measure"])
    assert s["classical_measure"] > 50
    assert set(s["q0_vs_classical"]) >= {"symmetric_difference", "relative", "raw_slice_measure"}
    assert s["grid"]["shape"] == [31, 31] and s["budget_grid"]["shape"] == [31, 31, 23]
    assert s["wall_time_s"]["W_eps"] > 0 and s["eps"] == 1e-3
    assert "Q=0 vs classical" in capsys.readouterr().out
    png = tmp_path / "fig.png"
    assert main(["plot", str(out), "--out", str(png), "--from", "0,4:0.3", "--from=-12,12:0.6"]) == 0
    assert png.read_bytes()[:8] == b"\x89PNG\r\n\x1a\n"


def test_solve_held_writes_the_sampled_data_game(tmp_path, capsys):
    out, js = tmp_path / "held.srt", tmp_path / "held.json"
    rc = main(["solve", "pointmass", "--held", "--grid", "21", "21", "--budget-points", "23", "--accuracy", "low",
               "--compile", "no", "--out", str(out), "--json", str(js), "--quiet"])
    assert rc == 0
    s = json.loads(js.read_text())
    assert s["control_period"] == 0.01 and "W_eps" in s["wall_time_s"] and "consistency" not in s["wall_time_s"]
    from softreach.reach import load_table

    table = load_table(out)
    assert table.control_period == 0.01 and len(table.times()) == 101  # every sample time of the 1 s horizon
    assert table.header["fields"]["W_eps"]["held_controls"] == [[-60.0], [-30.0], [0.0], [30.0], [60.0], [9.8]]
    assert "actions held for 0.01 s" in capsys.readouterr().out
    assert main(["solve", "pointmass", "--control-period", "0.03", "--quiet", "--out", str(tmp_path / "x.srt")]) == 2
    assert "must divide the horizon" in capsys.readouterr().err


@pytest.mark.parametrize("args,message", [
    (["--grid", "0", "31"], "grid size for v must be an integer >= 5, got 0"),
    (["--grid", "31"], "--grid needs 2 sizes"),
    (["--eps", "-1"], "eps must be a finite number > 0, got -1.0"),
    (["--eps", "nan"], "eps must be a finite number > 0, got nan"),
    (["--budget-scale", "0"], "budget scale must be a finite number > 0"),
    (["--out", "/nonexistent-dir/x.srt"], "output directory /nonexistent-dir does not exist"),
    (["--threads", "0"], "--threads must be >= 1, got 0"),
    (["--snapshots", "0"], "snapshots must be an integer >= 2, got 0"),
    (["--json", "/nonexistent-dir/s.json"], "--json directory /nonexistent-dir does not exist"),
])
def test_bad_input_is_a_clear_error(args, message, capsys, tmp_path):
    base = ["solve", "pointmass", "--quiet", "--compile", "no"]
    if "--out" not in args:
        base += ["--out", str(tmp_path / "x.srt")]
    assert main(base + args) == 2
    assert message in capsys.readouterr().err
    assert not (tmp_path / "x.srt.partial").exists()  # refused before any work


def test_plot_refuses_a_corrupted_table(tmp_path, capsys):
    bad = tmp_path / "bad.srt"
    bad.write_bytes(b"not a table")
    assert main(["plot", str(bad)]) == 2
    assert "bad magic" in capsys.readouterr().err


def test_console_script_is_installed():
    r = subprocess.run([sys.executable, "-m", "softreach.cli", "--help"], capture_output=True, text=True)
    assert r.returncode == 0 and "solve" in r.stdout and "plot" in r.stdout and "study" in r.stdout


def test_ctrl_c_keeps_the_work_and_the_rerun_resumes_with_the_whole_wall_time(tmp_path, capsys, monkeypatch):
    from softreach.reach.tables import table as table_mod

    out, js = tmp_path / "pm.srt", tmp_path / "pm.json"
    args = ["solve", "pointmass", "--grid", "21", "21", "--budget-points", "15", "--accuracy", "low",
            "--snapshots", "6", "--compile", "no", "--out", str(out), "--json", str(js), "--quiet"]
    original = table_mod.TableWriter.write_snapshot
    calls = []

    def interrupted(self, field, k, value):
        if field == "W_eps" and len([c for c in calls if c == "W_eps"]) == 3:
            raise KeyboardInterrupt
        calls.append(field)
        return original(self, field, k, value)

    monkeypatch.setattr(table_mod.TableWriter, "write_snapshot", interrupted)
    assert main(args) == 130
    err = capsys.readouterr().err
    assert "pm.srt.partial" in err and "run the same command again to resume" in err and "Traceback" not in err
    partial = table_mod.read_header(tmp_path / "pm.srt.partial", allow_incomplete=True)
    spent = partial["fields"]["W_eps"]["wall_s"]
    assert spent > 0 and sum(partial["fields"]["W_eps"]["done"]) == 3
    monkeypatch.setattr(table_mod.TableWriter, "write_snapshot", original)
    assert main(args) == 0
    s = json.loads(js.read_text())
    assert s["wall_time_s"]["W_eps"] >= spent  # the interrupted part counts
    assert s["wall_time_s"]["V"] == pytest.approx(partial["fields"]["V"]["wall_s"])  # V was finished before


def test_default_threads_follow_the_idle_cores(monkeypatch):
    import os

    from softreach.reach.cli.commands import idle_cores

    monkeypatch.delenv("OMP_NUM_THREADS", raising=False)
    monkeypatch.setattr(os, "cpu_count", lambda: 2)
    monkeypatch.setattr(os, "getloadavg", lambda: (1.1, 1.0, 1.0))
    assert idle_cores() == 1  # one core busy elsewhere: one thread
    monkeypatch.setattr(os, "getloadavg", lambda: (0.1, 0.1, 0.1))
    assert idle_cores() == 2
    monkeypatch.setattr(os, "getloadavg", lambda: (7.0, 7.0, 7.0))
    assert idle_cores() == 1  # never fewer than one
    monkeypatch.setenv("OMP_NUM_THREADS", "2")
    assert idle_cores() is None  # the user's setting wins
