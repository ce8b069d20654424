"""The package's compiled code and its one on-disk cache: :func:`njit` is ``numba.njit`` with the cache keyed by
the package's sources and kept in the user's cache folder.

Why a key of its own: numba's own cache (``numba.njit(cache=True)``) checks only the file that holds the
compiled function. Code compiled into it from other files (the functions it calls or inlines, the constants it
reads, an intrinsic's code generation) is not part of that check, so after a change there numba would load code
built from the old version. Here every cached function carries one stamp, a digest of every ``.py`` file of the
``softreach`` packages (:func:`source_stamp`, computed once per process): a change anywhere in the package
compiles everything afresh, and nothing is kept in step by hand.

Where: ``$NUMBA_CACHE_DIR`` when it is set (numba's own setting), else ``numba/`` in the folder that holds the
package's other cached files (:func:`cache_root`: ``$SOFTREACH_CACHE`` or ``~/.cache/softreach``). Never inside
the installed package, which is often read-only. Only the functions compiled through :func:`njit` use it; other
numba code in the same process keeps numba's defaults.

This relies on numba's cache classes (``numba.core.caching``) and on a dispatcher's ``_cache`` attribute, which
``pyproject.toml`` pins to a tested range of numba versions; tests/test_numba_cache.py checks the mechanism.
"""

from __future__ import annotations

import functools
import hashlib
import importlib.util
import inspect
import os
import sys
import warnings
from collections.abc import Callable, Iterable
from pathlib import Path
from typing import Any

import numba
from numba.core import config
from numba.core.caching import CompileResultCacheImpl, FunctionCache, _CacheLocator

#: the packages whose sources make up :func:`source_stamp` (pyproject.toml, ``[tool.setuptools] packages``;
#: each folder is searched with its sub-folders)
PACKAGES = ("softreach", "softreach.reach", "softreach.envs", "softreach.filters", "softreach.agents")


def cache_root() -> Path:
    """The folder of the package's cached files (compiled code, built cells): ``$SOFTREACH_CACHE`` or
    ``~/.cache/softreach``."""
    return Path(os.environ.get("SOFTREACH_CACHE") or Path.home() / ".cache" / "softreach")


def compiled_cache_dir() -> Path:
    """Where :func:`njit` keeps compiled code: ``$NUMBA_CACHE_DIR`` if set, else ``cache_root() / "numba"``."""
    return Path(config.CACHE_DIR) if config.CACHE_DIR else cache_root() / "numba"


def source_files(packages: Iterable[str] = PACKAGES) -> list[Path]:
    """Every ``.py`` file in the folders of ``packages`` and their sub-folders, sorted, each once.

    :param packages: dotted package names (their parents are imported; they are only located)
    """
    files: set[Path] = set()
    for name in packages:
        spec = importlib.util.find_spec(name)
        if spec is None or not spec.submodule_search_locations:
            raise ImportError(f"cannot locate the package {name!r} to key the compiled-code cache")
        for folder in spec.submodule_search_locations:
            files.update(p.resolve() for p in Path(folder).rglob("*.py"))
    return sorted(files)


def digest(files: Iterable[Path]) -> str:
    """A sha256 digest of the files' names and contents (hex)."""
    h = hashlib.sha256()
    for path in files:
        data = Path(path).read_bytes()
        h.update(f"{Path(path).name}\0{len(data)}\0".encode())
        h.update(data)
    return h.hexdigest()


@functools.lru_cache(maxsize=1)
def source_stamp() -> str:
    """The digest of the package's sources (:func:`source_files`) that every cached function is keyed by; once
    per process."""
    return digest(source_files())


class _PackageLocator(_CacheLocator):
    """numba's cache locator for a function compiled by :func:`njit`: its folder under
    :func:`compiled_cache_dir` and the package's :func:`source_stamp` as the stamp numba compares."""

    def __init__(self, py_func: Callable, py_file: str, stamp: str) -> None:
        self._py_file = py_file
        self._lineno = py_func.__code__.co_firstlineno
        self._stamp = stamp
        # one sub-folder per source folder (numba's scheme), so that two installs do not evict each other
        self._cache_path = str(compiled_cache_dir() / self.get_suitable_cache_subpath(py_file))

    def get_cache_path(self) -> str:
        return self._cache_path

    def get_source_stamp(self) -> str:
        return self._stamp

    def get_disambiguator(self) -> str:
        return str(self._lineno)

    @classmethod
    def from_function(cls, py_func: Callable, py_file: str) -> _PackageLocator:
        return cls(py_func, py_file, source_stamp())


class _PackageCacheImpl(CompileResultCacheImpl):
    """numba's compile-result cache with :class:`_PackageLocator` as its only locator (numba's
    ``NUMBA_CACHE_LOCATOR_CLASSES`` does not replace it: that would drop the package's stamp)."""

    def __init__(self, py_func: Callable) -> None:
        self._lineno = py_func.__code__.co_firstlineno
        source = inspect.getfile(py_func)
        self._locator = _PackageLocator.from_function(py_func, source)
        # the file's base name and the qualified name, as numba names its files
        fullname = f"{os.path.splitext(os.path.basename(source))[0]}.{py_func.__qualname__}"
        self._filename_base = self.get_filename_base(fullname, getattr(sys, "abiflags", ""))


class PackageCache(FunctionCache):
    """numba's per-function disk cache, located and stamped by :class:`_PackageLocator`."""

    _impl_class = _PackageCacheImpl


_UNWRITABLE: list[str] = []  # the cache folder that could not be written, once warned about


def njit(func: Callable | None = None, **options: Any) -> Any:
    """``numba.njit`` with the package's disk cache (:class:`PackageCache`): ``@njit`` or ``@njit(**options)``.

    :param func: the function to compile (when used as ``@njit``)
    :param options: numba's ``njit`` options (``inline``, ``nogil``, ``_nrt``, ...); not ``cache``
    :raises TypeError: ``cache`` given (this function decides where and how code is cached)
    """
    if "cache" in options:
        raise TypeError(f"softreach.reach.jit.njit caches always; got cache={options['cache']!r}")

    def wrap(f: Callable) -> Any:
        dispatcher = numba.njit(**options)(f)
        try:
            cache = PackageCache(dispatcher.py_func)
            cache._impl.locator.ensure_cache_path()
        except OSError as e:
            folder = str(compiled_cache_dir())
            if folder not in _UNWRITABLE:
                _UNWRITABLE.append(folder)
                warnings.warn(f"softreach: cannot write the compiled-code cache {folder} ({e}); each process "
                              f"compiles afresh. Set SOFTREACH_CACHE to a writable folder.", stacklevel=2)
            return dispatcher
        dispatcher._cache = cache  # what numba's Dispatcher.enable_caching sets, with this cache instead
        return dispatcher

    return wrap if func is None else wrap(func)
