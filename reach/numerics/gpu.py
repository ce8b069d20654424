"""The solver's time step on a GPU as a few CUDA kernels per Runge-Kutta stage (numba-cuda), with no host
synchronisation inside a step.

Why CUDA kernels written from the recorded node code, and not ``torch.compile``: the step's arithmetic is already
recorded as straight-line code per node for the CPU loops (:mod:`softreach.reach.numerics.fused`: the derivative
scheme, the model's numerical Hamiltonian, the projection, the stages, the ghost rule). The same lines compiled by
numba-cuda give one kernel for the rate of a stage, one for the stage value and one for the ghost layers, compiled
once per model, scheme and float type and cached on disk beside the CPU loops' source, where ``torch.compile``
re-traces the whole step in every process.

A step of ``k`` stages is ``3 k + 1`` launches and no read by the host:

1. ``rate_all`` (stage 0): the rate at every node and, reduced per block and then by one atomic maximum, the CFL
   speed into ``speed[0]``; a non-finite rate or speed makes the speed infinite.
2. ``clock``: one thread takes the step's length by the host loop's rule
   (:func:`softreach.reach.numerics.solver.march`, float64:
   ``dt = remaining / max(1, ceil(remaining / (cfl / speed) - 1e-9))``, ``dt = 0`` once ``t`` is within ``tol`` of
   the target), moves the device time ``t`` and resets ``speed``; an infinite speed sets ``bad``.
3. per stage: ``rate_all`` (stages after the first, speed into a slot nobody reads), ``stage_<k>`` (the projected
   stage value into the padded copy and, at the last stage, into the value) and ``ghosts`` (every axis's ghost
   layers, one kernel).

A step at ``t = target`` has ``dt = 0`` and leaves the value unchanged (the projection is idempotent), so the host
launches batches of steps blind and reads ``t`` and ``bad`` once per batch
(:func:`softreach.reach.numerics.device_loop.march_in_batches`).

The arrays are torch tensors on the device, handed to the kernels through ``__cuda_array_interface__`` (no copy);
torch and numba-cuda both launch on the device's default stream, so their work is ordered. Under numba-cuda's
simulator (``NUMBA_ENABLE_CUDASIM=1``) the same kernels run on the CPU on the tensors' numpy views: the tests check
the kernels there, without a GPU.
"""

from __future__ import annotations

import math
from typing import Any

import numpy as np

from .. import backend as B
from .derivatives import SCHEMES
from .fused import ghost_body, load_source, padded_index, parameter_array, rate_body, stage_body, stage_pairs
from .trace import Unsupported

#: threads per block of every kernel (a power of two: the speed's reduction halves it); the simulator runs each
#: thread of a block as a Python thread, and gets :data:`SIMULATED_BLOCK`
BLOCK = 256
SIMULATED_BLOCK = 32
#: blocks per multiprocessor of the grid-stride kernels: enough resident warps to hide memory latency
BLOCKS_PER_SM = 16

_HEADER = '''"""Written by softreach.reach.numerics.gpu; compiled by numba-cuda and cached beside this file."""
import math
import numpy as np
from numba import cuda
F = np.DTYPE
BLOCK = {block}
INF = F(np.inf)
_JIT = dict(cache=True)
'''

#: numpy functions of recorded lines, spelled as the ``math`` functions CUDA device code has
_CUDA_MATH = {"np.sin(": "math.sin(", "np.cos(": "math.cos(", "np.tan(": "math.tan(", "np.arcsin(": "math.asin(",
              "np.arccos(": "math.acos(", "np.arctan(": "math.atan(", "np.arctan2(": "math.atan2(",
              "np.exp(": "math.exp(", "np.log(": "math.log(", "np.sqrt(": "math.sqrt(", "np.tanh(": "math.tanh(",
              "np.hypot(": "math.hypot("}


def _cuda_line(line: str) -> str:
    for a, b in _CUDA_MATH.items():
        line = line.replace(a, b)
    return line


def _node_index(D: int, flat: str, shape: str = "n", skip: int | None = None, pad: str = "        ") -> list[str]:
    """Lines that split the flat index ``flat`` into ``i0, i1, ...`` (the last axis fastest), leaving out ``skip``."""
    axes = [b for b in range(D) if b != skip]
    if not axes:
        return []
    lines = [f"{pad}rest = {flat}"]
    for b in reversed(axes[1:]):
        lines += [f"{pad}i{b} = rest % {shape}{b}", f"{pad}rest = rest // {shape}{b}"]
    return lines + [f"{pad}i{axes[0]} = rest"]


