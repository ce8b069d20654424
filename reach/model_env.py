"""What an environment reads of a model beside its dynamics and sets: a group of its own (``docs/models.md``,
section 3, "What the environment needs").

The control period and the sub-steps at whose ends an episode checks ``C1`` and landing, and where episodes start.
:class:`~softreach.reach.problem.Model` is an :class:`EnvPart`; "reached" is its
:meth:`~softreach.reach.problem.Model.landed`.
"""

from __future__ import annotations

from .boxes import box_check, check_start_budget


class EnvPart:
    """The part of a model the environments read; see the module docstring."""

    #: the declared boxes and ranges this part checks where they are set (:class:`~softreach.reach.dynamics.Dynamics`)
    _CHECKS = {"start_box": box_check("start_box", states=True, optional=True), "start_budget": check_start_budget}

    #: the environment's control period [s] (``None``: no sampled-data game), and its RK4 sub-steps per period,
    #: whose ends are where an episode checks landing and ``C1``
    control_period: float | None = None
    substeps: int = 1
    #: the box the environment draws start states from, uniformly (``None``: the env must be given one)
    start_box: tuple[tuple[float, ...], tuple[float, ...]] | None = None
    #: the budget ``Q`` [s] of an episode, or a ``(low, high)`` range the environment draws it from
    start_budget: float | tuple[float, float] = 0.0
