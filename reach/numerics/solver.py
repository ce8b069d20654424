"""Time-marching solver for reach-avoid Hamilton-Jacobi-Isaacs variational inequalities.

The value of a reach-avoid game with target function ``l`` and constraint ``c`` solves (backwards from ``T``)

    0 = max{ c - W,  min[ l - W,  W_t + H(t, x, grad W) ] },   W(T) = max(c, l).

With ``tau = T - t`` this is ``W_tau = H`` followed, after every Runge-Kutta stage, by the projection
``W <- max(c, min(l, W))``. ``H`` is approximated by the Lax-Friedrichs numerical Hamiltonian

    H(x, (p- + p+)/2) + sum_i alpha_i (p+_i - p-_i) / 2

(the ``+`` sign is the backward-time form), with ``alpha_i >= |dH/dp_i|`` from the dynamics, globally or per node
and co-state box ("local"). A direction that no input enters gets ``alpha_i = |f_i|``, which is exact upwinding.

Where ``H`` is **separable**, ``H(t, x, p) = H(t, x, 0) + sum_i H_i(p_i)`` (every input and disturbance enters one
state equation, as in the point mass), the Godunov numerical Hamiltonian is used instead ("godunov"; "auto" picks
it where the model's Hamiltonian is separable). ``H_i`` is positively homogeneous, so it is the line
``p H(e_i)`` for ``p > 0`` and ``-p H(-e_i)`` for ``p < 0``, read off the model's own Hamiltonian, and

    H_G = H(t, x, 0) + sum_i ext_i,   ext_i = max of H_i over [p-_i, p+_i] if p-_i <= p+_i, else min over [p+_i, p-_i]

(the backward-time form of Godunov's flux; for a separable ``H`` the extrema separate). It is monotone under the
same CFL bound and consistent (Bardi and Osher 1991; Osher and Shu 1991), and it adds no viscosity where the
optimal motion is at rest along an axis: a run that rides a constraint boundary (``v`` held at the soft limit) sees
``p-_i < 0 < p+_i`` and ``H_i = 0``, where Lax-Friedrichs adds ``alpha_i (p+_i - p-_i) / 2`` at every step.
"""

from __future__ import annotations

import math
import os
from dataclasses import asdict, dataclass
from typing import Any, Callable, Sequence

from .. import backend as B
from .derivatives import SCHEMES, upwind_derivatives
from .godunov import godunov_hamiltonian, separable  # noqa: F401 - part of this module's interface
from .grid import Grid
from ..problem import ReachAvoidProblem

Array = B.Array

#: ``--accuracy`` presets, named as in hj_reachability so that benchmarks compare like with like
ACCURACY: dict[str, tuple[str, int]] = {
    "low": ("first", 1),
    "medium": ("eno2", 2),
    "high": ("weno3", 3),
    "very_high": ("weno5", 3),
}


#: numerical Hamiltonians (``SolverSettings.dissipation``)
DISSIPATION = ("local", "global", "godunov", "auto")