def _rate_kernel(op: Any, width: int) -> list[str]:
    D = op.grid.ndim
    body, out, speed = rate_body(op, width)
    xs = ", ".join(f"x{a}" for a in range(D))
    node = ", ".join(f"i{b}" for b in range(D))
    src = ["@cuda.jit(**_JIT)", f"def rate_all(up, out, {xs}, inv, h, t, params, speed, slot):", f"    W = {width}"]
    src += [f"    n{a} = out.shape[{a}]" for a in range(D)]
    src += [f"    inv{a} = inv[{a}]" for a in range(D)] + [f"    h{a} = h[{a}]" for a in range(D)]
    src += ["    top = F(0.0)", "    k = cuda.grid(1)", "    while k < out.size:"]
    src += _node_index(D, "k")
    src += [f"        x{a}v = x{a}[i{a}]" for a in range(D)]
    src += ["        " + _cuda_line(line) for line in body]
    src += [f"        h_out = {_cuda_line(out)}", f"        out[{node}] = h_out", f"        s = {_cuda_line(speed)}",
            "        if not (abs(h_out) < INF and s < INF):",  # NaN or infinite: the host is told through the speed
            "            s = INF",
            "        top = max(top, s)",
            "        k += cuda.gridsize(1)"]
    src += ["    best = cuda.shared.array(BLOCK, F)", "    tid = cuda.threadIdx.x", "    best[tid] = top",
            "    cuda.syncthreads()", "    half = BLOCK // 2", "    while half > 0:", "        if tid < half:",
            "            best[tid] = max(best[tid], best[tid + half])", "        cuda.syncthreads()",
            "        half //= 2", "    if tid == 0:", "        cuda.atomic.max(speed, slot, best[0])"]
    return src


def _stage_kernels(op: Any, width: int) -> tuple[list[str], dict[tuple[float, float], str]]:
    D = op.grid.ndim
    node = ", ".join(f"i{b}" for b in range(D))
    inner = padded_index(D, None, "", " + W")
    src, names = [], {}
    for k, (a, b) in enumerate(stage_pairs()):
        lines, v = stage_body(a, b)
        names[(a, b)] = f"stage_{k}"
        src += ["@cuda.jit(**_JIT)", f"def stage_{k}(u, up, r, l, c, step, write_u):", f"    W = {width}"]
        src += [f"    n{d} = u.shape[{d}]" for d in range(D)]
        src += ["    dt = F(step[0])", "    k = cuda.grid(1)", "    while k < u.size:"]
        src += _node_index(D, "k")
        src += [f"        uv = u[{node}]", f"        pv = up[{inner}]", f"        rv = r[{node}]",
                f"        lv = l[{node}]", f"        cv = c[{node}]"]
        src += ["        " + _cuda_line(line) for line in lines]
        src += [f"        v = {_cuda_line(v)}", f"        up[{inner}] = v", "        if write_u:",
                f"            u[{node}] = v", "        k += cuda.gridsize(1)"]
    return src, names


def _ghost_kernel(op: Any, width: int) -> list[str]:
    """``ghosts(up)``: the ghost layers of every axis at the other axes' inner nodes, one line of nodes a thread
    (:func:`~softreach.reach.numerics.derivatives.pad`; corners are never read by the one-axis stencils)."""
    D = op.grid.ndim
    src = ["@cuda.jit(**_JIT)", "def ghosts(up):", f"    W = {width}"]
    src += [f"    n{d} = up.shape[{d}] - 2 * W" for d in range(D)]
    src += ["    k = cuda.grid(1)"]
    start = "0"
    for a in range(D):
        count = " * ".join(f"n{d}" for d in range(D) if d != a) or "1"
        src += [f"    lines{a} = {count}", f"    while k < {start} + lines{a}:"]
        src += _node_index(D, f"k - ({start})", skip=a)
        at = lambda e, a=a: f"up[{padded_index(D, a, e, ' + W')}]"  # noqa: E731
        n, rule = f"n{a}", op.boundaries[a]
        if rule == "periodic":
            for g in range(width):
                src += [f"        {at(str(g))} = {at(f'{g} + {n}')}", f"        {at(f'{n} + W + {g}')} = {at(f'W + {g}')}"]
        else:
            lo_rule, hi_rule = (rule, rule) if isinstance(rule, str) else rule
            for end, r, edge, inside, place in (("lo", lo_rule, "W", "W + 1", "W - {k}"),
                                                ("hi", hi_rule, f"{n} + W - 1", f"{n} + W - 2", f"{n} + W - 1 + {{k}}")):
                lines, values = ghost_body(r, end, width)
                src += [f"        e_{end} = {at(edge)}", f"        i_{end} = {at(inside)}"]
                src += ["        " + _cuda_line(line) for line in lines]
                src += [f"        {at(place.format(k=k))} = {_cuda_line(v)}" for k, v in enumerate(values, start=1)]
        src += ["        k += cuda.gridsize(1)"]
        # the grid-stride index goes on past this axis's lines into the next axis's
        start = f"{start} + lines{a}"
    return src


