"""The solver's time step on a CPU as a few compiled loops over the grid (numba), one pass per Runge-Kutta stage.

A stage reads the value once from a ghost-padded copy and, node by node, forms the one-sided derivatives of every
axis, the numerical Hamiltonian and the CFL speed (one loop, :func:`rate_rows`); a second loop forms the stage
value, projects it and writes it back into the padded copy; a third refreshes the ghost layers. Nothing of that is
written twice: the loops' bodies are recorded from the solver's own array code (:mod:`softreach.reach.numerics.trace`):
the derivative scheme (:data:`~softreach.reach.numerics.derivatives.SCHEMES`), the ghost rule
(:func:`~softreach.reach.numerics.derivatives.ghost`), the model's Hamiltonian and dissipation
(:meth:`~softreach.reach.numerics.solver.HamiltonianOperator.numerical_hamiltonian`), the projection and the stages
(:data:`~softreach.reach.numerics.solver.RK_STAGES`).

The loops round every operation as the array code does (no fast-math; the array code multiplies differences by
``1/dx`` as the loops do), so that the two give the same table: ``RA~_0`` is the flat face ``W_eps = 0`` of the set,
where a value that the array code puts exactly on the floor ``W = 0`` and the loops put ``1e-10`` above it would move
a node out of the set. Reassociated sums and fused multiply-adds would make the WENO5 rate loop about 1.7 times faster
and move a few such nodes.

Why not ``torch.compile``: on a CPU it compiles the WENO5 step of a 3-D grid for over a minute, on every machine
that has not yet, and its loops keep several full-grid temporaries per stage. The source written here depends on the
model, the scheme and the float type, not on the grid; numba compiles it once (a few seconds) and keeps it in
``$SOFTREACH_CACHE/kernels`` for every later process. The rate loop is a module of its own; the stages and each axis's
ghost layers, which read only the grid's dimension, the scheme's width, the float type and the axis's rule, are
modules that every step reading the same shares (:func:`kernel_sources`).

Rows of the first axis are handed to threads in small chunks, taken in turn, so that a thread that the machine
deschedules (a loaded machine) delays only its current chunk.
"""

from __future__ import annotations

import hashlib
import importlib.util
import itertools
import os
import sys
from concurrent.futures import ThreadPoolExecutor
from pathlib import Path
from types import SimpleNamespace
from typing import Any

import numpy as np

from .. import backend as B
from .derivatives import SCHEMES, ghost
from .trace import Tape, Unsupported

_HEADER = '''"""Written by softreach.reach.numerics.fused; compiled by numba and cached beside this file."""
import numpy as np
import numba as nb
F = np.DTYPE
# no fast-math: each operation is rounded as the array code rounds it (module docstring of softreach.reach.numerics.fused)
_JIT = dict(nogil=True, cache=True, error_model="numpy", boundscheck=False)
'''


def kernel_dir() -> Path:
    """Where the generated loops and numba's compiled copies of them are kept: ``kernels/`` in
    :func:`~softreach.reach.jit.cache_root`. Each file holds all its code and is named by the digest of its text, so
    numba's own cache check (the file's time stamp) is the right one for it."""
    from ..jit import cache_root

    return cache_root() / "kernels"


def padded_index(ndim: int, axis: int | None, expr: str, pad: str) -> str:
    """``up[...]`` index: node ``i_b + pad`` along every axis, ``expr`` along ``axis``."""
    return ", ".join(expr if b == axis else f"i{b}{pad}" for b in range(ndim))


def _loops(ndim: int, first: str, indent: int, skip: int | None = None) -> tuple[list[str], str]:
    """Nested ``for`` lines over the nodes (the first loop over ``first``), and the body's indentation."""
    lines, pad, outer = [], " " * indent, True
    for b in range(ndim):
        if b == skip:
            continue
        rng = first if (outer and first) else f"range(n{b})"
        lines.append(f"{pad}for i{b} in {rng}:")
        pad += "    "
        outer = False
    return lines, pad


def parameters(dynamics: Any) -> list[float]:
    """The values a compiled step reads at every call instead of baking them in: ``dynamics.kernel_parameters()``
    where the dynamics has them (the held action of :class:`~softreach.reach.numerics.held.HeldControl`), else none."""
    get = getattr(dynamics, "kernel_parameters", None)
    return [float(v) for v in get()] if get is not None else []


