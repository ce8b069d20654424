"""``SafetyFilter``: the least-restrictive filter as a ``gymnasium.Wrapper`` around a landing environment."""

from __future__ import annotations

import math
import os
from pathlib import Path
from typing import Any

import numpy as np

import gymnasium as gym

from softreach.reach import Table, TableError, load_table

from .core import NO_PLAN, REASONS, ValueFilter
from .plans import advance_plan
from .tensors import clip_unit

#: what the wrapper reads from ``env.unwrapped`` (the softreach landing environments provide all of it)
REQUIRED_ATTRIBUTES = ("model", "dt", "eps", "state", "time", "budget")


class SafetyFilter(gym.Wrapper):
    """Filter any policy's actions with a table so that the sampled-data guarantee holds: from a start certified at
    ``reset``, for every policy and wind within bounds, each step provably keeps ``C1`` and the budget and every run
    lands by ``T``; the policy's action passes whenever holding it for one period keeps the state certified
    (docs/filters.md, 'What the user runs, and what is guaranteed'). The filter reads ``state``, ``time`` and
    ``budget`` from ``env.unwrapped``; observations and rewards pass unchanged. Works under gymnasium's vector
    environments and SB3's ``make_vec_env(..., wrapper_class=SafetyFilter, wrapper_kwargs={"table": path})``.

    ``info`` of every step adds:

    * ``filter_active`` — the filter replaced (or, with ``rule="smooth"``, moved) the policy's action;
    * ``policy_action`` / ``applied_action`` — the normalised action the policy gave / the one applied;
    * ``value`` — the table's ``min(V~, W~_eps)`` at the decision's state (``+inf`` outside), which proves nothing;
    * ``margin`` (0); ``optimal_action`` — the normalised candidate the filter chose (NaN where the policy passed);
    * ``filter_reason`` — why: ``"pass"`` or another name in :data:`~softreach.filters.reasons.REASONS`;
    * ``certified`` — the applied action passed the one-period test (or follows a landing cell's plan);
      ``lookahead`` — its next table value (at its end box's centre), which ranks;
    * at an episode's end, ``filter_episode``: ``steps``, ``interventions``, ``intervention_rate``, ``min_value``
      and ``max_value`` of the decisions (``max_value <= 0``: the episode never left the table's safe set),
      ``budget_used``, ``initial_budget`` and ``certified_start``.

    ``reset`` adds the start's ``value``, ``margin``, ``certified``, ``certified_reason`` (one of
    :data:`~softreach.filters.core.CERTIFY_REASONS`) and ``start_plan``: the first steps' plan of its own, two
    ``(candidate, periods, owner)``, ``(-1, 0, 0)`` where none (:meth:`~softreach.filters.ValueFilter.certify_start`).

    :param env: a softreach landing environment (possibly wrapped, e.g. by ``TimeLimit`` or ``Monitor``)
    :param table: a :class:`~softreach.reach.Table` with ``W_eps``, or the path of one
    :param margin: ``None`` or 0 (any other is refused: the cells compare no table value with a margin)
    :param rule: ``"switch"`` (least restrictive; the default) or ``"smooth"``
    :param filter_kwargs: passed to :class:`~softreach.filters.ValueFilter` (``fallback_action``,
        ``smooth_iterations``, ``eps``, ``landing_cells``, ``start_periods``)
    :param value_filter: a :class:`~softreach.filters.ValueFilter` to share among environments (its rule and margin
        apply); ``table`` may then be ``None``, and ``margin``, ``rule`` and ``filter_kwargs`` left out or agreeing
    :raises TableError: the table was solved for another model, other parameters or another ``eps``
    :raises TypeError: the environment does not expose what the filter needs, or neither table nor filter is given
    :raises ValueError: a shared ``value_filter`` that disagrees with the arguments or the environment"""

    def __init__(self, env: gym.Env, table: Table | str | os.PathLike | None = None, margin: float | None = None,
                 rule: str | None = None, *, value_filter: ValueFilter | None = None, **filter_kwargs: Any):
        super().__init__(env)
        base = env.unwrapped
        missing = [name for name in REQUIRED_ATTRIBUTES if not hasattr(base, name)]
        if missing:
            raise TypeError(f"SafetyFilter needs an environment exposing {list(REQUIRED_ATTRIBUTES)} on "
                            f"env.unwrapped (the softreach landing environments do); {type(base).__name__} lacks "
                            f"{missing}")
        if value_filter is not None:
            if not isinstance(value_filter, ValueFilter):
                raise TypeError(f"value_filter must be a softreach.filters.ValueFilter, got "
                                f"{type(value_filter).__name__}")
            if table is None:
                table = value_filter.table
            if rule is not None and rule != value_filter.rule:
                raise ValueError(f"rule={rule!r} differs from the shared value_filter's {value_filter.rule!r}")
            if margin is not None and margin != value_filter.constant_margin:
                raise ValueError(f"margin={margin!r} differs from the shared value_filter's "
                                 f"{value_filter.constant_margin!r}")
            if filter_kwargs:
                raise ValueError(f"{sorted(filter_kwargs)} cannot apply to a shared value_filter")
            if not math.isclose(value_filter.dt, float(base.dt), rel_tol=1e-12, abs_tol=0.0):
                raise ValueError(f"the shared value_filter was made for dt={value_filter.dt}, the environment "
                                 f"steps dt={base.dt}: actions are held for one control period")
            substeps = int(getattr(base, "n_substeps", 1))
            if substeps % value_filter.target_checks:
                raise ValueError(f"the shared value_filter counts on landing checks at {value_filter.target_checks}"
                                 f" instants per period, the environment checks at its {substeps} sub-step ends; "
                                 f"make it with target_checks dividing {substeps}")
        if table is None:
            raise TypeError("SafetyFilter needs a table (a softreach Table or its path) or a value_filter")
        if not isinstance(table, Table):
            table = load_table(table)
        if value_filter is not None and table is not value_filter.table and \
                Path(table.path).resolve() != Path(value_filter.table.path).resolve():
            raise ValueError(f"table {table.path} is not the shared value_filter's {value_filter.table.path}")
        table.check_compatible(base.model)
        if table.has_budget and table.eps is not None and not math.isclose(float(table.eps), float(base.eps),
                                                                              rel_tol=1e-9, abs_tol=0.0):
            raise TableError(f"table {table.path} was solved with eps={table.eps}, but the environment drains the "
                             f"budget with eps={base.eps}; make the environment with eps={table.eps}")
        self.table = table
        if value_filter is None:
            filter_kwargs.setdefault("target_checks", int(getattr(base, "n_substeps", 1)))
            value_filter = ValueFilter(table, float(base.dt), margin=margin, rule=rule or "switch",
                                       model=base.model, **filter_kwargs)
        self.value_filter = value_filter
        self.rule = value_filter.rule
        #: ``env.unwrapped``, kept: each read of it goes down the chain of wrappers
        self._base = base
        self._reset_stats()

    def _reset_stats(self) -> None:
        self._steps = self._interventions = 0
        self._min_value, self._max_value = math.inf, -math.inf
        self._initial_budget = math.nan
        self._certified_start = False
        self._pending: tuple | None = None
        #: the plan the filter follows (``ValueFilter.filter``'s ``plan``), and a start plan's second segment
        self._plan, self._queued = np.array(NO_PLAN, np.int64), np.array(NO_PLAN, np.int64)
        # the action space's dtype and shape, read once an episode: each read of a wrapper's action_space goes down
        # the chain of wrappers
        space = self.action_space
        self._action_type = (space.dtype if space.dtype is not None else np.float32, space.shape)

    def expect(self, action: Any, applied: np.ndarray, decision: dict[str, Any]) -> None:
        """Hand over a batched decision for ``action`` in this state (:class:`~softreach.filters.VecSafetyFilter`):
        the next :meth:`step` uses it if it gets that action in that state, and decides itself otherwise."""
        base = self._base
        self._pending = (np.array(action, copy=True), base.time, np.array(base.state, copy=True), base.budget,
                         applied, decision)

    def reset(self, *, seed: int | None = None, options: dict[str, Any] | None = None):
        """Reset the environment and the episode statistics; ``info`` adds the start's keys (the class docstring)."""
        obs, info = self.env.reset(seed=seed, options=options)
        self._reset_stats()
        base = self._base
        self._initial_budget = float(base.budget)
        vf = self.value_filter
        value = float(vf.value(base.time, base.state, base.budget))
        certified, why, _, plan = vf.certify_start(base.time, base.state, base.budget)
        # a start certified by a plan of its own is certified for the run that follows it from the first step
        self._plan, self._queued = np.array(plan[0], np.int64), np.array(plan[1], np.int64)
        self._certified_start = bool(certified)
        return obs, dict(info, value=value, margin=float(vf.constant_margin or 0.0), certified=bool(certified),
                         certified_reason=why, start_plan=np.array(plan, np.int64))

    def step(self, action: Any):
        """Filter ``action`` (normalised, as the policy gives it) and step the environment; a non-finite or wrongly
        shaped action raises ``ValueError`` (as the environment would)."""
        base = self._base
        x = base.state
        if x is None:
            raise gym.error.ResetNeeded("call reset() before step()")
        pending, self._pending = self._pending, None
        if pending is not None and pending[1] == base.time and pending[3] == base.budget \
                and np.array_equal(pending[2], x) and np.array_equal(pending[0], np.asarray(action)):
            applied, f = pending[4], pending[5]
        else:
            applied, f = self.value_filter.filter(base.time, x, base.budget, np.asarray(action), normalized=True,
                                                  plan=self._plan)
        self._plan, self._queued = advance_plan(f["plan"], self._queued)
        active = bool(f["active"])
        dtype, shape = self._action_type
        # the filter's action goes in binary64: the space's float32 would move its physical image off the one judged
        to_env = np.asarray(applied, dtype=np.float64) if active else action
        obs, reward, terminated, truncated, info = self.env.step(to_env)

        value = float(f["value"])
        self._steps += 1
        self._interventions += int(active)
        self._min_value = min(self._min_value, value)
        self._max_value = max(self._max_value, value)
        info = dict(info)
        info["filter_active"] = active
        info["policy_action"] = np.array(action, dtype=dtype, copy=True).reshape(shape)
        # what the environment applies: it clips a finite out-of-range action to [-1, 1]
        info["applied_action"] = clip_unit(np.asarray(to_env, dtype=dtype)).reshape(shape)
        info["value"] = value
        info["margin"] = float(f["margin"])
        info["optimal_action"] = np.asarray(f["optimal_action"], dtype=dtype).reshape(shape)
        info["filter_reason"] = REASONS[int(f["reason"])]
        info["certified"] = bool(f["certified"])
        info["lookahead"] = float(f["lookahead"])
        if terminated or truncated:
            info["filter_episode"] = self.episode_summary(info)
        return obs, reward, terminated, truncated, info

    def episode_summary(self, info: dict[str, Any] | None = None) -> dict[str, float]:
        """The running episode's filter statistics (what ``info["filter_episode"]`` holds at its end)."""
        base = self._base
        used = info.get("budget_used") if info else None
        if used is None:
            used = self._initial_budget - float(base.budget)
        return {"steps": self._steps, "interventions": self._interventions,
                "intervention_rate": self._interventions / self._steps if self._steps else 0.0,
                "min_value": self._min_value, "max_value": self._max_value, "budget_used": float(used),
                "initial_budget": self._initial_budget, "certified_start": self._certified_start}
