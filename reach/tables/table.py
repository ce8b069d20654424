"""``W_eps`` / ``V`` tables: one file, written snapshot by snapshot, memory-mapped on load.

Layout: a 16-byte magic, an 8-byte header capacity, a JSON header padded to that capacity, then (aligned to 4 KiB)
one float32 C-order block per field of shape ``(n_times, *grid.shape)``. The solver streams each snapshot to its
place as soon as it is computed and rewrites the header's ``done`` flags, so an interrupted solve leaves a
``.partial`` file to resume from and never more than one snapshot interval of lost work. On completion the
SHA-256 of every block is stored and the file is renamed into place.

Loading checks the magic, the header, the file size (truncation) and the checksums (streamed in chunks), then
memory-maps the blocks: a 4-D glider table is never held twice in memory, nor even once.
"""

from __future__ import annotations

import datetime as _dt
import hashlib
import json
import math
import os
import threading
from concurrent.futures import Future, ThreadPoolExecutor
from pathlib import Path
from typing import Any, Callable

import numpy as np

from ..numerics.grid import Grid

MAGIC = b"SOFTREACH-TBL\x00v1"
HEADER_CAPACITY = 1 << 20
ALIGN = 4096
FORMAT_VERSION = 1
_CHUNK = 1 << 24


class TableError(ValueError):
    """A table file that cannot be used: corrupted, truncated, incomplete or made for something else."""


def _data_start() -> int:
    return _align(len(MAGIC) + 8 + HEADER_CAPACITY)


def _align(n: int) -> int:
    return (n + ALIGN - 1) // ALIGN * ALIGN


def _version() -> str:
    try:
        from importlib.metadata import version

        return version("softreach")
    except Exception:  # pragma: no cover
        return "unknown"