@dataclass(frozen=True)
class SolverSettings:
    """Numerical settings.

    :param scheme: spatial derivative scheme (``first``, ``eno2``, ``weno3``, ``weno5``)
    :param time_order: order of the TVD Runge-Kutta scheme (1, 2 or 3)
    :param cfl: Courant number; the step is ``cfl / max sum_i alpha_i / dx_i``
    :param dissipation: ``"local"`` (per node and co-state box) or ``"global"`` Lax-Friedrichs, ``"godunov"``
        (the Godunov flux; the model's Hamiltonian must be separable, see the module docstring), or ``"auto"``:
        Godunov where the Hamiltonian is separable, local Lax-Friedrichs otherwise
    :param boundary: ghost-node rule at non-periodic ends (see :func:`softreach.reach.numerics.derivatives.pad`)
    :param backend: ``"torch"`` or ``"numpy"``
    :param device: torch device (``"cpu"``, ``"cuda"``, ``"cuda:1"``)
    :param dtype: ``"float32"`` or ``"float64"`` for the computation (tables store float32)
    :param compile: compiled time steps: on a CPU the loops of :mod:`softreach.reach.numerics.fused` (numba; compiled once
        per model and scheme, a few seconds, and cached on disk), elsewhere ``torch.compile`` with the step's length
        computed on the device (:mod:`softreach.reach.numerics.device_loop`); ``None`` compiles grids of
        :data:`FUSED_MIN_NODES` nodes or more on a CPU, 90,000 elsewhere; ``False`` runs the array code
    """

    scheme: str = "weno5"
    time_order: int = 3
    cfl: float = 0.75
    dissipation: str = "local"
    boundary: str = "extrapolate_away"
    backend: str = "torch"
    device: str = "cpu"
    dtype: str = "float64"
    compile: bool | None = None

    def __post_init__(self):
        if self.scheme not in SCHEMES:
            raise ValueError(f"unknown scheme {self.scheme!r}; choose from {sorted(SCHEMES)}")
        if self.time_order not in (1, 2, 3):
            raise ValueError(f"time_order must be 1, 2 or 3, got {self.time_order!r}")
        if not (isinstance(self.cfl, (int, float)) and 0 < self.cfl <= 1):
            raise ValueError(f"cfl must be in (0, 1], got {self.cfl!r}")
        if self.dissipation not in DISSIPATION:
            raise ValueError(f"dissipation must be one of {DISSIPATION}, got {self.dissipation!r}")
        B.resolve_dtype(self.backend, self.dtype)
        if self.backend == "numpy" and self.device != "cpu":
            raise ValueError(f"the numpy backend runs on the CPU only; got device={self.device!r}")
        if self.backend == "torch" and str(self.device).startswith("cuda"):
            if not B.torch.cuda.is_available():
                raise RuntimeError(f"device={self.device!r} was requested but torch sees no CUDA device")

    @classmethod
    def from_accuracy(cls, accuracy: str, **overrides: Any) -> "SolverSettings":
        """Settings for an accuracy preset (``low``, ``medium``, ``high``, ``very_high``)."""
        try:
            scheme, order = ACCURACY[accuracy]
        except KeyError:
            raise ValueError(f"unknown accuracy {accuracy!r}; choose from {list(ACCURACY)}") from None
        return cls(scheme=scheme, time_order=order, **overrides)

    def to_dict(self) -> dict[str, Any]:
        return asdict(self)


