"""The package's compiled-code cache (:mod:`softreach.reach.jit`): every compiled function is cached through it,
its key covers every source file of the package, a change to a file that compiled code only depends on (not the
file of the function itself) compiles it afresh, and the cache lives in the user's cache folder, never in the
package."""

from __future__ import annotations

import importlib
import json
import os
import re
import subprocess
import sys
import tomllib
from pathlib import Path

import numba
import numpy as np
import pytest
from numba.core.caching import NullCache

from softreach.reach import jit

ROOT = Path(__file__).resolve().parents[1]
PYPROJECT = tomllib.loads((ROOT / "pyproject.toml").read_text())["tool"]["setuptools"]


def _package_folders() -> dict[str, Path]:
    """Each installed package's folder in this checkout (pyproject.toml's ``packages`` and ``package-dir``)."""
    dirs = PYPROJECT["package-dir"]
    out = {}
    for name in PYPROJECT["packages"]:
        parent = max((p for p in dirs if name == p or name.startswith(p + ".")), key=len)
        out[name] = ROOT / dirs[parent] / name[len(parent):].lstrip(".").replace(".", "/")
    return out


def _compiled_modules() -> list[str]:
    """The dotted names of the package files that compile code with numba."""
    out = []
    for name, folder in _package_folders().items():
        for p in sorted(folder.glob("*.py")):
            if re.search(r"^\s*@(nb\.|numba\.)?njit", p.read_text(), re.M):
                out.append(name if p.name == "__init__.py" else f"{name}.{p.stem}")
    return out


def test_every_compiled_function_is_cached_by_the_package_cache():
    modules = _compiled_modules()
    assert {"softreach.filters.compiled", "softreach.filters.judge", "softreach.reach.proof.kernels",
            "softreach.reach.models.pointmass"} <= set(modules)
    found = 0
    for name in modules:
        module = importlib.import_module(name)
        for value in vars(module).values():
            if isinstance(value, numba.core.registry.CPUDispatcher) and value.py_func.__module__ == name:
                assert isinstance(value._cache, jit.PackageCache), f"{name}.{value.__name__} is not cached by jit"
                found += 1
    assert found >= 50
    # and no module asks numba for its own cache, which would key the code on the module's file alone
    for folder in _package_folders().values():
        for p in folder.glob("*.py"):
            assert not re.search(r"^\s*@[\w.]*jit\([^)]*cache\s*=", p.read_text(), re.M), p


def test_the_key_is_a_digest_of_every_package_source():
    expected = sorted({p.resolve() for folder in _package_folders().values() for p in folder.rglob("*.py")})
    assert {ROOT / "reach/proof/kernels.py", ROOT / "filters/judge.py", ROOT / "reach/models/glider.py",
            ROOT / "src/softreach/cli.py"} <= set(expected)
    assert jit.source_files() == expected
    from softreach.reach.proof.kernels import certificate_rows
    assert certificate_rows._cache._impl.locator.get_source_stamp() == jit.source_stamp()
    jit.source_stamp.cache_clear()  # read the files again now (the stamp is computed once per process)
    assert jit.source_stamp() == jit.digest(expected)


def test_a_one_space_edit_of_any_source_changes_the_key(tmp_path):
    files = []
    for rel in ("reach/proof/kernels.py", "filters/judge.py", "reach/proof/model_kernels.py"):
        dst = tmp_path / rel.replace("/", "_")
        dst.write_bytes((ROOT / rel).read_bytes())
        files.append(dst)
    before = jit.digest(files)
    for f in files:
        text = f.read_text()
        f.write_text(text.replace('"""', '""" ', 1))
        assert jit.digest(files) != before, f
        f.write_text(text)
        assert jit.digest(files) == before
    files[0].rename(tmp_path / "renamed.py")
    assert jit.digest([tmp_path / "renamed.py", *files[1:]]) != before


# two modules outside the package: ``user.f`` compiles in ``dep.g`` and ``dep.SCALE``
DEP = """\
from softreach.reach.jit import njit
SCALE = {scale}

@njit(inline="always")
def g(x):
    return x + 1.0
"""
USER = """\
from softreach.reach.jit import njit
from dep import SCALE, g

@njit
def f(x):
    return g(x) * SCALE
"""
# one process: ``f`` keyed by a digest of the two modules' folder (as the package's sources key the package's
# functions), and a function of the user's own with numba's plain cache, which keeps numba's defaults
RUN = """\
import json, sys
from pathlib import Path
import numba
import numpy as np
folder = Path(sys.argv[1])
sys.path.insert(0, str(folder))
import softreach.reach.jit as jit
jit.source_stamp = lambda: jit.digest(sorted(folder.glob("*.py")))
import user, plain
print(json.dumps({{"f": user.f(2.0), "hits": sum(user.f.stats.cache_hits.values()),
                   "misses": sum(user.f.stats.cache_misses.values()), "path": user.f.stats.cache_path,
                   "plain": plain.p(1.0), "plain_path": plain.p.stats.cache_path,
                   "numba_dir": numba.config.CACHE_DIR}}))
"""
PLAIN = """\
import numba
import numpy as np

@numba.njit(cache=True)
def p(x):
    return x * 3.0
"""


def _run(folder: Path, env: dict[str, str]) -> dict:
    out = subprocess.run([sys.executable, "-c", RUN.format(), str(folder)], env=env, capture_output=True,
                         text=True, timeout=300)
    assert out.returncode == 0, out.stderr
    return json.loads(out.stdout.strip().splitlines()[-1])


