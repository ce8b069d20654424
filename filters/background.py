"""The safety filter's compiled code (:mod:`softreach.filters.precompile`) compiled in a background process while
``softreach solve`` solves, so that the two share the cores; it depends on neither model nor table (tables store
float32; a model's enclosure is called by its address). A filter built meanwhile waits for it
(:func:`softreach.reach.jit.wait_for_compile_ahead`). ``SOFTREACH_COMPILE_AHEAD=0`` turns it off."""

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
    """The filter's compiled entry points: the decision (also a state's certificate) and the start-plan search."""
    from .compiled import decide_rows
    from .compiled_starts import start_plan_rows

    return decide_rows, start_plan_rows


def filter_code_cached() -> bool | None:
    """Whether the compiled decision and start-plan search are in numba's on-disk cache (or already
    compiled in this process): ``False`` when one must be compiled, ``None`` when the cache cannot be read."""
    try:
        # an index that numba loads for these sources (it reads an empty one where the sources changed)
        return all(f.signatures or f._cache._cache_file._load_index() for f in compiled_functions())
    except Exception:  # noqa: BLE001 - numba internals: not knowing is no reason to fail a solve or an episode
        return None


def start() -> subprocess.Popen | None:
    """Start compiling the filter's code in a background process where the cache lacks it and :data:`ENV_SWITCH`
    is not ``0``: the process, or ``None``."""
    if os.environ.get(ENV_SWITCH, "1") == "0" or filter_code_cached() is not False:
        return None
    # its own session: a solve's Ctrl-C leaves it to finish into the cache; a failure only costs the time it would save
    return subprocess.Popen([sys.executable, "-m", "softreach.filters.background"], stdin=subprocess.DEVNULL,
                            stdout=subprocess.DEVNULL, stderr=subprocess.DEVNULL, start_new_session=True)


def compile_ahead() -> str:
    """Compile the filter's code into the cache under the compile-ahead lock: ``"compiled"``, ``"cached"``
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