_CLOCK = '''
@cuda.jit(**_JIT)
def clock(speed, t, target, tol, cfl, step, bad):
    """The step's length on the device, by the host loop's rule (softreach.reach.numerics.solver.march)."""
    if cuda.grid(1) != 0:
        return
    s = np.float64(speed[0])
    speed[0] = F(0.0)
    remaining = t[0] - target[0]
    dt = 0.0
    if not (s < math.inf):
        bad[0] = 1
    elif remaining > tol[0]:
        steps = 1.0
        if s > 0.0:
            steps = max(1.0, math.ceil(remaining / (cfl / s) - 1e-9))
        dt = remaining / steps
    step[0] = dt
    t[0] = t[0] - dt
'''


def kernel_source(op: Any, dtype: str) -> str:
    """The CUDA kernels of ``op``'s step as Python source for numba-cuda.

    :raises Unsupported: the model's code does something a pointwise kernel cannot
    """
    width = SCHEMES[op.settings.scheme][0]
    src = [_HEADER.replace("DTYPE", dtype).format(block=_block())]
    src += _rate_kernel(op, width) + _stage_kernels(op, width)[0] + _ghost_kernel(op, width) + [_CLOCK]
    return "\n".join(src) + "\n"


def load_kernels(op: Any, dtype: str) -> Any:
    """The module of ``op``'s kernels, kept beside the CPU loops (:func:`~softreach.reach.numerics.fused.load_source`;
    numba-cuda caches the compiled kernels beside it)."""
    return load_source(kernel_source(op, dtype), "softreach_cuda_")


def _block() -> int:
    return SIMULATED_BLOCK if simulated() else BLOCK


def simulated() -> bool:
    """Whether numba-cuda runs its CPU simulator (``NUMBA_ENABLE_CUDASIM=1``) in this process."""
    from numba import config

    return bool(config.ENABLE_CUDASIM)


