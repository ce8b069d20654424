"""The test run's warm-up: compiles the filter's decision (:func:`softreach.filters.background.compile_ahead`, what
``softreach solve`` runs in the background), then solves the glider's shared held table and compiles the glider's
kernels on it (:func:`softreach.filters.precompile.precompile`, what ``softreach compile`` runs), in a process of its
own, started by ``tests/conftest.py`` while the tests that do not make the filter decide run.

The filter's first decision compiles it (``benchmarks/first_compile.py filter`` measures how long), paid otherwise by
whichever test decides first, while the machine's other core idles (one pytest process) or compiles the same code
(two workers). Here it is compiled once, beside the tests, into the run's compiled-code cache, which the tests then
load.

Usage: ``python tests/warm_up.py ROOT PHASE...`` with the phases ``pointmass`` (the filter's code) and ``glider`` (the
glider's shared held table, then its kernels). Each phase's lock (:func:`phase_lock`) is held from the start until the
phase is done, so a test that waits on it finds the decision compiled; the line ``locked`` on stdout says that every
lock is held. The tables themselves are taken under their own locks (:func:`shared_tables.solved`), never while
waiting on another. While the filter compiles, the warm-up also holds the compile-ahead lock
(:func:`softreach.reach.jit.compiling_ahead`): a test that makes the filter decide without waiting on a phase waits
for that compilation and loads it.
"""

from __future__ import annotations

import sys
from pathlib import Path

from filelock import FileLock

#: phase -> the shared held table whose filter it compiles
PHASES = {"pointmass": "pointmass_held", "glider": "glider_held"}


def phase_lock(root: Path, phase: str) -> FileLock:
    """The lock the warm-up holds while it prepares ``phase``'s filter."""
    return FileLock(str(Path(root) / f"warm_up-{phase}.lock"))


def main(argv: list[str]) -> int:
    root, phases = Path(argv[0]), argv[1:]
    held = [phase_lock(root, p) for p in phases]
    for each in held:
        each.acquire()
    print("locked", flush=True)

    import torch

    torch.set_num_threads(1)  # beside the tests, on a machine of two cores
    sys.path.insert(0, str(Path(__file__).resolve().parent))
    from shared_tables import solved

    from softreach.filters.background import compile_ahead
    from softreach.filters.precompile import precompile
    from softreach.reach import load_table

    for phase, phase_held in zip(phases, held):
        # the filter's compiled code is the same for every table: compiled first on the smallest one (what
        # softreach solve compiles in the background), so that the tests need not also wait for the shared held
        # table, which the first of them to ask solves meanwhile
        result = compile_ahead() if phase == "pointmass" else None
        if result in (None, "busy"):  # the glider's kernels, or another process compiles ahead: on the shared table
            path = solved(PHASES[phase], root)  # or the table a test has solved meanwhile
            result = precompile(load_table(path))
        print(f"{phase}: {result}", file=sys.stderr, flush=True)  # to the log the conftest keeps
        phase_held.release()
    return 0


if __name__ == "__main__":
    raise SystemExit(main(sys.argv[1:]))
