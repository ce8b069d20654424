"""Checks of the boxes and ranges a model declares (its control and disturbance boxes, its grid box, ...): each
raises a one-line ``ValueError`` that names the model, the attribute and the bad values.
:class:`~softreach.reach.dynamics.Dynamics` runs them where the attributes are set (``Dynamics._CHECKS``)."""

from __future__ import annotations

import math
from typing import Any, Callable, Sequence

import numpy as np


def model_label(obj: Any) -> str:
    """How a message names a model: ``model 'name' (Class)``."""
    cls = obj if isinstance(obj, type) else type(obj)
    return f"model {getattr(obj, 'name', cls.__name__)!r} ({cls.__qualname__})"


def _number(v: Any) -> bool:
    return isinstance(v, (int, float, np.integer, np.floating)) and not isinstance(v, (bool, np.bool_))


def check_box(owner: str, box: Any, *, field: str, strict: bool = False, unbounded: bool = False,
              axis_names: Sequence[str] = (), why: str = "") -> None:
    """Raise a one-line ``ValueError`` naming ``owner``, ``field`` and the bad values unless ``box`` is a pair
    ``(lower, upper)`` of equally long sequences of real numbers with ``lower <= upper`` on every axis.

    :param owner: what declares the box (the model's name), for the message
    :param field: the attribute, for the message
    :param strict: ask ``lower < upper`` (a box that a grid spans or that cells tile has width on every axis); a
        zero width is otherwise allowed (an input held fixed, a start fixed along an axis)
    :param unbounded: allow ``-inf`` lower and ``+inf`` upper ends (a box that only bounds some axes); NaN never
    :param axis_names: names of the axes, for the message (indices where not given)
    :param why: what needs the width, added to a message about a zero width
    """
    where = f"{owner}: {field}"
    if isinstance(box, (str, bytes)) or not isinstance(box, (Sequence, np.ndarray)) or len(box) != 2:
        raise ValueError(f"{where} must be a pair (lower, upper) of per-axis bounds, got {box!r}")
    lower, upper = box
    for side, ends in (("lower", lower), ("upper", upper)):
        if isinstance(ends, (str, bytes)) or not isinstance(ends, (Sequence, np.ndarray)):
            raise ValueError(f"{where}: {side} must be a sequence of numbers, one per axis, got {ends!r} in {box!r}")
        bad = [v for v in ends if not _number(v)]
        if bad:
            raise ValueError(f"{where}: {side} holds {bad[0]!r}, not a real number, in {box!r}")
    if len(lower) != len(upper):
        raise ValueError(f"{where}: lower has {len(lower)} entries and upper {len(upper)}, got {box!r}")
    for i, (lo, hi) in enumerate(zip(lower, upper)):
        axis = f"axis {axis_names[i]!r}" if i < len(axis_names) else f"axis {i}"
        lo_ok = math.isfinite(lo) or (unbounded and lo == -math.inf)
        hi_ok = math.isfinite(hi) or (unbounded and hi == math.inf)
        if not (lo_ok and hi_ok):
            allowed = "finite, or -inf below and +inf above" if unbounded else "finite"
            raise ValueError(f"{where}: bounds must be {allowed}; {axis} has [{lo!r}, {hi!r}] in {box!r}")
        if lo > hi or (strict and lo == hi):
            rule = "lower < upper" if strict else "lower <= upper"
            raise ValueError(f"{where} needs {rule} on every axis; {axis} has lower {lo!r} > upper {hi!r} in {box!r}"
                             if lo > hi else f"{where} needs {rule} on every axis; {axis} has zero width "
                             f"[{lo!r}, {hi!r}] in {box!r}" + (f": {why}" if why else ""))


def box_check(field: str, *, states: bool = False, optional: bool = False, **options: Any
              ) -> Callable[[Any, Any], None]:
    """The check of a box attribute for ``Dynamics._CHECKS``: ``check(obj, value)`` runs :func:`check_box`
    naming ``obj`` (a model class or instance).

    :param states: a box over the state: its axes are named by ``obj.state_names``
    :param optional: ``None`` (not declared) is accepted
    :param options: ``strict`` and ``unbounded`` of :func:`check_box`
    """
    def check(obj: Any, value: Any) -> None:
        if optional and value is None:
            return
        names = tuple(getattr(obj, "state_names", ())) if states else ()
        check_box(model_label(obj), value, field=field, axis_names=names, **options)

    return check


def check_action_box(obj: Any) -> None:
    """Where actions are normalised (an environment's action space ``[-1, 1]``, the safety filter's map of it,
    :func:`~softreach.reach.proof.lookahead.action_map`), the control box needs a width on every axis: ``q = (u - mid) /
    half``. The model's own check (``Dynamics._CHECKS``) allows a zero width, which a solve alone can use (an
    input held fixed); this check refuses it with a one-line ``ValueError`` naming the model, the axis and its
    bounds."""
    check_box(model_label(obj), obj.control_bounds, field="control_bounds", strict=True,
              why="an environment and the safety filter map actions to [-1, 1] by the box's half-width; give the "
                  "axis a width or leave that input out of the model")


def check_horizon(obj: Any, value: Any) -> None:
    """The horizon ``T`` [s]: a finite number > 0."""
    if isinstance(value, bool) or not isinstance(value, (int, float, np.integer, np.floating)) or not (
            math.isfinite(value) and value > 0):
        raise ValueError(f"{model_label(obj)}: horizon must be a finite number of seconds > 0, got {value!r}")


def check_start_budget(obj: Any, value: Any) -> None:
    """The episode budget: a number of seconds >= 0, or a ``(low, high)`` range of them with ``low <= high``."""
    ends = tuple(value) if isinstance(value, (tuple, list)) else (value,)
    ok = len(ends) in (1, 2) and all(not isinstance(v, bool) and isinstance(v, (int, float, np.integer, np.floating))
                                     and math.isfinite(v) and v >= 0 for v in ends)
    if not ok or ends[0] > ends[-1]:
        raise ValueError(f"{model_label(obj)}: start_budget must be a budget [s] >= 0 or a (low, high) range with "
                         f"0 <= low <= high, got {value!r}")
