"""The ``softreach`` command line: ``solve``, ``plot``, ``study``, ``compile`` (and ``train``, ``evaluate``,
``demo`` where installed)."""

from __future__ import annotations

import argparse
import sys


def build_parser() -> argparse.ArgumentParser:
    from softreach import __version__

    parser = argparse.ArgumentParser(prog="softreach", description="Hamilton-Jacobi reachability with soft constraints.")
    parser.add_argument("--version", action="version", version=f"softreach {__version__}",
                        help="print the installed version and exit")
    sub = parser.add_subparsers(dest="command", required=True)
    from softreach.reach.cli.commands import add_commands

    add_commands(sub)
    from softreach.filters.precompile import add_commands as add_filter_commands

    add_filter_commands(sub)
    try:  # the RL commands live with the agents package
        from softreach.agents.commands import add_commands as add_agent_commands
    except ImportError:
        pass
    else:
        add_agent_commands(sub)
    return parser


def main(argv: list[str] | None = None) -> int:
    parser = build_parser()
    args = parser.parse_args(argv)
    try:
        return int(args.func(args) or 0)
    except (ValueError, PermissionError, FileNotFoundError, RuntimeError) as exc:
        # bad input and unusable files: one clear line, no traceback
        from softreach.reach.tables.table import TableError

        kind = "error" if not isinstance(exc, TableError) else "table error"
        print(f"softreach: {kind}: {exc}", file=sys.stderr)
        return 2


if __name__ == "__main__":  # pragma: no cover
    sys.exit(main())
