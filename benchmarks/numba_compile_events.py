"""Where numba's compile time goes over a run: a pytest plugin that records numba's compile events in each process
that loads it, and a summary of what the processes recorded.

    rm -rf /tmp/ev && SOFTREACH_CACHE=$(mktemp -d) NUMBA_CACHE_DIR=$(mktemp -d) COMPILE_EVENTS=/tmp/ev \\
        PYTHONPATH=benchmarks python -m pytest -q -n 2 -p numba_compile_events
    python benchmarks/numba_compile_events.py /tmp/ev

Each process that loads the plugin (the pytest workers; not the processes the tests start) writes, at its exit, the
seconds spent compiling each function, less the time of the functions compiled inside it, to
``$COMPILE_EVENTS/<pid>.json``. The summary adds them up by module, the solver's generated loops by kind (``rate``,
``stages``, ``ghosts``: :func:`softreach.reach.numerics.fused.kernel_sources`).
"""

from __future__ import annotations

import atexit
import collections
import json
import os
import sys
import time
from pathlib import Path


def _install(folder: Path) -> None:
    from numba.core import event

    open_events: list[list[float]] = []  # [start, seconds of the compilations inside it]
    spent: dict[str, float] = collections.defaultdict(float)

    class Recorder(event.Listener):
        def on_start(self, ev: event.Event) -> None:
            open_events.append([time.perf_counter(), 0.0])

        def on_end(self, ev: event.Event) -> None:
            start, inner = open_events.pop()
            seconds = time.perf_counter() - start
            func = getattr(ev.data.get("dispatcher"), "py_func", None) if isinstance(ev.data, dict) else None
            spent[f"{func.__module__}.{func.__qualname__}" if func else "?"] += seconds - inner
            if open_events:
                open_events[-1][1] += seconds

    event.register("numba:compile", Recorder())
    folder.mkdir(parents=True, exist_ok=True)
    atexit.register(lambda: (folder / f"{os.getpid()}.json").write_text(json.dumps(spent)))


def summary(folder: Path) -> None:
    """Print the compile seconds the processes recorded in ``folder``, by module and in all."""
    by_module: dict[str, float] = collections.Counter()
    for path in folder.glob("*.json"):
        for name, seconds in json.loads(path.read_text()).items():
            module = name.rsplit(".", 1)[0]
            if module.startswith("softreach_"):  # a generated module: softreach_<kind>_<digest>
                module = "generated " + module.split("_")[1]
            by_module[module] += seconds
    for module, seconds in by_module.most_common(20):
        print(f"{seconds:8.1f} s  {module}")
    print(f"{sum(by_module.values()):8.1f} s  in all ({len(list(folder.glob('*.json')))} processes)")


if __name__ == "__main__":
    summary(Path(sys.argv[1]))
elif os.environ.get("COMPILE_EVENTS"):
    _install(Path(os.environ["COMPILE_EVENTS"]))
