"""Compiling ahead of use (softreach.reach.jit.compiling_ahead, softreach.filters.background): a process that misses
a function another process is compiling ahead waits and loads that process's result instead of compiling it too;
functions the other process does not compile are not waited for; softreach solve starts the filter's compilation."""

from __future__ import annotations

import json
import os
import subprocess
import sys
import textwrap
import time

import pytest

from softreach.filters import background

MODULE = '''
from softreach.reach.jit import njit


@njit
def named(x):
    return 2.0 * x + 1.0


@njit
def other(x):
    return 3.0 * x - 1.0
'''

HOLDER = '''
import sys, time
import mod_ahead
from softreach.reach.jit import compiling_ahead

with compiling_ahead([mod_ahead.named]) as held:
    print("held" if held else "busy", flush=True)
    time.sleep(float(sys.argv[1]))  # the other process misses the cache meanwhile
    mod_ahead.named(1.0)
'''

WAITER = '''
import json, sys, time
import mod_ahead

func = getattr(mod_ahead, sys.argv[1])
t0 = time.perf_counter()
value = func(1.0)
print(json.dumps({"value": value, "seconds": time.perf_counter() - t0,
                  "hits": sum(func.stats.cache_hits.values()), "misses": sum(func.stats.cache_misses.values())}))
'''


@pytest.mark.process
@pytest.mark.parametrize("which", ["named", "other"])
def test_a_process_waits_for_the_function_being_compiled_ahead(tmp_path, which):
    (tmp_path / "mod_ahead.py").write_text(MODULE)
    (tmp_path / "holder.py").write_text(HOLDER)
    (tmp_path / "waiter.py").write_text(WAITER)
    env = {**os.environ, "NUMBA_CACHE_DIR": str(tmp_path / "cache"), "PYTHONPATH": os.pathsep.join(
        [str(tmp_path)] + [p for p in os.environ.get("PYTHONPATH", "").split(os.pathsep) if p])}
    # the other function's waiter must end while the holder still holds the lock: a long hold, cut short after it
    sleep = 4.0 if which == "named" else 90.0
    holder = subprocess.Popen([sys.executable, "holder.py", str(sleep)], cwd=tmp_path, env=env,
                              stdout=subprocess.PIPE, text=True)
    try:
        assert holder.stdout.readline().strip() == "held"
        t0 = time.monotonic()
        out = subprocess.run([sys.executable, "waiter.py", which], cwd=tmp_path, env=env, capture_output=True,
                             text=True, timeout=120, check=True)
        elapsed = time.monotonic() - t0
        still_held = holder.poll() is None
    finally:
        if which != "named":
            holder.terminate()
        holder.wait(timeout=120)
    row = json.loads(out.stdout.strip().splitlines()[-1])
    if which == "named":
        assert holder.returncode == 0
        # it waited for the holder (which sleeps before compiling), then loaded the holder's code from the cache
        assert row["value"] == 3.0 and row["hits"] == 1 and row["misses"] == 0, row
        assert "waiting for process" in out.stderr
        assert elapsed >= sleep - 1.0
    else:
        # a function the holder does not compile ahead is compiled at once, without waiting
        assert row["value"] == 2.0 and row["hits"] == 0 and row["misses"] == 1, row
        assert "waiting" not in out.stderr
        assert still_held and row["seconds"] < sleep


def test_a_second_holder_is_refused(tmp_path, monkeypatch):
    from softreach.reach import jit

    monkeypatch.setattr(jit.config, "CACHE_DIR", str(tmp_path))
    code = textwrap.dedent(f'''
        import time
        from numba.core import config
        config.CACHE_DIR = {str(tmp_path)!r}
        from softreach.reach.jit import compiling_ahead
        with compiling_ahead([]) as held:
            print(held, flush=True)
            time.sleep(30)
    ''')
    other = subprocess.Popen([sys.executable, "-c", code], stdout=subprocess.PIPE, text=True)
    try:
        assert other.stdout.readline().strip() == "True"
        with jit.compiling_ahead([]) as held:
            assert held is False
    finally:
        other.kill()
        other.wait()
    with jit.compiling_ahead([]) as held:  # released with the process that held it
        assert held is True


def test_solve_starts_the_filters_compilation_unless_switched_off(monkeypatch, tmp_path):
    from softreach.cli import main

    started = []
    monkeypatch.setattr(background, "start", lambda: started.append(True) or None)
    args = ["solve", "pointmass", "--grid", "9", "9", "--budget-points", "8", "--snapshots", "2", "--accuracy",
            "low", "--compile", "no", "--out", str(tmp_path / "t.srt")]
    assert main(args) == 0
    assert started == [True]
    assert main(args[:-2] + ["--classical", "--out", str(tmp_path / "c.srt")]) == 0
    assert started == [True]  # a classical table has no filter


def test_the_switch_and_a_filled_cache_start_nothing(monkeypatch):
    monkeypatch.setenv(background.ENV_SWITCH, "0")
    monkeypatch.setattr(background, "filter_code_cached", lambda: False)
    assert background.start() is None
    monkeypatch.setenv(background.ENV_SWITCH, "1")
    monkeypatch.setattr(background, "filter_code_cached", lambda: True)
    assert background.start() is None