class HamiltonianOperator:
    """The right-hand side ``W_tau = H_hat`` of one problem on one grid, plus the projection onto the VI."""

    def __init__(self, problem: ReachAvoidProblem, grid: Grid, settings: SolverSettings):
        if grid.ndim != problem.dynamics.state_dim:
            raise ValueError(f"grid has {grid.ndim} axes but {problem.dynamics.name} has {problem.dynamics.state_dim} states")
        self.problem, self.grid, self.settings = problem, grid, settings
        self.dynamics = problem.dynamics
        self.x = grid.coordinates(settings.backend, settings.dtype, settings.device)
        self.dx = grid.spacing
        self.boundaries = problem.boundaries(grid.periodic, settings.boundary)
        self.time_invariant = problem.model.time_invariant
        self._sets_at: float | None = None
        self._sets(0.0)
        split = settings.dissipation in ("godunov", "auto") and separable(
            self.dynamics, grid.coordinates("numpy", "float64", "cpu"))
        self.godunov = split
        if settings.dissipation == "godunov" and not split:
            raise ValueError(f"dissipation='godunov' needs a separable Hamiltonian (every input entering one state "
                             f"equation); {self.dynamics.name}'s is not: use 'local' or 'auto'")

    def _sets(self, t: float) -> tuple[Array, Array]:
        if self._sets_at is None or not self.time_invariant:
            full = self.x[0] * 0
            for xi in self.x[1:]:
                full = full + xi * 0
            self.l = self.problem.target_function(t, self.x) + full
            self.c = self.problem.constraint_function(t, self.x) + full
            floor = self.problem.floor_function(t, self.x)
            # max(c, floor) is one obstacle: both bound the value from below
            self.c = self.c if floor is None else B.maximum(self.c, floor + full)
            self._sets_at = t
        return self.l, self.c

    def terminal(self, t: float) -> Array:
        """``W(T) = max(c, l)`` (``c`` for a game without a target)."""
        l, c = self._sets(t)
        return B.maximum(c, l) if self.problem.has_target else c

    def project(self, t: float, u: Array) -> Array:
        """``max(c, min(l, u))``: the obstacles of the variational inequality."""
        l, c = self._sets(t)
        return project_values(l, c, u)

    def rate(self, t: float, u: Array) -> tuple[Array, float]:
        """``(H_hat, max_x sum_i alpha_i / dx_i)`` for the value ``u`` at time ``t``."""
        out, speed = self.rate_lazy(t, u)
        return out, B.max_value(speed)

    def rate_lazy(self, t: float, u: Array) -> tuple[Array, Any]:
        """:meth:`rate` with the speed left as an array (no device synchronisation, no graph break)."""
        s = self.settings
        lefts, rights = [], []
        for i in range(self.grid.ndim):
            dm, dp = upwind_derivatives(u, i, self.dx[i], s.scheme, self.boundaries[i])
            lefts.append(dm)
            rights.append(dp)
        out, speed = self.numerical_hamiltonian(t, self.x, self.dx, lefts, rights)
        if hasattr(speed, "shape"):
            speed = speed.max()
        return out, speed

    def numerical_hamiltonian(self, t: Any, x: Sequence[Array], dx: Sequence[Any], lefts: Sequence[Array],
                              rights: Sequence[Array]) -> tuple[Array, Any]:
        """``(H_hat, sum_i alpha_i / dx_i)`` at every node from the one-sided derivatives ``lefts`` (``p-``) and
        ``rights`` (``p+``): pointwise, so that :mod:`softreach.reach.numerics.fused` compiles it node by node."""
        if self.godunov:
            return godunov_hamiltonian(self.dynamics, t, x, dx, lefts, rights)
        p = [0.5 * (a + b) for a, b in zip(lefts, rights)]
        out = self.dynamics.hamiltonian(t, x, p)
        if self.settings.dissipation == "local":
            p_lo = [B.minimum(a, b) for a, b in zip(lefts, rights)]
            p_hi = [B.maximum(a, b) for a, b in zip(lefts, rights)]
            alpha = self.dynamics.dissipation(t, x, p_lo, p_hi)
        else:
            alpha = self.dynamics.dissipation(t, x, None, None)
        speed: Any = 0.0
        for i in range(len(x)):
            out = out + (0.5 * alpha[i]) * (rights[i] - lefts[i])
            speed = speed + alpha[i] / dx[i]
        return out, speed


def project_values(l: Array, c: Array, u: Array) -> Array:
    """``max(c, min(l, u))``: the value projected onto the obstacles ``l`` (target) and ``c`` (constraint)."""
    return B.maximum(c, B.minimum(l, u))


#: the TVD Runge-Kutta schemes of Shu and Osher, stage by stage: ``(a, b, c)`` makes the stage value
#: ``u_k = P(t - c dt, a u + b (u_k-1 + dt rate(u_k-1)))`` from the step's start ``u = u_0``, with ``P`` the
#: projection and the rate taken at the previous stage's time (``t`` for the first)
RK_STAGES: dict[int, tuple[tuple[float, float, float], ...]] = {
    1: ((0.0, 1.0, 1.0),),
    2: ((0.0, 1.0, 1.0), (0.5, 0.5, 1.0)),
    3: ((0.0, 1.0, 1.0), (0.75, 0.25, 0.5), (1.0 / 3.0, 2.0 / 3.0, 1.0)),
}


