"""A model's scalar fast path: its ``f``, ``h_eps``, ``c1`` and ``g`` at one point of Python floats.

A model may define scalar versions of these methods (``f_scalar``, ``violation_rate_scalar``,
``hard_constraint_scalar``, ``target_scalar``; the point mass does) that take one point of Python floats and
repeat the vectorised arithmetic without building arrays. The environments then use them for the RK4 stages and
the end-of-step checks (:func:`softreach.reach.sim.integrator.integrate_period`); the results are the same, bit for
bit (tests/test_envs_fastpath.py). Otherwise, or where a subclass overrides a vectorised method but not its
scalar version, the vectorised methods are used as they are.
"""

from __future__ import annotations

from collections.abc import Callable
from typing import NamedTuple

from ..problem import Model


class ScalarModel(NamedTuple):
    """A model's scalar fast paths, bound to the model: the same functions as its vectorised ``f``,
    ``violation_rate``, ``hard_constraint`` and ``target`` at one point given as Python floats (sequences of
    floats in, floats or a sequence of floats out), for the per-step work of the environments."""

    f: Callable
    violation_rate: Callable
    hard_constraint: Callable
    target: Callable


#: the scalar methods a model provides for the fast path, each with the vectorised methods it stands for
_SCALAR_METHODS = (
    ("f_scalar", ("f",)),
    ("violation_rate_scalar", ("violation_rate", "soft_constraint")),
    ("hard_constraint_scalar", ("hard_constraint",)),
    ("target_scalar", ("target",)),
)


def _owner(cls: type, name: str) -> type | None:
    for c in cls.__mro__:
        if name in c.__dict__:
            return c
    return None


def scalar_model(model: Model) -> ScalarModel | None:
    """The model's scalar fast path, or ``None`` (then the environments use the vectorised methods).

    A model opts in by defining ``f_scalar``, ``violation_rate_scalar``, ``hard_constraint_scalar`` and
    ``target_scalar``. A scalar method is used only where it is defined in the same class as the vectorised
    methods it stands for, or in a subclass of it: a subclass that overrides ``f`` (or replaces it on the
    instance) but not ``f_scalar`` falls back to the vectorised methods instead of silently ignoring the change.
    """
    cls = type(model)
    own = getattr(model, "__dict__", {})
    methods = []
    for fast, slows in _SCALAR_METHODS:
        owner = _owner(cls, fast)
        if owner is None or fast in own:
            return None
        for slow in slows:
            slow_owner = _owner(cls, slow)
            if slow in own or slow_owner is None or not issubclass(owner, slow_owner):
                return None
        methods.append(getattr(model, fast))
    return ScalarModel(*methods)
