"""softreach: Hamilton-Jacobi reachability with soft constraints.

Sub-packages: :mod:`softreach.reach` (solver and ``W_eps`` tables), :mod:`softreach.envs` (Gymnasium landings),
:mod:`softreach.filters` (safety filter), :mod:`softreach.agents` (training and evaluation).
"""

import importlib
from importlib.metadata import PackageNotFoundError, version
from typing import Any, Callable

try:
    __version__ = version("softreach")
except PackageNotFoundError:  # pragma: no cover - running from a source tree without install
    __version__ = "0.0.0+unknown"


def lazy_exports(namespace: dict[str, Any], exports: dict[str, str]) -> tuple[Callable[[str], Any],
                                                                             Callable[[], list[str]]]:
    """``__getattr__`` and ``__dir__`` of a package whose public names load at their first use (PEP 562), so that
    importing one of its modules imports no more than that module needs.

    :param namespace: the package's ``globals()``
    :param exports: public name -> the module defining it, relative to the package (``".core"``) or absolute"""
    package = namespace["__name__"]

    def __getattr__(name: str) -> Any:
        where = exports.get(name)
        if where is None:
            raise AttributeError(f"module {package!r} has no attribute {name!r}")
        value = getattr(importlib.import_module(where, package), name)
        namespace[name] = value  # later look-ups skip this function
        return value

    def __dir__() -> list[str]:
        return sorted(set(namespace) | set(exports))

    return __getattr__, __dir__