def stage_value(a: float, b: float, u: Array, prev: Array, dt: Any, rate: Array) -> Array:
    """``a u + b (prev + dt rate)``, the unprojected value of a stage of :data:`RK_STAGES` (a zero ``a`` and a
    unit ``b`` are left out, not multiplied)."""
    moved = prev + dt * rate
    moved = moved if b == 1.0 else b * moved
    return moved if a == 0.0 else a * u + moved


def tvd_rk_step(op: HamiltonianOperator, t: float, u: Array, dt: float, order: int, first_rate: Array | None = None,
                rate: Callable[[float, Array], Array] | None = None) -> Array:
    """One backward step ``t -> t - dt`` of the TVD Runge-Kutta scheme of Shu & Osher (:data:`RK_STAGES`),
    projected after each stage.

    :param rate: ``(t, u) -> du/dt`` in place of ``op.rate_lazy`` (a compiled one)
    """
    rate = rate or (lambda s, v: op.rate_lazy(s, v)[0])
    prev, before = u, 0.0
    for k, (a, b, c) in enumerate(RK_STAGES[order]):
        r = first_rate if (k == 0 and first_rate is not None) else rate(t - before * dt, prev)
        prev, before = op.project(t - c * dt, stage_value(a, b, u, prev, dt, r)), c
    return prev


SnapshotSink = Callable[[int, float, Array], None]


def solve(
    problem: ReachAvoidProblem,
    grid: Grid,
    times: Sequence[float],
    settings: SolverSettings | None = None,
    *,
    sink: SnapshotSink | None = None,
    start: tuple[int, Array] | None = None,
    progress: Any = None,
) -> Array:
    """March the value backwards from ``times[-1]`` to ``times[0]``.

    :param problem: the reach-avoid problem (classical or soft)
    :param grid: the grid over the problem's state (augmented with ``z`` for a soft problem)
    :param times: increasing output times; ``times[-1]`` is the terminal time ``T``. Steps are shortened so as
        to land exactly on every one of them.
    :param settings: numerical settings
    :param sink: called as ``sink(k, times[k], value)`` for every output time, ``k`` from last to first
    :param start: ``(k, value at times[k])`` to resume from instead of the terminal condition
    :param progress: optional object with ``update(seconds_of_model_time)`` (e.g. a tqdm bar)
    :return: the value at ``times[0]``
    """
    settings = settings or SolverSettings()
    times = output_times(times)
    op = HamiltonianOperator(problem, grid, settings)
    stepper = Stepper(op, settings)
    k0, u = initial_value(op, times, start, sink)
    t = times[k0]
    for k in range(k0 - 1, -1, -1):
        u = march(stepper, t, u, times[k], progress)
        t = times[k]
        if sink is not None:
            sink(k, t, u)
    return u


def output_times(times: Sequence[float]) -> list[float]:
    """``times`` as floats, checked: finite, strictly increasing, at least two."""
    times = [float(t) for t in times]
    if len(times) < 2 or any(not math.isfinite(t) for t in times) or any(b <= a for a, b in zip(times, times[1:])):
        raise ValueError(f"times must be finite and strictly increasing with at least two entries, got {times!r}")
    return times


def initial_value(op: HamiltonianOperator, times: list[float], start: tuple[int, Array] | None,
                  sink: SnapshotSink | None) -> tuple[int, Array]:
    """``(k, value)`` to march from: the terminal condition at ``times[-1]`` (handed to ``sink``), or ``start``."""
    settings = op.settings
    if start is None:
        k0, u = len(times) - 1, op.terminal(times[-1])
        if sink is not None:
            sink(k0, times[k0], u)
        return k0, u
    k0, u = start
    u = B.asarray(u, settings.backend, settings.dtype, settings.device)
    if tuple(u.shape) != op.grid.shape:
        raise ValueError(f"resume value has shape {tuple(u.shape)}, the grid {op.grid.shape}")
    return k0, u