def parameter_array(dynamics: Any, dtype: Any) -> np.ndarray:
    """:func:`parameters` as the kernels' ``params`` argument (one unused entry where there are none: a typed
    array either way)."""
    return np.array(parameters(dynamics) or [0.0], dtype=dtype)


def rate_body(op: Any, width: int) -> tuple[list[str], str, str]:
    """The rate at node ``(i0, i1, ...)`` as straight-line code: ``(lines, rate, speed)``, the lines reading the
    stencil of every axis from the padded ``up`` (ghost width ``W``), the coordinates ``x<a>v``, the steps ``h<a>``,
    ``inv<a> = 1 / h<a>``, ``t`` and the :func:`parameters` ``p<i>``; ``rate`` and ``speed`` the expressions of the
    node's rate and CFL speed. The CPU loops here and the GPU kernels (:mod:`softreach.reach.numerics.gpu`) put the same
    lines in their own loops."""
    import contextlib

    D = op.grid.ndim
    fn = SCHEMES[op.settings.scheme][1]
    tape = Tape()
    loads, lefts, rights = [], [], []
    for a in range(D):
        for m in range(2 * width + 1):
            loads.append(f"u{a}_{m} = up[{padded_index(D, a, f'i{a} + {m}', ' + W')}]")
        for m in range(2 * width):
            loads.append(f"d{a}_{m} = (u{a}_{m + 1} - u{a}_{m}) * inv{a}")
        dm, dp = fn([tape.var(f"d{a}_{m}") for m in range(2 * width)])
        lefts.append(dm)
        rights.append(dp)
    xs = [tape.var(f"x{a}v") for a in range(D)]
    hs = [tape.var(f"h{a}") for a in range(D)]
    n = len(parameters(op.dynamics))
    given = op.dynamics.parameters_as([tape.var(f"p{i}") for i in range(n)]) if n else contextlib.nullcontext()
    with given:
        out, speed = op.numerical_hamiltonian(tape.var("t"), xs, hs, lefts, rights)
    loads = [f"p{i} = params[{i}]" for i in range(n)] + loads
    return loads + tape.lines, tape.value(out), tape.value(speed)


def _rate_source(op: Any, width: int) -> list[str]:
    """``rate_rows(lo, hi, up, out, xs..., inv, h, t, params, speed, acc)``: the rate and the CFL speed at rows
    ``lo:hi``."""
    D = op.grid.ndim
    body, out, speed = rate_body(op, width)
    args = ", ".join(f"x{a}" for a in range(D))
    src = ["@nb.njit(**_JIT)", f"def rate_rows(lo, hi, up, out, {args}, inv, h, t, params, speed, acc):", f"    W = {width}"]
    src += [f"    n{a} = out.shape[{a}]" for a in range(D)]
    src += [f"    inv{a} = inv[{a}]" for a in range(D)] + [f"    h{a} = h[{a}]" for a in range(D)]
    # the largest speed of a row is kept per node of the last axis: a running maximum in one variable would keep
    # the loop from being vectorised, a maximum per lane does not
    last = f"i{D - 1}"
    src += [f"    top = np.zeros(n{D - 1}, F)", f"    total = np.zeros(n{D - 1}, F)", "    for i0 in range(lo, hi):",
            "        x0v = x0[i0]"]
    if D > 1:
        src += ["        top[:] = F(0.0)", "        total[:] = F(0.0)"]
    loops, pad = _loops(D, "", 8, skip=0)
    src += loops
    for a in range(1, D):
        src.append(f"{pad}x{a}v = x{a}[i{a}]")
    src += [pad + line for line in body]
    node = ", ".join(f"i{b}" for b in range(D))
    src += [f"{pad}h_out = {out}", f"{pad}out[{node}] = h_out",
            f"{pad}top[{last}] = max(top[{last}], {speed})", f"{pad}total[{last}] += h_out"]
    src += ["        speed[i0] = top.max()" if D > 1 else "        speed[i0] = top[i0]",
            "        acc[i0] = total.sum()" if D > 1 else "        acc[i0] = total[i0]"]
    return src


