"""softreach: Hamilton-Jacobi reachability with soft constraints.

Sub-packages: :mod:`softreach.reach` (solver and ``W_eps`` tables), :mod:`softreach.envs` (Gymnasium landings),
:mod:`softreach.filters` (safety filter), :mod:`softreach.agents` (training and evaluation).
"""

from importlib.metadata import PackageNotFoundError, version

try:
    __version__ = version("softreach")
except PackageNotFoundError:  # pragma: no cover - running from a source tree without install
    __version__ = "0.0.0+unknown"