def march(stepper: "Stepper", t: float, u: Array, target: float, progress: Any = None) -> Array:
    """Step ``u`` from time ``t`` back to ``target < t`` with CFL-limited steps that land exactly on ``target``.

    The one time-integration loop of the solver: the continuous solve and every sub-solve of the sampled-data
    game (:mod:`softreach.reach.numerics.held`) run it.
    """
    if stepper.cuda is not None:
        return stepper.cuda.march(t, u, target, progress)
    if stepper.compiled and DEVICE_LOOP:
        from .device_loop import march_on_device

        return march_on_device(stepper.whole, stepper.settings.cfl, t, u, target, progress)
    while t - target > 1e-12 * max(1.0, abs(target)):
        rate, speed = stepper.rate(t, u)
        if not math.isfinite(speed):
            raise FloatingPointError(f"the dissipation speed is {speed} at t = {t:.6g}: the value or the model's "
                                     f"dissipation is not finite (a NaN in the table or an unbounded f)")
        remaining = t - target
        dt_max = stepper.settings.cfl / speed if speed > 0 else remaining
        steps = max(1, math.ceil(remaining / dt_max - 1e-9))
        dt = remaining / steps
        u = stepper.step(t, u, rate, dt)
        t -= dt
        if progress is not None:
            # clamp: summed float steps would overshoot the bar's total
            progress.update(max(0.0, min(dt, (progress.total or math.inf) - progress.n)))
    return stepper.done(u)


#: grids from this many nodes fuse the whole Runge-Kutta step into one compiled graph; smaller ones compile only the
#: rate and combine the stages eagerly: fusing the step costs compile time on a first run and gains per step only on
#: large grids (docs/budget_surface.md, "The first run on a machine", times both with the command)
FUSED_STEP_NODES = 250_000


#: the ``torch.compile`` engine marches with the step's length computed on the device
#: (:mod:`softreach.reach.numerics.device_loop`); ``False``: the host reads the speed at every step, as the other engines
DEVICE_LOOP = True
#: with ``compile=None``, grids from this many nodes run the compiled loops on a CPU (the point mass's default
#: ``V``, ``101 x 101``, among them): numba compiles them once per model and scheme (a few seconds) and keeps them
#: for every later process; smaller grids run the array code, fast enough there
FUSED_MIN_NODES = 10_000
#: the ways :class:`Stepper` runs a step: ``"fused"`` (compiled loops on a CPU, :mod:`softreach.reach.numerics.fused`),
#: ``"cuda"`` (CUDA kernels from the same node code, a GPU's, :mod:`softreach.reach.numerics.gpu`), ``"compile"``
#: (``torch.compile``: a GPU's where the CUDA kernels are not at hand), ``"eager"``
ENGINES = ("fused", "cuda", "compile", "eager")
#: what compiled code means on a CPU: ``"fused"``, or ``"compile"`` to run the GPU's ``torch.compile`` step there
#: (its tests do, so that it stays right between GPU measurements)
CPU_ENGINE = "fused"