def test_a_changed_dependency_recompiles_and_the_cache_stays_out_of_the_sources(tmp_path):
    code, cache = tmp_path / "code", tmp_path / "cache"
    code.mkdir()
    (code / "dep.py").write_text(DEP.format(scale=10.0))
    (code / "user.py").write_text(USER)
    (code / "plain.py").write_text(PLAIN)
    env = {k: v for k, v in os.environ.items() if not k.startswith("NUMBA_")}
    env["SOFTREACH_CACHE"] = str(cache)

    first = _run(code, env)
    assert (first["f"], first["misses"], first["hits"]) == (30.0, 1, 0)
    again = _run(code, env)
    assert (again["f"], again["misses"], again["hits"]) == (30.0, 0, 1)  # loaded from the disk cache
    # only the dependency changes, not the file of the compiled function: numba's own key would not see it
    (code / "dep.py").write_text(DEP.format(scale=100.0))
    changed = _run(code, env)
    assert (changed["f"], changed["misses"], changed["hits"]) == (300.0, 1, 0)

    # the compiled code lives under $SOFTREACH_CACHE/numba, nothing of it beside the sources
    assert Path(first["path"]).is_relative_to(cache / "numba")
    assert list((cache / "numba").rglob("user.f-*.nbi"))
    assert not [p for p in code.rglob("*") if p.name.startswith("user.") and p.suffix in (".nbi", ".nbc")]
    # a user's own numba code in the same process keeps numba's defaults: its cache beside its file, no
    # NUMBA_CACHE_DIR set for it
    assert first["plain"] == 3.0 and Path(first["plain_path"]) == code / "__pycache__"
    assert first["numba_dir"] == ""


def test_numba_cache_dir_takes_precedence(tmp_path, monkeypatch):
    monkeypatch.setenv("SOFTREACH_CACHE", str(tmp_path / "softreach"))
    monkeypatch.setattr(jit.config, "CACHE_DIR", "")
    assert jit.compiled_cache_dir() == tmp_path / "softreach" / "numba"
    assert jit.PackageCache(_square).cache_path.startswith(str(tmp_path / "softreach" / "numba") + os.sep)
    monkeypatch.setattr(jit.config, "CACHE_DIR", str(tmp_path / "numba_dir"))
    assert jit.compiled_cache_dir() == tmp_path / "numba_dir"
    assert jit.PackageCache(_square).cache_path.startswith(str(tmp_path / "numba_dir") + os.sep)


def _square(x):
    return x * x


def test_an_unwritable_cache_folder_compiles_without_a_cache(tmp_path, monkeypatch):
    blocker = tmp_path / "a_file"
    blocker.write_text("")
    monkeypatch.setenv("SOFTREACH_CACHE", str(blocker))  # a file, so the folder below it cannot be made
    monkeypatch.setattr(jit.config, "CACHE_DIR", "")
    monkeypatch.setattr(jit, "_UNWRITABLE", [])
    with pytest.warns(UserWarning, match=re.escape(str(blocker / "numba"))):
        square = jit.njit(_square)
    assert isinstance(square._cache, NullCache)
    assert square(3.0) == 9.0


def test_cache_is_not_an_option():
    with pytest.raises(TypeError, match="cache=False"):
        jit.njit(cache=False)


def test_entry_point_runs_the_code_compiled_for_these_arguments_and_else_the_dispatcher():
    f = numba.njit(lambda a, pair: a[0] + pair[1][0])
    args = (np.arange(3.0), (1, np.ones(2)))
    assert f(*args) == 1.0
    run = jit.entry_point(f, args)
    assert run is not f and run(*args) == 1.0
    args[0][0] = 5.0  # the same objects, rewritten in place, as CompiledDecision.one passes them
    assert run(*args) == 6.0
    # integer values: the dispatcher has no code for exactly these types (it would convert them)
    assert jit.entry_point(f, (np.arange(3), (1, np.ones(2)))) is f


_NAME_OF_A_COMPILATION = """
import os
import numba
import softreach.reach.jit

def one_more(n):
    return n + 1

def name():
    f = numba.njit(one_more)
    f(3)
    return next(iter(f.overloads.values())).fndesc.mangled_name

read, write = os.pipe()
if os.fork() == 0:
    os.write(write, name().encode())
    os._exit(0)
os.wait()
print(name(), os.read(read, 4096).decode())
"""


@pytest.mark.skipif(not hasattr(os, "fork"), reason="the check forks")
def test_processes_name_the_same_compilation_apart():
    """Two processes, and a process and its forked child, that compile the same function after the same steps
    give its code different symbol names (numba would give both the same: ids counted from 1), so that a process
    loading cached code that both compiled links each name to one code (:func:`softreach.reach.jit.
    _draw_function_ids`)."""
    def run() -> list[str]:
        out = subprocess.run([sys.executable, "-c", _NAME_OF_A_COMPILATION], capture_output=True, text=True,
                             timeout=300, env={**os.environ, "OMP_NUM_THREADS": "1"})
        assert out.returncode == 0, out.stderr
        return out.stdout.split()

    (parent, child), (other, _) = run(), run()
    for a, b in ((parent, other), (parent, child)):
        assert "one_more" in a and "one_more" in b
        assert a != b