def stage_pairs() -> list[tuple[float, float]]:
    """The distinct ``(a, b)`` of :data:`~softreach.reach.numerics.solver.RK_STAGES`, in the order of their kernels."""
    from .solver import RK_STAGES

    return sorted({(a, b) for stages in RK_STAGES.values() for a, b, _ in stages})


def stage_body(a: float, b: float) -> tuple[list[str], str]:
    """The projected stage value ``P(a uv + b (pv + dt rv))`` of one node from ``uv``, ``pv``, ``rv``, ``lv``, ``cv``
    and ``dt``, as ``(lines, value)``."""
    from .solver import project_values, stage_value

    tape = Tape()
    v = project_values(tape.var("lv"), tape.var("cv"),
                       stage_value(a, b, tape.var("uv"), tape.var("pv"), tape.var("dt"), tape.var("rv")))
    return tape.lines, tape.value(v)


def ghost_body(rule: Any, end: str, width: int) -> tuple[list[str], list[str]]:
    """The ``width`` ghost values beyond one end (``end``: ``"lo"`` or ``"hi"``) under a non-periodic ``rule``
    (:func:`~softreach.reach.numerics.derivatives.ghost`), from the edge value ``e_<end>`` and the next one ``i_<end>``:
    ``(lines, values)``, nearest the edge first."""
    tape = Tape()
    values = [ghost(rule, tape.var(f"e_{end}"), tape.var(f"i_{end}"), k) for k in range(1, width + 1)]
    return _renamed(tape.lines, f"g{end}_"), [_renamed([tape.value(v)], f"g{end}_")[0] for v in values]


def _stage_sources(op: Any, width: int) -> tuple[list[str], dict[tuple[float, float], str]]:
    """One ``stage_<k>(lo, hi, u, up, r, l, c, dt, write_u)`` per pair of :func:`stage_pairs`: the projected stage
    value into the padded copy (and into ``u``)."""
    D = op.grid.ndim
    src, names = [], {}
    node = ", ".join(f"i{b}" for b in range(D))
    inner = padded_index(D, None, "", " + W")
    for k, (a, b) in enumerate(stage_pairs()):
        lines, v = stage_body(a, b)
        names[(a, b)] = f"stage_{k}"
        src += ["@nb.njit(**_JIT)", f"def stage_{k}(lo, hi, u, up, r, l, c, dt, write_u):", f"    W = {width}"]
        src += [f"    n{d} = u.shape[{d}]" for d in range(D)]
        loops, pad = _loops(D, "range(lo, hi)", 4)
        src += loops
        src += [f"{pad}uv = u[{node}]", f"{pad}pv = up[{inner}]", f"{pad}rv = r[{node}]", f"{pad}lv = l[{node}]",
                f"{pad}cv = c[{node}]"] + [pad + line for line in lines]
        src += [f"{pad}v = {v}", f"{pad}up[{inner}] = v", f"{pad}if write_u:", f"{pad}    u[{node}] = v"]
    return src, names


def _ghost_source(op: Any, width: int, a: int) -> list[str]:
    """``ghosts_<a>(up)``: the ghost layers along axis ``a`` at the other axes' inner nodes
    (:func:`~softreach.reach.numerics.derivatives.pad`: wrapped where periodic, else
    :func:`~softreach.reach.numerics.derivatives.ghost`)."""
    D = op.grid.ndim
    rule = op.boundaries[a]
    src = ["@nb.njit(**_JIT)", f"def ghosts_{a}(up):", f"    W = {width}"]
    src += [f"    n{d} = up.shape[{d}] - 2 * W" for d in range(D)]
    loops, pad = _loops(D, "", 4, skip=a)
    src += loops
    at = lambda e: f"up[{padded_index(D, a, e, ' + W')}]"  # noqa: E731
    n = f"n{a}"
    if rule == "periodic":
        for g in range(width):
            src += [f"{pad}{at(str(g))} = {at(f'{g} + {n}')}", f"{pad}{at(f'{n} + W + {g}')} = {at(f'W + {g}')}"]
        return src
    lo_rule, hi_rule = (rule, rule) if isinstance(rule, str) else rule
    for end, r, edge, inner, place in (("lo", lo_rule, "W", "W + 1", "W - {k}"),
                                       ("hi", hi_rule, f"{n} + W - 1", f"{n} + W - 2", f"{n} + W - 1 + {{k}}")):
        lines, values = ghost_body(r, end, width)
        src += [f"{pad}e_{end} = {at(edge)}", f"{pad}i_{end} = {at(inner)}"] + [pad + line for line in lines]
        for k, v in enumerate(values, start=1):
            src.append(f"{pad}{at(place.format(k=k))} = {v}")
    return src