class Stepper:
    """Runs :func:`tvd_rk_step`: on a CPU as compiled loops (:mod:`softreach.reach.numerics.fused`), on a GPU as CUDA kernels
    from the same node code (:mod:`softreach.reach.numerics.gpu`) or, where those are not at hand, fused by ``torch.compile``;
    else eagerly.

    A compiled graph must not see a changing Python float (it would recompile every step), so the ``torch.compile``
    path passes ``dt`` as a 0-d tensor and is used only for time-invariant problems, where ``t`` is irrelevant.

    :param engine: one of :data:`ENGINES`; ``None`` chooses: ``settings.compile`` (``None``: grids of
        :data:`FUSED_MIN_NODES` nodes or more on a CPU, 90,000 elsewhere) asks for compiled code, which is
        ``"fused"`` on a CPU where the model's code records pointwise and ``"compile"`` otherwise; on a GPU
        ``"cuda"`` wherever ``settings.compile`` is not ``False`` and the kernels compile
    """

    def __init__(self, op: HamiltonianOperator, settings: SolverSettings, engine: str | None = None):
        self.op, self.settings = op, settings
        if engine is not None and engine not in ENGINES:
            raise ValueError(f"engine must be one of {ENGINES}, got {engine!r}")
        want = settings.compile
        on_cpu = settings.device == "cpu" and CPU_ENGINE == "fused"
        if want is None:
            want = op.grid.size >= (FUSED_MIN_NODES if on_cpu else 90_000)
        self.fused = self.cuda = None
        # the CUDA kernels compile once per model and scheme and are cached on disk: any grid on a GPU takes them
        if engine == "cuda" or (engine is None and settings.compile is not False and settings.backend == "torch"
                                and str(settings.device).startswith("cuda")):
            from .gpu import cuda_stepper

            self.cuda = cuda_stepper(op, settings, required=engine == "cuda")
            if self.cuda is not None:
                self.engine, self.compiled = "cuda", False
                return
        if engine == "fused" or (engine is None and want and on_cpu):
            from .fused import fused_stepper

            self.fused = fused_stepper(op, settings)
            if self.fused is None and engine == "fused":
                raise ValueError(f"{op.dynamics.name}'s step cannot be compiled pointwise on {settings.device}")
        self.engine = "fused" if self.fused is not None else (
            engine or ("compile" if want and settings.backend == "torch" and op.time_invariant else "eager"))
        self.compiled = self.engine == "compile"
        if self.compiled:
            torch = B.torch
            t0 = 0.0
            # inductor's compiled graphs kept beside softreach's other caches, for every later process
            from .fused import kernel_dir

            os.environ.setdefault("TORCHINDUCTOR_CACHE_DIR", str(kernel_dir().parent / "inductor"))
            self._rate_c = torch.compile(lambda u: op.rate_lazy(t0, u), dynamic=False)
            self._step_c = None
            if op.grid.size >= FUSED_STEP_NODES:
                self._step_c = torch.compile(lambda u, r, dt: tvd_rk_step(op, t0, u, dt, settings.time_order, first_rate=r),
                                             dynamic=False)
            from .device_loop import whole_step

            #: the step with its own CFL length, on the device (:mod:`softreach.reach.numerics.device_loop`)
            self.whole = torch.compile(lambda u, t, stop, tol, bad: whole_step(op, settings.time_order, settings.cfl,
                                                                                u, t, stop, tol, bad), dynamic=False)

    def rate(self, t: float, u: Array) -> tuple[Array, float]:
        if self.fused is not None:
            return self.fused.rate(t, u)
        if self.compiled:
            try:
                r, s = self._rate_c(u)
                return r, B.max_value(s)
            except Exception as exc:  # no C++ compiler, unsupported platform...: eager still works
                self._fall_back(exc)
        return self.op.rate(t, u)

    def step(self, t: float, u: Array, rate: Array, dt: float) -> Array:
        if self.fused is not None:
            return self.fused.step(t, u, rate, dt)
        if self.compiled:
            try:
                if self._step_c is None:  # the stages eagerly, each rate compiled
                    return tvd_rk_step(self.op, t, u, dt, self.settings.time_order, first_rate=rate,
                                       rate=lambda s, v: self._rate_c(v)[0])
                return self._step_c(u, rate, B.torch.tensor(dt, dtype=u.dtype, device=u.device))
            except Exception as exc:
                self._fall_back(exc)
        return tvd_rk_step(self.op, t, u, dt, self.settings.time_order, first_rate=rate)

    def done(self, u: Array) -> Array:
        """``u`` as a value to keep: the fused stepper overwrites its own buffer at the next step."""
        return self.fused.done(u) if self.fused is not None else u

    def _fall_back(self, exc: Exception) -> None:
        import warnings

        warnings.warn(f"torch.compile failed ({type(exc).__name__}: {exc}); continuing without it", RuntimeWarning)
        self.compiled = False
        self.engine = "eager"