class TableWriter:
    """Creates (or resumes) a table file and streams snapshots into it.

    :param path: final path; work goes to ``path + ".partial"`` until :meth:`finalize`
    :param header: the header (``fields`` entries need ``grid``, ``times``; offsets are filled in here)
    """

    def __init__(self, path: str | os.PathLike, header: dict[str, Any], *, resume: bool = True):
        self.path = Path(path)
        # the file and the header are shared by the solver's thread and the snapshots' writer
        # (:class:`BackgroundWrites`): one operation at a time
        self._lock = threading.RLock()
        self.partial = self.path.with_name(self.path.name + ".partial")
        offset = end = _data_start()
        for spec in header["fields"].values():
            shape = [len(spec["times"])] + list(spec["grid"]["shape"])
            spec.update(offset=offset, shape=shape, dtype="<f4", sha256=None)
            spec.setdefault("done", [False] * shape[0])
            end = offset + 4 * int(np.prod(shape))
            offset = _align(end)
        header.update(format="softreach-table", format_version=FORMAT_VERSION, complete=False)
        self.size = end  # no padding after the last block: any truncation cuts into data
        if resume and self.partial.exists():
            old = read_header(self.partial, allow_incomplete=True)
            mismatch = _first_mismatch(_identity(old), _identity(header))
            if mismatch:
                raise TableError(f"{self.partial} was started with other settings ({mismatch}); delete it or pass resume=False / --no-resume")
            for name, spec in header["fields"].items():
                spec["done"] = old["fields"][name]["done"]
                # solver time already spent on this field, so that a resumed solve reports the whole cost
                spec["wall_s"] = old["fields"][name].get("wall_s", 0.0)
            header["created"] = old.get("created")
            self.header = header
            self._f = open(self.partial, "r+b")
        else:
            self.header = header
            header["created"] = _dt.datetime.now(_dt.timezone.utc).isoformat(timespec="seconds")
            self._f = open(self.partial, "w+b")
            self._f.truncate(self.size)
            self._write_header()

    def resume_point(self, field: str) -> int | None:
        """The earliest snapshot index ``k`` such that all of ``k..n-1`` are done (``None``: nothing done)."""
        done = self.header["fields"][field]["done"]
        k = len(done)
        while k > 0 and done[k - 1]:
            k -= 1
        return None if k == len(done) else k

    def read_snapshot(self, field: str, k: int) -> np.ndarray:
        spec = self.header["fields"][field]
        n = int(np.prod(spec["shape"][1:]))
        with self._lock:
            self._f.seek(spec["offset"] + 4 * n * k)
            data = np.frombuffer(self._f.read(4 * n), dtype="<f4")
        return data.reshape(spec["shape"][1:]).copy()

    def write_snapshot(self, field: str, k: int, value: Any) -> None:
        """Write snapshot ``k`` of ``field`` (any array convertible to float32) and mark it done."""
        from ..backend import to_numpy

        spec = self.header["fields"][field]
        arr = np.ascontiguousarray(to_numpy(value), dtype="<f4")
        if list(arr.shape) != spec["shape"][1:]:
            raise ValueError(f"snapshot of shape {arr.shape} for field {field!r} with grid {spec['shape'][1:]}")
        if not np.isfinite(arr).all():
            raise FloatingPointError(f"the solver produced non-finite values in {field!r} at t={spec['times'][k]}")
        with self._lock:
            self._f.seek(spec["offset"] + arr.nbytes * k)
            self._f.write(arr.data)
            self._f.flush()
            os.fsync(self._f.fileno())
            spec["done"][k] = True
            self._write_header()

    def set(self, **entries: Any) -> None:
        """Add or replace top-level header entries (e.g. a solve summary)."""
        with self._lock:
            self.header.update(entries)
            self._write_header()

    def finalize(self) -> Path:
        """Checksum every block, mark the table complete and move it to its final path."""
        with self._lock:
            for name, spec in self.header["fields"].items():
                if not all(spec["done"]):
                    raise TableError(f"field {name!r} is missing snapshots; cannot finalize")
                spec["sha256"] = _sha256(self._f, spec["offset"], 4 * int(np.prod(spec["shape"])))
            self.header["complete"] = True
            self.header["softreach_version"] = _version()
            self._write_header()
            self._f.close()
            os.replace(self.partial, self.path)
        return self.path

    def close(self) -> None:
        with self._lock:
            if not self._f.closed:
                self._f.close()

    def _write_header(self) -> None:
        blob = json.dumps(self.header, sort_keys=True).encode()
        if len(blob) > HEADER_CAPACITY:
            raise TableError(f"table header of {len(blob)} bytes exceeds {HEADER_CAPACITY}")
        self._f.seek(0)
        self._f.write(MAGIC + len(blob).to_bytes(8, "little") + blob + b" " * (HEADER_CAPACITY - len(blob)))
        self._f.flush()


class BackgroundWrites:
    """Runs the writing of snapshots on one thread while the solver computes the next: on a GPU the step does not
    wait for the disk, and on a CPU the disk's waits leave the cores to the solver. At most one write is in flight,
    so at most one snapshot is held twice; :meth:`wait` returns when it is on disk and raises what it raised."""

    def __init__(self) -> None:
        self._pool = ThreadPoolExecutor(1, thread_name_prefix="softreach-write")
        self._pending: Future | None = None

    def submit(self, fn: Callable[..., Any], *args: Any) -> None:
        """Run ``fn(*args)`` on the writer's thread, after the write in flight (if any) has finished."""
        self.wait()
        self._pending = self._pool.submit(fn, *args)

    def wait(self) -> None:
        """Until the write in flight is done; its exception, if any, is raised here."""
        pending, self._pending = self._pending, None
        if pending is not None:
            pending.result()

    def close(self) -> None:
        """Finish the write in flight (also on Ctrl-C: a finished snapshot is never lost) and stop the thread."""
        try:
            self.wait()
        finally:
            self._pool.shutdown(wait=True)


def _identity(header: dict[str, Any]) -> dict[str, Any]:
    """The parts of a header that must agree for a partial file to be resumed."""
    return {"model": header.get("model"), "fields": {
        k: {kk: v[kk] for kk in ("grid", "times", "problem", "settings")} for k, v in header["fields"].items()}}


