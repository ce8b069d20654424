"""Numba keeps compiled code on disk keyed by the text of the function's own file alone (numba 0.68 hashes it), not
by what it compiles in from other files: the functions it calls or inlines and the global constants it reads. A
module whose cached functions import from another package file therefore names each such file with a digest of
its text (``COMPILED_IN``): a change there must change the importing module's text too, so that numba compiles it
afresh instead of loading code built from the old import (after an upgrade that changed only the imported file,
or during development)."""

from __future__ import annotations

import ast
import hashlib
import importlib
from pathlib import Path

import pytest

ROOT = Path(__file__).resolve().parents[1]
# the installed packages' folders (pyproject.toml, [tool.setuptools.package-dir])
FOLDERS = {"softreach.reach.models": "reach/models", "softreach.reach": "reach", "softreach.filters": "filters",
           "softreach.envs": "envs", "softreach.agents": "agents"}
CACHED = sorted(p.relative_to(ROOT).as_posix() for d in ("reach", "filters", "envs", "agents")
                for p in (ROOT / d).rglob("*.py") if "cache=True" in p.read_text())


def _module(rel: str) -> str:
    """The dotted name of the package file ``rel``."""
    folder, name = rel.rsplit("/", 1)
    package = next(k for k, v in FOLDERS.items() if v == folder)
    return package if name == "__init__.py" else f"{package}.{name[:-3]}"


def _file(module: str) -> str | None:
    """The package file of a dotted module name, or ``None`` outside the package folders."""
    for package, folder in sorted(FOLDERS.items(), key=lambda kv: -len(kv[0])):
        if module == package:
            return f"{folder}/__init__.py"
        if module.startswith(package + "."):
            rest = module[len(package) + 1:].replace(".", "/")
            for rel in (f"{folder}/{rest}.py", f"{folder}/{rest}/__init__.py"):
                if (ROOT / rel).exists():
                    return rel
    return None


def _imported(rel: str) -> set[str]:
    """The package files the module ``rel`` imports at its top level."""
    here = _module(rel)
    package = here if rel.endswith("__init__.py") else here.rsplit(".", 1)[0]
    out = set()
    for node in ast.parse((ROOT / rel).read_text()).body:
        if isinstance(node, ast.Import):
            names = [a.name for a in node.names]
        elif isinstance(node, ast.ImportFrom):
            base = node.module or ""
            if node.level:
                anchor = package.rsplit(".", node.level - 1)[0] if node.level > 1 else package
                base = f"{anchor}.{base}" if base else anchor
            # "from pkg import name" imports the module pkg.name where there is one
            names = [f"{base}.{a.name}" if _file(f"{base}.{a.name}") else base for a in node.names]
        else:
            continue
        out.update(f for f in map(_file, names) if f is not None and f != rel)
    return out


def _digest(rel: str) -> str:
    return hashlib.sha256((ROOT / rel).read_bytes()).hexdigest()[:16]


def test_the_cached_modules_are_found():
    assert {"filters/compiled.py", "filters/judge.py", "reach/kernels.py"} <= set(CACHED)


@pytest.mark.parametrize("rel", CACHED)
def test_a_cached_module_names_what_it_compiles_in(rel):
    expected = {f: _digest(f) for f in sorted(_imported(rel))}
    declared = getattr(importlib.import_module(_module(rel)), "COMPILED_IN", {})
    assert declared == expected, (f"{rel} imports package files whose change numba would not notice; set its "
                                  f"COMPILED_IN = {expected!r}")
