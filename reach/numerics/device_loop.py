"""The time loop of the ``torch.compile`` engine (a GPU's) without a host synchronisation per step.

:func:`softreach.reach.numerics.solver.march` reads the CFL speed on the host at every step to choose the step; on a GPU that
read waits for the whole step to finish, and the host then launches the next one into an idle device. Here the step
and its own length are one compiled function of tensors (:func:`whole_step`): the time ``t`` lives on the device, the
step ``dt = remaining / ceil(remaining / (cfl / speed))`` (the host loop's rule, in float64) is computed there, and
a step at ``t = target`` has ``dt = 0`` and leaves the value as it is (the projection is idempotent). The host runs as
many steps as the first speed asks without looking, then reads ``t`` once to see whether more are needed (a speed
that grows as the value steepens asks for a few more). A non-finite speed is remembered on the device and raised at
that read.
"""

from __future__ import annotations

import math
from typing import Any, Callable

from .. import backend as B


def whole_step(op: Any, order: int, cfl: float, u: Any, t: Any, target: Any, tol: Any, bad: Any
               ) -> tuple[Any, Any, Any]:
    """One CFL-limited step of ``u`` from the device time ``t`` towards ``target`` (0-d float64 tensors), as
    :func:`~softreach.reach.numerics.solver.march` chooses it; ``(u, t - dt, bad or the speed was not finite)``.

    :param tol: ``t - target`` below which no step is taken (the host loop's stopping rule)
    """
    from .solver import tvd_rk_step

    torch = B.torch
    r, speed = op.rate_lazy(0.0, u)
    speed = torch.as_tensor(speed, dtype=torch.float64, device=u.device)
    remaining = t - target
    steps = torch.clamp(torch.ceil(remaining / (cfl / speed) - 1e-9), min=1.0)
    dt = torch.where(remaining > tol, remaining / steps, torch.zeros_like(remaining))
    u = tvd_rk_step(op, 0.0, u, dt.to(u.dtype), order, first_rate=r)
    return u, t - dt, bad | ~torch.isfinite(speed)


def march_on_device(step: Any, cfl: float, t: float, u: Any, target: float, progress: Any = None) -> Any:
    """:func:`~softreach.reach.numerics.solver.march` with the compiled :func:`whole_step` ``step(u, t, target, tol, bad)``:
    the host reads the device (one synchronisation) only after each batch of steps."""
    torch = B.torch
    f64 = dict(dtype=torch.float64, device=u.device)
    state = {"u": u, "t": torch.tensor(t, **f64), "bad": torch.zeros((), dtype=torch.bool, device=u.device)}
    stop, tol = torch.tensor(target, **f64), torch.tensor(1e-12 * max(1.0, abs(target)), **f64)

    def advance(steps: int) -> tuple[float, bool]:
        for _ in range(steps):
            state["u"], state["t"], state["bad"] = step(state["u"], state["t"], stop, tol, state["bad"])
        return float(state["t"]), bool(state["bad"])  # the one synchronisation of a batch

    march_in_batches(advance, t, target, progress)
    return state["u"]


def march_in_batches(advance: Callable[[int], tuple[float, bool]], t: float, target: float,
                     progress: Any = None) -> None:
    """Run steps that choose their own length on the device, in batches, until the device time reaches ``target``.

    :param advance: ``advance(n)`` launches ``n`` steps and returns the device time after them and whether a speed
        was not finite: the one read of the device per batch
    :param t: the time the value is at
    :param progress: optional object with ``update(seconds_of_model_time)``
    :raises FloatingPointError: a step's CFL speed was not finite
    """
    done_to = t
    batch = 1  # the first batch is one step, whose length sizes the next
    while True:
        now, failed = advance(batch)
        if failed:
            raise FloatingPointError(f"the dissipation speed is not finite between t = {done_to:.6g} and {now:.6g}: "
                                     f"the value or the model's dissipation is not finite (a NaN in the table or "
                                     f"an unbounded f)")
        if progress is not None:
            progress.update(max(0.0, min(done_to - now, (progress.total or math.inf) - progress.n)))
        if now - target <= 1e-12 * max(1.0, abs(target)):
            return
        # the steps so far predict the rest: a speed that does not change needs exactly this many
        per_step = (done_to - now) / batch
        batch = max(1, math.ceil((now - target) / per_step - 1e-9)) if per_step > 0 else 1
        done_to = now