class CudaStepper:
    """Marches the value on the GPU with the kernels of :func:`kernel_source` (module docstring); the value, its
    padded copy, the rate and the obstacles live in torch tensors on the device between steps.

    :param op: the problem's operator (time-invariant: the kernels see ``t = 0``)
    :param settings: the solver's settings (scheme, order, CFL number, float type, device)
    """

    def __init__(self, op: Any, settings: Any):
        from numba import cuda

        from .solver import RK_STAGES

        self.op, self.settings, self.cuda = op, settings, cuda
        self.kernels = load_kernels(op, settings.dtype)
        torch = B.torch
        w = SCHEMES[settings.scheme][0]
        shape = op.grid.shape
        device = torch.device(settings.device)
        if device.type != "cuda" and not simulated():
            raise ValueError(f"the CUDA kernels run on a GPU (or numba-cuda's simulator), not on {settings.device!r}")
        f = dict(dtype=getattr(torch, settings.dtype), device=device)
        f64 = dict(dtype=torch.float64, device=device)
        self.u = torch.zeros(shape, **f)
        self.up = torch.zeros(tuple(n + 2 * w for n in shape), **f)
        self.r = torch.zeros(shape, **f)
        l, c = op._sets(0.0)
        self.l, self.c = (B.asarray(v, "torch", settings.dtype, str(device)).expand(shape).contiguous() for v in (l, c))
        self.xs = [B.asarray(x, "torch", settings.dtype, str(device)).reshape(-1).contiguous() for x in op.x]
        self.h = torch.tensor(op.dx, **f)
        self.inv = torch.tensor([1.0 / d for d in op.dx], **f)
        self.params = torch.from_numpy(parameter_array(op.dynamics, np.dtype(settings.dtype))).to(device)
        self.speed = torch.zeros(2, **f)  # [0]: the first stage's CFL speed; [1]: the other stages', never read
        self.t, self.target, self.tol, self.dt = (torch.zeros(1, **f64) for _ in range(4))
        self.bad = torch.zeros(1, dtype=torch.int32, device=device)
        self.t0 = np.dtype(settings.dtype).type(0.0)
        sms = torch.cuda.get_device_properties(device).multi_processor_count if device.type == "cuda" else 1
        block = _block()
        self.blocks = max(1, min(math.ceil(op.grid.size / block), sms * BLOCKS_PER_SM))
        lines = sum(math.prod(n for d, n in enumerate(shape) if d != a) for a in range(len(shape)))
        ghost_blocks = max(1, min(math.ceil(lines / block), sms * BLOCKS_PER_SM))
        k = self.kernels
        self._rate = k.rate_all[self.blocks, block]
        self._ghosts = k.ghosts[ghost_blocks, block]
        self._clock = k.clock[1, 1]
        names = {pair: f"stage_{i}" for i, pair in enumerate(stage_pairs())}
        table = RK_STAGES[settings.time_order]
        self._stages = [getattr(k, names[(a, b)])[self.blocks, block] for a, b, _ in table]
        d = self._device
        self._rate_args = (d(self.up), d(self.r), *map(d, self.xs), d(self.inv), d(self.h), self.t0, d(self.params),
                           d(self.speed))
        self._stage_args = tuple(map(d, (self.u, self.up, self.r, self.l, self.c, self.dt)))
        self._clock_args = (d(self.speed), d(self.t), d(self.target), d(self.tol), float(settings.cfl), d(self.dt),
                            d(self.bad))
        self._up = d(self.up)
        #: kernel launches so far (the tests count them per step)
        self.launches = 0

    def _device(self, x: Any) -> Any:
        """``x`` as the kernels take it: a view of the tensor's device memory (or, simulated, of its numpy memory)."""
        return self.cuda.as_cuda_array(x) if x.is_cuda else x.numpy()

    def _load(self, u: Any) -> None:
        w = SCHEMES[self.settings.scheme][0]
        self.u.copy_(B.asarray(u, "torch", self.settings.dtype, str(self.u.device)))
        self.up[tuple(slice(w, -w) for _ in self.u.shape)] = self.u
        self._ghosts(self._up)
        self.launches += 1

    def step(self) -> None:
        """One CFL-limited step from the device time ``t`` towards ``target`` (module docstring), launched only."""
        self._rate(*self._rate_args, 0)
        self._clock(*self._clock_args)
        last = len(self._stages) - 1
        for i, stage in enumerate(self._stages):
            if i:
                self._rate(*self._rate_args, 1)
            stage(*self._stage_args, i == last)
            self._ghosts(self._up)
        self.launches += 3 * len(self._stages) + 1

    def march(self, t: float, u: Any, target: float, progress: Any = None) -> Any:
        """:func:`~softreach.reach.numerics.solver.march` on the device: ``u`` at ``t`` stepped back to ``target``."""
        from .device_loop import march_in_batches

        self._load(u)
        self.params.copy_(B.torch.from_numpy(parameter_array(self.op.dynamics, np.dtype(self.settings.dtype))))
        self.t.fill_(t)
        self.target.fill_(target)
        self.tol.fill_(1e-12 * max(1.0, abs(target)))
        self.bad.zero_()
        self.speed.zero_()

        def advance(steps: int) -> tuple[float, bool]:
            for _ in range(steps):
                self.step()
            return float(self.t[0]), bool(self.bad[0])  # the one synchronisation of a batch

        march_in_batches(advance, t, target, progress)
        return self.u.clone()


def cuda_stepper(op: Any, settings: Any, required: bool = False) -> CudaStepper | None:
    """A :class:`CudaStepper` whose kernels compiled and ran once, or ``None`` (with a warning where something was
    tried) where numba-cuda, a GPU or a pointwise form of the model's step is missing.

    :param required: raise instead of returning ``None``
    """
    try:
        from numba import cuda

        if not (simulated() or cuda.is_available()):
            raise RuntimeError("numba-cuda sees no GPU")
        if not op.time_invariant:
            raise Unsupported("a time-varying problem (the kernels see t = 0)")
        stepper = CudaStepper(op, settings)
        stepper.march(1.0, stepper.u, 1.0)  # compiles and runs every kernel once: a failure shows here, not later
        return stepper
    except Exception as exc:
        if required:
            raise
        if not isinstance(exc, (ImportError, Unsupported)):
            import warnings

            warnings.warn(f"the CUDA kernels of {op.dynamics.name}'s step are not used ({type(exc).__name__}: "
                          f"{str(exc)[:300]}); continuing with torch.compile", RuntimeWarning)
        return None
