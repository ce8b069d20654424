"""The safety filter's compiled code, compiled in the background while ``softreach solve`` solves a table.

The filter's decision, a state's certificate and a start's plan search are numba code that a machine compiles once
(:mod:`softreach.filters.precompile`), into the package's compiled-code cache (:mod:`softreach.reach.jit`). That
compilation depends on neither the model nor the table (tables store float32, and each model's enclosure is called
by its address), so it need not wait for the user's table: ``softreach solve`` starts it in a process of its own (:func:`start`) where the cache lacks it,
and the solve and the compilation share the machine's cores instead of following each other. A filter built
meanwhile waits for that process and loads its result (:func:`softreach.reach.jit.wait_for_compile_ahead`).

``SOFTREACH_COMPILE_AHEAD=0`` turns it off (the test suite compiles the filter in a warm-up process of its own).

    python -m softreach.filters.background      # what softreach solve starts
"""

from __future__ import annotations

import argparse
import os
import subprocess
import sys
import tempfile
from pathlib import Path

#: set to ``0`` to keep ``softreach solve`` from compiling the filter in the background
ENV_SWITCH = "SOFTREACH_COMPILE_AHEAD"


def compiled_functions() -> tuple:
    """The filter's three compiled entry points: the decision, the certificate, the start-plan search."""
    from .compiled import decide_rows
    from .compiled_certify import certify_rows
    from .compiled_starts import start_plan_rows

    return decide_rows, certify_rows, start_plan_rows


def filter_code_cached() -> bool | None:
    """Whether the compiled decision, certificate and start-plan search are in numba's on-disk cache (or already
    compiled in this process): ``False`` when one must be compiled, ``None`` when the cache cannot be read."""
    try:
        # an index that numba loads for these sources (it reads an empty one where the sources changed)
        return all(f.signatures or f._cache._cache_file._load_index() for f in compiled_functions())
    except Exception:  # noqa: BLE001 - numba internals: not knowing is no reason to fail a solve or an episode
        return None


def start() -> subprocess.Popen | None:
    """Start compiling the filter's code in a background process where the cache lacks it and
    ``$SOFTREACH_COMPILE_AHEAD`` is not ``0``; the process, or ``None`` where none was started."""
    if os.environ.get(ENV_SWITCH, "1") == "0" or filter_code_cached() is not False:
        return None
    # detached from the terminal's Ctrl-C (a solve interrupted by the user leaves it to finish: the cache keeps
    # its work); its output goes nowhere: a failure costs only the time it would have saved
    return subprocess.Popen([sys.executable, "-m", "softreach.filters.background"],
                            stdin=subprocess.DEVNULL, stdout=subprocess.DEVNULL, stderr=subprocess.DEVNULL,
                            start_new_session=True)


def compile_ahead() -> str:
    """Compile the filter's code into the cache, holding the compile-ahead lock: ``"compiled"``, ``"cached"``
    (nothing to do) or ``"busy"`` (another process holds the lock)."""
    from softreach.reach import SolveConfig, SolverSettings, get_model, solve_table
    from softreach.reach.jit import compiling_ahead

    from .precompile import precompile

    with compiling_ahead(compiled_functions()) as held:
        if not held:
            return "busy"
        if filter_code_cached():
            return "cached"
        # the smallest table of a built-in model: the compiled code is the same for every model and table
        model = get_model("pointmass")
        cfg = SolveConfig(shape=(9, 9), budget_points=8, snapshots=2,
                          settings=SolverSettings.from_accuracy("low", compile=False))
        with tempfile.TemporaryDirectory() as folder:
            path = Path(folder) / "ahead.srt"
            solve_table(model, cfg, path, progress=False)
            precompile(str(path), period=model.control_period, cells=False)
    return "compiled"


def main(argv: list[str] | None = None) -> int:
    argparse.ArgumentParser(description="Compile the safety filter's code into the cache, in the background: "
                                        "prints compiled, cached or busy.").parse_args(argv)
    os.environ.setdefault("OMP_NUM_THREADS", "1")
    print(compile_ahead())
    return 0


if __name__ == "__main__":  # pragma: no cover
    sys.exit(main())
