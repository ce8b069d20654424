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

Names: the cache holds code that many processes compiled (a warm-up, the compile-ahead process, each test worker),
so that one process may load copies of a function from several. numba's symbol names can coincide between
processes, and a process that loads such copies may fail; every compilation in a process that imports this module
is numbered from a random start instead (:func:`_draw_function_ids`).

A process that compiles ahead of use (:func:`compiling_ahead`: ``softreach solve`` compiles the safety filter's code
in the background while it solves) holds a lock beside the cache and names the functions it compiles; another
process that misses one of them in the cache waits for it and loads the result (:meth:`PackageCache.load_overload`)
instead of compiling the same code at the same time on the same cores.

This relies on numba's cache classes (``numba.core.caching``), a dispatcher's ``_cache`` attribute and
``FunctionIdentity._unique_ids``, which ``pyproject.toml`` pins to a tested range of numba versions;
tests/test_numba_cache.py checks the mechanism.
"""

from __future__ import annotations

import contextlib
import functools
import hashlib
import importlib.util
import inspect
import itertools
import json
import os
import secrets
import sys
import time
import warnings
from collections.abc import Callable, Iterable, Iterator
from pathlib import Path
from typing import Any

import numba
from numba.core import config
from numba.core.bytecode import FunctionIdentity
from numba.core.caching import CompileResultCacheImpl, FunctionCache, _CacheLocator

try:  # POSIX file locks; elsewhere nothing compiles ahead and nothing waits
    import fcntl
except ImportError:  # pragma: no cover - Windows
    fcntl = None  # type: ignore[assignment]

#: the packages whose sources make up :func:`source_stamp` (pyproject.toml, ``[tool.setuptools] packages``;
#: each folder is searched with its sub-folders)
PACKAGES = ("softreach", "softreach.reach", "softreach.envs", "softreach.filters", "softreach.agents")


def _draw_function_ids() -> None:
    """Number this process's compilations from a random 62-bit start, drawn again in a forked child.

    numba names a compiled function's symbols by its qualified name and an id that counts compilations from 1 in
    every process (``FunctionIdentity._unique_ids``), so two processes that compile the same function after the
    same steps give it the same names (numba/numba#10486). A cached caller carries a copy of each function it
    calls; where that copy and the function's own cached code were compiled by two processes under one name, a
    process that loads both can fail at the function's first call from Python with
    ``In 'NRT_adapt_ndarray_to_python', 'descr' is NULL`` (docs/filters.md). With a random start the ids stay
    unique within a process and two processes' ranges overlap by a chance of about ``n / 2**61`` for ``n``
    compilations."""
    FunctionIdentity._unique_ids = itertools.count(secrets.randbits(62))


_draw_function_ids()
if hasattr(os, "register_at_fork"):
    os.register_at_fork(after_in_child=_draw_function_ids)


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

    def load_overload(self, sig: Any, target_context: Any) -> Any:
        """The cached code for ``sig``, or ``None``; where it is missing and another process is compiling this
        function ahead of use (:func:`compiling_ahead`), wait for that process and read the cache again."""
        out = super().load_overload(sig, target_context)
        if out is None and wait_for_compile_ahead(self._py_func):
            out = super().load_overload(sig, target_context)
        return out


#: the lock file beside the compiled code that a process compiling ahead of use holds (:func:`compiling_ahead`)
LOCK_NAME = "compiling-ahead.lock"
#: the longest wait for a process compiling ahead [s]; past it the waiting process compiles itself
WAIT_LIMIT_S = 1800.0
_HOLDING: list[bool] = [False]  # this process holds the lock: its own misses are its own to compile
_ANNOUNCED: list[bool] = [False]


def qualified_name(func: Callable) -> str:
    """``module.qualname`` of a Python function or of a dispatcher's ``py_func``: how the lock names functions."""
    func = getattr(func, "py_func", func)
    return f"{func.__module__}.{func.__qualname__}"


@contextlib.contextmanager
def compiling_ahead(functions: Iterable[Callable]) -> Iterator[bool]:
    """Hold the compile-ahead lock while this process compiles ``functions`` (dispatchers of :func:`njit`), so that
    a process that misses one of them in the cache meanwhile waits and loads it instead of compiling it too.

    Yields ``True`` while the lock is held, ``False`` (holding nothing) where another process holds it or the
    platform has no file locks. A process that dies releases the lock with it.
    """
    if fcntl is None:
        yield False
        return
    path = compiled_cache_dir() / LOCK_NAME
    path.parent.mkdir(parents=True, exist_ok=True)
    with open(path, "a+") as fh:
        try:
            fcntl.flock(fh, fcntl.LOCK_EX | fcntl.LOCK_NB)
        except BlockingIOError:
            yield False
            return
        _HOLDING[0] = True
        try:
            fh.seek(0)
            fh.truncate()
            fh.write(json.dumps({"pid": os.getpid(), "functions": [qualified_name(f) for f in functions]}))
            fh.flush()
            yield True
        finally:
            _HOLDING[0] = False
            fcntl.flock(fh, fcntl.LOCK_UN)


def wait_for_compile_ahead(func: Callable, poll_s: float = 0.1) -> bool:
    """Wait while another process compiles ``func`` ahead of use (:func:`compiling_ahead`); ``True`` if it waited.

    Says once on stderr why the process waits. Returns at once where no process holds the lock, where the holder
    compiles other functions, or where this process is the holder.
    """
    if fcntl is None or _HOLDING[0]:
        return False
    path = compiled_cache_dir() / LOCK_NAME
    try:
        fh = open(path)
    except OSError:
        return False
    with fh:
        try:
            fcntl.flock(fh, fcntl.LOCK_SH | fcntl.LOCK_NB)
        except BlockingIOError:
            pass
        else:
            fcntl.flock(fh, fcntl.LOCK_UN)
            return False
        try:
            holder = json.loads(fh.read() or "{}")
        except ValueError:
            holder = {}
        # only for the functions the holder names (one that has not yet written them is not waited for: a wrong
        # wait would stall an unrelated compilation for the holder's whole one)
        if qualified_name(func) not in holder.get("functions", ()):
            return False
        if not _ANNOUNCED[0]:
            _ANNOUNCED[0] = True
            print(f"softreach: waiting for process {holder.get('pid', '?')}, which compiles the safety filter's code "
                  f"ahead of its first use (started by softreach solve)", file=sys.stderr, flush=True)
        deadline = time.monotonic() + WAIT_LIMIT_S
        while time.monotonic() < deadline:
            try:
                fcntl.flock(fh, fcntl.LOCK_SH | fcntl.LOCK_NB)
            except BlockingIOError:
                time.sleep(poll_s)
                continue
            fcntl.flock(fh, fcntl.LOCK_UN)
            break
    return True


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


def entry_point(dispatcher: Any, args: tuple) -> Callable:
    """The compiled function that ``dispatcher(*args)`` runs, for a caller that passes the same argument objects
    again and again (arrays it rewrites in place): numba's dispatcher types every argument at every call, which for
    a long argument list costs more than the work; the entry point only unboxes them. ``dispatcher`` itself where
    it has compiled nothing for exactly these types (it may then convert them). Call the dispatcher once first, so
    that the code exists (``Dispatcher.overloads``, which the numba pin covers)."""
    types = tuple(dispatcher.typeof_pyval(a) for a in args)
    compiled = dispatcher.overloads.get(types)
    return dispatcher if compiled is None else compiled.entry_point
