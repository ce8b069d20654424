"""The size of the filter's code as issue 37 counts it: the filter (every module of ``filters/``) and everything only
it uses (a module of the package whose importers are all filter code, found transitively; a package's ``__init__``
that re-exports a name is no user of it, tests and benchmarks are none either).

    python benchmarks/filter_lines.py [--modules]

prints the total lines (``wc -l``), with ``--modules`` each module's, and the modules the filter imports that others
use too (which the total leaves out), with those other users."""

from __future__ import annotations

import argparse
import ast
from pathlib import Path

ROOT = Path(__file__).resolve().parent.parent
PACKAGES = ("reach", "envs", "filters", "agents")


def modules() -> dict[str, Path]:
    """Every module of the package, by its installed name (``softreach.reach.jit``), and its file."""
    out = {}
    for package in PACKAGES:
        for path in sorted((ROOT / package).rglob("*.py")):
            parts = path.relative_to(ROOT).with_suffix("").parts
            out[".".join(("softreach",) + (parts[:-1] if parts[-1] == "__init__" else parts))] = path
    return out


def importers(mods: dict[str, Path]) -> dict[str, set[str]]:
    """Per module, the modules that import it or a name from it (relative imports resolved); ``__init__`` files
    left out."""
    out: dict[str, set[str]] = {name: set() for name in mods}
    for name, path in mods.items():
        if path.name == "__init__.py":
            continue
        package = name.rsplit(".", 1)[0]
        for node in ast.walk(ast.parse(path.read_text())):
            if isinstance(node, ast.Import):
                targets = [a.name for a in node.names]
            elif isinstance(node, ast.ImportFrom):
                base = node.module or ""
                if node.level:
                    up = package.split(".")[:len(package.split(".")) - node.level + 1]
                    base = ".".join(up + ([node.module] if node.module else []))
                targets = [base] + [f"{base}.{a.name}" for a in node.names]
            else:
                continue
            for target in targets:
                if target in out and target != name:
                    out[target].add(name)
    return out


def filter_code(mods: dict[str, Path], users: dict[str, set[str]]) -> set[str]:
    """``filters/`` and, transitively, every module whose importers are all in the set."""
    code = {name for name in mods if name.startswith("softreach.filters")}
    grown = True
    while grown:
        grown = False
        for name in mods:
            if name not in code and mods[name].name != "__init__.py" and users[name] and users[name] <= code:
                code.add(name)
                grown = True
    return code


def lines(path: Path) -> int:
    return len(path.read_bytes().splitlines())


def main(argv: list[str] | None = None) -> int:
    parser = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    parser.add_argument("--modules", action="store_true", help="each module's lines, and the shared modules")
    args = parser.parse_args(argv)
    mods = modules()
    users = importers(mods)
    code = filter_code(mods, users)
    if args.modules:
        for name in sorted(code):
            print(f"{lines(mods[name]):6d}  {mods[name].relative_to(ROOT)}")
        shared = sorted({m for name in code for m in mods
                         if name in users[m] and m not in code and mods[m].name != "__init__.py"})
        print("imported by the filter, used by others too (not counted):")
        for name in shared:
            print(f"        {mods[name].relative_to(ROOT)}: {', '.join(sorted(users[name] - code))}")
    print(f"filter code: {sum(lines(mods[name]) for name in code)} lines in {len(code)} modules")
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