def _renamed(lines: list[str], prefix: str) -> list[str]:
    """Recorded lines with their temporaries ``tN`` renamed ``<prefix>N`` (tapes of one function must not share
    names: numba gives a name one type)."""
    import re

    return [re.sub(r"\bt(\d+)\b", prefix + r"\1", line) for line in lines]


def kernel_sources(op: Any, dtype: str) -> dict[str, str]:
    """The loops of ``op``'s step as Python source for numba, one module per part, so that steps whose part reads
    the same share its compiled code: ``"rate"`` (the model's Hamiltonian and the scheme), ``"stages"`` (the
    grid's dimension and the scheme's width) and ``"ghosts_<a>"`` per axis (its rule, the dimension and the width).

    :raises Unsupported: the model's code does something a pointwise loop cannot (the array path then runs)
    """
    width = SCHEMES[op.settings.scheme][0]
    header = _HEADER.replace("DTYPE", dtype)
    parts = {"rate": _rate_source(op, width), "stages": _stage_sources(op, width)[0]}
    parts.update({f"ghosts_{a}": _ghost_source(op, width, a) for a in range(op.grid.ndim)})
    return {name: "\n".join([header] + lines) + "\n" for name, lines in parts.items()}


def load_kernels(op: Any, dtype: str) -> Any:
    """``op``'s compiled loops by name (``rate_rows``, ``stage_<k>``, ``ghosts_<a>``), from the modules of
    :func:`kernel_sources` (:func:`load_source`)."""
    loops = {}
    for part, text in kernel_sources(op, dtype).items():
        module = load_source(text, f"softreach_{part.split('_')[0]}_")
        loops.update({k: v for k, v in vars(module).items() if k.startswith(("rate_rows", "stage_", "ghosts_"))})
    return SimpleNamespace(**loops)


def load_source(text: str, prefix: str) -> Any:
    """Generated kernel source as a module, written into :func:`kernel_dir` under ``prefix`` and the digest of its
    text (once: numba keys its cache on the file's time stamp, and keeps the compiled code beside it) and imported
    from there."""
    name = prefix + hashlib.sha256(text.encode()).hexdigest()[:20]
    if name in sys.modules:
        return sys.modules[name]
    folder = kernel_dir()
    folder.mkdir(parents=True, exist_ok=True)
    path = folder / f"{name}.py"
    if not path.exists() or path.read_text() != text:
        tmp = folder / f".{name}.{os.getpid()}.tmp"
        tmp.write_text(text)
        os.replace(tmp, path)
    spec = importlib.util.spec_from_file_location(name, path)
    module = importlib.util.module_from_spec(spec)
    sys.modules[name] = module
    spec.loader.exec_module(module)
    return module


