"""Snapshots written on a thread while the solver steps on (reach/tables/table.py, ``BackgroundWrites``): a Ctrl-C
in the solver's thread loses no snapshot already handed to the writer, and a write that fails stops the solve with
its own error."""

from __future__ import annotations

import time

import pytest

from softreach.reach import SolveConfig, SolverSettings, get_model, load_table, solve_table
from softreach.reach.numerics import compute
from softreach.reach.tables import table as table_mod

MODEL = get_model("pointmass")
CFG = SolveConfig(shape=(21, 21), budget_points=23, snapshots=5,
                  settings=SolverSettings.from_accuracy("low", dtype="float32", compile=False))


def test_ctrl_c_in_the_solver_keeps_the_snapshot_being_written(tmp_path, monkeypatch):
    """The third snapshot of ``V`` is still being written (a slow disk) when the solver's thread is interrupted:
    the partial file marks all three done, and the resumed solve gives the table of an unbroken one."""
    write, solve = table_mod.TableWriter.write_snapshot, compute.solve

    def slow_write(self, field, k, value):
        time.sleep(0.3)
        return write(self, field, k, value)

    def interrupted(*args, sink, **kw):
        handed = []

        def counting(k, t, u):
            sink(k, t, u)
            handed.append(k)
            if len(handed) == 3:
                raise KeyboardInterrupt

        return solve(*args, sink=counting, **kw)

    monkeypatch.setattr(table_mod.TableWriter, "write_snapshot", slow_write)
    monkeypatch.setattr(compute, "solve", interrupted)
    out = tmp_path / "t.srt"
    with pytest.raises(KeyboardInterrupt):
        solve_table(MODEL, CFG, out, progress=False)
    header = table_mod.read_header(out.with_name(out.name + ".partial"), allow_incomplete=True)
    assert sum(header["fields"]["V"]["done"]) == 3 and not any(header["fields"]["W_eps"]["done"])

    monkeypatch.setattr(compute, "solve", solve)
    monkeypatch.setattr(table_mod.TableWriter, "write_snapshot", write)
    summary = solve_table(MODEL, CFG, out, progress=False)
    assert summary["resumed"]
    solve_table(MODEL, CFG, tmp_path / "ref.srt", progress=False)
    resumed, ref = load_table(out), load_table(tmp_path / "ref.srt")
    for f in ("V", "W_eps"):
        assert (resumed.values(f) == ref.values(f)).all()


def test_a_failed_write_stops_the_solve_with_its_error(tmp_path, monkeypatch):
    write = table_mod.TableWriter.write_snapshot
    calls = []

    def full_disk(self, field, k, value):
        calls.append(k)
        if len(calls) == 2:
            raise OSError(28, "No space left on device")
        return write(self, field, k, value)

    monkeypatch.setattr(table_mod.TableWriter, "write_snapshot", full_disk)
    with pytest.raises(OSError, match="No space left"):
        solve_table(MODEL, CFG, tmp_path / "t.srt", progress=False)
    # the solve stopped at the next snapshot: no third write was started
    assert len(calls) <= 3