def _first_mismatch(a: Any, b: Any, where: str = "") -> str | None:
    if isinstance(a, dict) and isinstance(b, dict):
        for key in sorted(set(a) | set(b)):
            m = _first_mismatch(a.get(key), b.get(key), f"{where}.{key}" if where else str(key))
            if m:
                return m
        return None
    if isinstance(a, (list, tuple)) and isinstance(b, (list, tuple)):
        if len(a) != len(b):
            return f"{where}: {list(a)!r} != {list(b)!r}"
        for i, (x, y) in enumerate(zip(a, b)):
            m = _first_mismatch(x, y, f"{where}[{i}]")
            if m:
                return m
        return None
    if isinstance(a, (int, float)) and isinstance(b, (int, float)) and not isinstance(a, bool):
        return None if math.isclose(a, b, rel_tol=1e-9, abs_tol=1e-12) else f"{where}: {a!r} != {b!r}"
    return None if a == b else f"{where}: {a!r} != {b!r}"


def _sha256(f, offset: int, nbytes: int) -> str:
    h = hashlib.sha256()
    f.seek(offset)
    left = nbytes
    while left > 0:
        chunk = f.read(min(_CHUNK, left))
        if not chunk:
            break
        h.update(chunk)
        left -= len(chunk)
    return h.hexdigest()


def read_header(path: str | os.PathLike, *, allow_incomplete: bool = False) -> dict[str, Any]:
    """Read and check a table's header (magic, JSON, version, completeness, size)."""
    path = Path(path)
    if not path.exists():
        raise FileNotFoundError(f"no table at {path}")
    size = path.stat().st_size
    with open(path, "rb") as f:
        head = f.read(len(MAGIC) + 8)
        if len(head) < len(MAGIC) + 8 or head[: len(MAGIC)] != MAGIC:
            raise TableError(f"{path} is not a softreach table (bad magic bytes)")
        n = int.from_bytes(head[len(MAGIC):], "little")
        if n > HEADER_CAPACITY:
            raise TableError(f"{path}: header length {n} is corrupted (capacity {HEADER_CAPACITY})")
        blob = f.read(n)
    if len(blob) < n:
        raise TableError(f"{path} is truncated inside its header ({size} bytes)")
    try:
        header = json.loads(blob)
    except (UnicodeDecodeError, json.JSONDecodeError) as exc:
        raise TableError(f"{path}: header is corrupted ({exc})") from None
    if header.get("format") != "softreach-table" or header.get("format_version") != FORMAT_VERSION:
        raise TableError(f"{path}: unsupported table format {header.get('format')!r} version {header.get('format_version')!r}")
    if not allow_incomplete and not header.get("complete"):
        raise TableError(f"{path} is incomplete: the solve that wrote it did not finish (resume it with the same command)")
    end = max(spec["offset"] + 4 * int(np.prod(spec["shape"])) for spec in header["fields"].values())
    if size < end:
        raise TableError(f"{path} is truncated: {size} bytes, expected {end}")
    return header


def verify(path: str | os.PathLike, header: dict[str, Any]) -> None:
    """Recompute every block's SHA-256 (streamed) and compare with the header."""
    with open(path, "rb") as f:
        for name, spec in header["fields"].items():
            digest = _sha256(f, spec["offset"], 4 * int(np.prod(spec["shape"])))
            if digest != spec.get("sha256"):
                raise TableError(f"{path}: checksum mismatch in field {name!r}: the data is corrupted")


def open_field(path: str | os.PathLike, header: dict[str, Any], name: str) -> np.memmap:
    """Memory-map one field's block, shape ``(n_times, *grid.shape)``."""
    spec = header["fields"][name]
    return np.memmap(path, dtype=spec["dtype"], mode="r", offset=spec["offset"], shape=tuple(spec["shape"]))


def field_grid(header: dict[str, Any], name: str) -> Grid:
    return Grid.from_dict(header["fields"][name]["grid"])