class Rows:
    """Runs ``fn(lo, hi, *args)`` over ``range(rows)`` in chunks that ``threads`` threads take in turn."""

    def __init__(self, threads: int):
        self.threads = max(1, int(threads))
        self._pool = ThreadPoolExecutor(self.threads - 1, thread_name_prefix="softreach-step") if self.threads > 1 else None

    def __call__(self, fn: Any, rows: int, *args: Any) -> None:
        if self._pool is None or rows < 2:
            fn(0, rows, *args)
            return
        chunk = max(1, rows // (8 * self.threads))
        taken = itertools.count()

        def work() -> None:
            while True:
                lo = next(taken) * chunk  # itertools.count is advanced under the GIL: each chunk goes to one thread
                if lo >= rows:
                    return
                fn(lo, min(rows, lo + chunk), *args)

        others = [self._pool.submit(work) for _ in range(self.threads - 1)]
        try:
            work()
        finally:
            for f in others:
                f.exception()
        for f in others:
            f.result()


class FusedStepper:
    """:class:`~softreach.reach.numerics.solver.Stepper`'s interface (``rate``, ``step``, ``done``) on the compiled loops.

    The value lives in a ghost-padded buffer between steps; a value handed back in is recognised (by identity) and
    not copied again. ``step`` returns that buffer's plain twin, overwritten by the next step: :meth:`done` gives a
    copy to keep.
    """

    def __init__(self, op: Any, settings: Any, threads: int | None = None):
        self.op, self.settings = op, settings
        self.kernels = load_kernels(op, settings.dtype)
        self.width = SCHEMES[settings.scheme][0]
        dt = np.dtype(settings.dtype)
        shape = op.grid.shape
        self.u = np.zeros(shape, dt)
        self.up = np.zeros(tuple(n + 2 * self.width for n in shape), dt)
        self.r = np.zeros(shape, dt)
        self.xs = [np.ascontiguousarray(B.to_numpy(x).reshape(-1), dtype=dt) for x in op.x]
        self.h = np.array(op.dx, dtype=dt)
        self.inv = np.array([1.0 / d for d in op.dx], dtype=dt)
        self.speed = np.zeros(shape[0], dt)
        self.acc = np.zeros(shape[0], dt)
        self.torch = settings.backend == "torch"
        self.handle = B.torch.from_numpy(self.u) if self.torch else self.u
        self._loaded: Any = None
        if threads is None:
            threads = B.torch.get_num_threads() if B.torch is not None else 1
        self.rows = Rows(threads)
        from .solver import RK_STAGES

        self.table = RK_STAGES[settings.time_order]
        names = _stage_sources(op, self.width)[1]
        self.stages = [getattr(self.kernels, names[(a, b)]) for a, b, _ in self.table]

    def _load(self, u: Any) -> None:
        self._loaded = u  # the value held now (a reference: the same object handed in again is not copied again)
        self.u[...] = B.to_numpy(u)
        self.up[tuple(slice(self.width, -self.width) for _ in self.u.shape)] = self.u
        self._ghosts()

    def _ghosts(self) -> None:
        for a in range(self.u.ndim):
            getattr(self.kernels, f"ghosts_{a}")(self.up)

    def _rate(self, t: float) -> float:
        k = self.kernels
        self.rows(k.rate_rows, self.u.shape[0], self.up, self.r, *self.xs, self.inv, self.h, self.u.dtype.type(t),
                  parameter_array(self.op.dynamics, self.u.dtype), self.speed, self.acc)
        if not np.isfinite(self.acc.sum(dtype=np.float64)):
            return float("nan")
        return float(self.speed.max())

    def rate(self, t: float, u: Any) -> tuple[Any, float]:
        if u is not self.handle and u is not self._loaded:
            self._load(u)
        speed = self._rate(t)
        return (B.torch.from_numpy(self.r) if self.torch else self.r), speed

    def step(self, t: float, u: Any, rate: Any, dt: float) -> Any:
        if u is not self.handle and u is not self._loaded:  # a value from elsewhere, with its rate: start from them
            self._load(u)
            self.r[...] = B.to_numpy(rate)
        self._loaded = None  # the buffer moves on: the value handed in last is no longer what it holds
        before = 0.0
        last = len(self.table) - 1
        for k, (kernel, (_, _, c)) in enumerate(zip(self.stages, self.table)):
            if k > 0:
                self._rate(t - before * dt)
            l, cc = (B.to_numpy(v) for v in self.op._sets(t - c * dt))
            self.rows(kernel, self.u.shape[0], self.u, self.up, self.r, l, cc, self.u.dtype.type(dt), k == last)
            self._ghosts()
            before = c
        return self.handle

    def done(self, u: Any) -> Any:
        """``u`` to keep: a copy where it is this stepper's buffer."""
        if u is self.handle:
            return B.torch.from_numpy(self.u.copy()) if self.torch else self.u.copy()
        return u


def fused_stepper(op: Any, settings: Any) -> FusedStepper | None:
    """A :class:`FusedStepper` for ``op``, or ``None`` where its code cannot be compiled pointwise (:class:`Unsupported`)
    or numba cannot compile it."""
    if settings.device != "cpu":
        return None
    try:
        return FusedStepper(op, settings)
    except Unsupported:
        return None
    except Exception as exc:  # a model's code that fails on placeholders, or numba that cannot compile it
        import warnings

        warnings.warn(f"the step of {op.dynamics.name} could not be compiled pointwise ({type(exc).__name__}: "
                      f"{str(exc)[:200]}); continuing with the array code", RuntimeWarning)
        return None
