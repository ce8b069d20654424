"""The batched core of the least-restrictive, sampled-data safety filter: :class:`ValueFilter`.

The filter judges the policy's action *held* for one period ``dt`` against a wind that may change at any instant,
by the one-period test and the rule of docs/filters.md ("The one-period test", "The rule"), compiled
(:mod:`softreach.filters.compiled`): the cells prove, the table (``W_eps`` or ``Q_min``) only ranks the candidates.

Everything works on batches: ``t`` and ``z`` are scalars or ``(N,)``, ``x`` is ``(N, n)`` (or ``(n,)``), actions
``(N, m)`` (or ``(m,)``) in physical units unless ``normalized=True``. numpy in, numpy out; torch in, torch out.
Non-finite or wrongly shaped inputs raise :class:`ValueError` naming the value; states outside the table are
answered conservatively (not certified; the best candidate is applied)."""

from __future__ import annotations

import math
from typing import Any

import numpy as np

from softreach.reach import Table, TableError
from softreach.reach.proof.blocks import default_threads
from softreach.reach.proof import enclosure_check
from softreach.reach.proof.lookahead import Lookahead, exact_normalized

from .compiled import CompiledDecision
from .plans import NO_PLAN, PLAN_LAND, PLAN_SAFE, START_SEGMENTS, check_plans, resolve_cells
from .reasons import AFTER_HORIZON, BLEND, FALLBACK, OPTIMAL, OUTSIDE, PASS, REASONS, UNCERTIFIED
from .single import filter_one
from .tensors import batch_inputs, clip_unit, to_torch

__all__ = ["NO_PLAN", "PLAN_LAND", "PLAN_SAFE", "PASS", "BLEND", "OPTIMAL", "OUTSIDE", "AFTER_HORIZON",
           "FALLBACK", "UNCERTIFIED", "REASONS", "RULES", "CERTIFY_REASONS", "ValueFilter"]

RULES = ("switch", "smooth")
#: why a state is or is not certified (:meth:`ValueFilter.certify`)
CERTIFY_REASONS = ("certified", "outside_table", "after_horizon", "not_in_set", "no_certified_action")


class ValueFilter:
    """The safety filter's core: one table, one control period, one rule.

    :param table: a ``W_eps`` or ``Q_min`` table of the model (``softreach solve MODEL``): it ranks; the cells certify
    :param dt: the control period [s] over which every action is held
    :param margin: ``None`` or 0: the cells' proof needs no tightening (any other value is refused)
    :param rule: ``"switch"`` (most robust certified candidate) or ``"smooth"`` (closest to the policy)
    :param model: if given, the table must have been solved for it, else :class:`~softreach.reach.TableError`
    :param fallback_action: physical action where no candidate can be bounded; default the control box's centre
    :param smooth_iterations: bisection steps of the smooth rule
    :param eps: the ``h_eps`` width with which the environment drains the budget (default: the table's)
    :param target_checks: equally spaced instants per period at which the environment checks for landing (its
        sub-step ends, :class:`SafetyFilter` passes ``n_substeps``); the default 1, the period's end, is always right
    :param safe_cells: ``"auto"`` or ``None``, alike: the filter proves and plans with the landing cells alone
        (docs/filters.md, "The filter with cells"); :attr:`safe_cells` is ``None``
    :param landing_cells: ``"auto"`` or a ``"land"``-game certificate (:mod:`~softreach.reach.proof.cell_certificate`)
    :param start_periods: the longest plan :meth:`certify_start` searches from a start state (0: none)
    :raises ValueError: the model lacks what the decision needs (named, before any cell is built); ``margin`` not 0"""

    def __init__(self, table: Table, dt: float, *, margin: float | None = None, rule: str = "switch",
                 model: Any = None, fallback_action: Any = None, smooth_iterations: int = 8,
                 eps: float | None = None, target_checks: int = 1, safe_cells: Any = "auto",
                 landing_cells: Any = "auto", start_periods: int = 32):
        if not isinstance(table, Table):
            raise TypeError(f"table must be a softreach.reach.Table (load_table(path)), got {type(table).__name__}")
        if rule not in RULES:
            raise ValueError(f"rule must be one of {RULES}, got {rule!r}")
        if not (isinstance(dt, (int, float, np.floating)) and not isinstance(dt, bool) and math.isfinite(dt)
                and dt > 0):
            raise ValueError(f"dt must be a finite positive number of seconds, got {dt!r}")
        if margin is not None and not (isinstance(margin, (int, float, np.floating)) and not isinstance(margin, bool)
                                       and margin == 0):
            raise ValueError(f"margin must be None or 0: the landing cells prove the guarantee and no table value "
                             f"is compared with a margin, got {margin!r}")
        if not (isinstance(smooth_iterations, (int, np.integer)) and smooth_iterations >= 0):
            raise ValueError(f"smooth_iterations must be a non-negative integer, got {smooth_iterations!r}")
        if not (isinstance(start_periods, (int, np.integer)) and not isinstance(start_periods, bool)
                and start_periods >= 0):
            raise ValueError(f"start_periods must be a non-negative integer, got {start_periods!r}")
        if not (safe_cells is None or (isinstance(safe_cells, str) and safe_cells == "auto")):
            raise ValueError(f"safe_cells must be 'auto' or None: the filter reads no safe cells, only the landing "
                             f"cells (landing_cells), got {type(safe_cells).__name__}")
        if not (table.has_budget or table.has_budget_surface):
            raise TableError(f"table {table.path} holds only the classical V; the filter needs W_eps or Q_min (solve "
                             f"it without --classical)")
        if model is not None:
            table.check_compatible(model)
        self.table = table
        self.model = model if model is not None else table.model
        if table.grid("V").ndim != self.model.state_dim:
            raise TableError(f"table {table.path} has {table.grid('V').ndim} states, the model {self.model.state_dim}")
        missing = enclosure_check.lacking(self.model)
        if missing is not None:
            raise ValueError(f"the safety filter cannot decide for model {self.model.name!r}: {missing}")
        self.dt = float(dt)
        self.rule = rule
        self.smooth_iterations = int(smooth_iterations)
        self.start_periods = int(start_periods)
        self.eps = float(table.eps if eps is None else eps)
        self.constant_margin = None if margin is None else 0.0
        self.n, self.m = self.model.state_dim, self.model.control_dim
        self.a_lo = np.array(self.model.control_bounds[0], dtype=np.float64)
        self.a_hi = np.array(self.model.control_bounds[1], dtype=np.float64)
        self.a_mid = 0.5 * (self.a_lo + self.a_hi)
        self.a_half = 0.5 * (self.a_hi - self.a_lo)
        if fallback_action is None:
            self.fallback_action = self.a_mid.copy()
        else:
            fb = np.asarray(fallback_action, dtype=np.float64).reshape(-1)
            if fb.shape != (self.m,) or not np.all(np.isfinite(fb)):
                raise ValueError(f"fallback_action must be {self.m} finite physical value(s), got {fallback_action!r}")
            self.fallback_action = np.clip(fb, self.a_lo, self.a_hi)
        self.lookahead = Lookahead.from_table(table, self.model, self.dt, self.eps, target_checks=target_checks)
        self.target_checks = self.lookahead.target_checks
        #: the cells that prove C1, the budget and landing by T (:mod:`softreach.reach.proof.cell_certificate`)
        self.landing_cells = resolve_cells(self, landing_cells)
        self.safe_cells = None
        self.compiled = CompiledDecision(self)
        #: threads that share a large batch (:data:`~softreach.reach.proof.blocks.PARALLEL_MIN_ROWS`); 1: the caller's
        self.threads = default_threads()

    def physical(self, action: Any) -> np.ndarray:
        """Normalised ``[-1, 1]`` actions to physical ones (clipped; the environments' affine map)."""
        return self.a_mid + self.a_half * clip_unit(np.asarray(action, dtype=np.float64))

    def normalized(self, physical: Any) -> np.ndarray:
        """Physical actions to the normalised ``[-1, 1]`` space (inverse of :meth:`physical`)."""
        return (np.asarray(physical, dtype=np.float64) - self.a_mid) / self.a_half

    def blend(self, best: np.ndarray, pol: np.ndarray, lam: np.ndarray) -> np.ndarray:
        """The smooth rule's point ``lam`` of the way from candidates ``best`` to policy actions ``pol`` (physical,
        ``(N, m)``), in the normalised space and mapped back as an environment maps it: the point judged is applied."""
        qb = exact_normalized(best, self.a_mid, self.a_half)
        return self.a_mid + self.a_half * clip_unit(qb + lam[:, None] * ((pol - self.a_mid) / self.a_half - qb))

    def _inputs(self, t: Any, x: Any, z: Any, action: Any | None):
        return batch_inputs(t, x, z, action, self.n, self.m, self.model.state_names)

    def value(self, t: Any, x: Any, z: Any) -> np.ndarray:
        """The table's value ``D = min(V~, W~_eps)`` (``+inf`` outside the table), which ranks; numpy out."""
        tt, xs, zz, _, single, _ = self._inputs(t, x, z, None)
        out = self.lookahead.certificate(tt, xs, zz)
        return out[0] if single else out

    def certify(self, t: Any, x: Any, z: Any) -> tuple[np.ndarray, list[str], np.ndarray]:
        """Whether each state is certified: some candidate passes the one-period test, or a landing cell holds it.

        :return: ``(certified (N,), reasons, best next table value (N,))``; reasons from :data:`CERTIFY_REASONS`"""
        tt, xs, zz, _, single, _ = self._inputs(t, x, z, None)
        ok, nxt, value, inside = self.compiled.certify(tt, xs, zz)
        after = tt >= self.lookahead.horizon - 1e-9
        # the first condition that holds names the reason
        reasons = np.select([after, ~inside, ok, value > 0], ["after_horizon", "outside_table", "certified",
                                                              "not_in_set"], "no_certified_action").tolist()
        certified = ok & inside & ~after
        if single:
            return certified[0], reasons[0], nxt[0]
        return certified, reasons, nxt

    def certify_start(self, t: Any, x: Any, z: Any) -> tuple[np.ndarray, list[str], np.ndarray, np.ndarray]:
        """:meth:`certify`, where a start not otherwise certified may begin with a plan of its own
        (:meth:`~softreach.filters.compiled.CompiledDecision.start_plans`), certified only for a run whose
        :meth:`filter` calls get that plan (:func:`~softreach.filters.plans.advance_plan`; :class:`SafetyFilter` does
        so).

        :return: ``(certified, reasons, best next table value, plans (N, START_SEGMENTS, 3))``; :data:`NO_PLAN`: none"""
        tt, xs, zz, _, single, _ = self._inputs(t, x, z, None)
        certified, reasons, nxt = self.certify(tt, xs, zz)
        # searched where neither one period nor a cell certifies the start; a plan of one period would be neither
        rows = np.nonzero([r in ("not_in_set", "no_certified_action") for r in reasons])[0]
        plans = np.tile(np.array(NO_PLAN, np.int64), (len(xs), START_SEGMENTS, 1))
        if self.start_periods >= 2 and len(rows):
            second = np.array([self.model.start_segments > 1 and reasons[r] == "no_certified_action" for r in rows],
                              dtype=bool)
            plans[rows] = self.compiled.start_plans(tt[rows], xs[rows], zz[rows], self.start_periods, second)
        planned = plans[:, 0, 0] >= 0
        certified = certified | planned
        reasons = ["certified" if p else r for r, p in zip(reasons, planned)]
        if single:
            return certified[0], reasons[0], nxt[0], plans[0]
        return certified, reasons, nxt, plans

    def worst_disturbance(self, t: Any, x: Any, z: Any) -> np.ndarray:
        """The table's ``b*(t, x, z)`` (:meth:`Table.worst_disturbance`), ``(N, k)`` physical; numpy out."""
        tt, xs, zz, _, single, _ = self._inputs(t, x, z, None)
        out = self.table.worst_disturbance(tt, xs, np.maximum(zz, self.table.budget_resolution), outside="nearest")
        return out[0] if single else out

    def filter(self, t: Any, x: Any, z: Any, action: Any, *, normalized: bool = False, plan: Any = None,
               diagnostics: bool = True):
        """Filter a batch of actions.

        :param t: time(s) [s], scalar or ``(N,)``
        :param x: state(s), ``(N, n)`` or ``(n,)``, physical units
        :param z: remaining budget(s) [s], scalar or ``(N,)``
        :param action: the policy's action(s), ``(N, m)`` or ``(m,)``: physical, or ``[-1, 1]`` with
            ``normalized=True`` (then every returned action is normalised too)
        :param plan: the ``info["plan"]`` of the previous step of the same runs (``None`` at the first); following it
            where no action ends in the landing cells is what makes landing by ``T`` a proof
        :param diagnostics: ``False`` skips what decides nothing: ``value`` is NaN, and ``lookahead`` where the policy
            passed; the applied actions and other entries are the same
        :return: ``(applied, info)``, a passing policy action bit for bit. ``info``: ``value`` (the table's ``D``),
            ``margin``, ``active`` (changed), ``reason`` (:data:`REASONS`), ``optimal_action`` (the chosen candidate,
            NaN where the policy passed), ``blend`` (``1`` where it passed), ``lookahead`` (the applied action's next
            table value, at its end box's centre; ``-inf`` where it surely lands, ``+inf`` where it fails),
            ``certified`` (it passed, or follows a landing cell's plan), ``plan`` (``(N, 3)`` ints: candidate,
            periods left, :data:`PLAN_LAND`; or :data:`NO_PLAN`)
        :raises ValueError: non-finite or wrongly shaped inputs, or :attr:`threads` below 1
        :raises TypeError: ``diagnostics`` is not a bool"""
        if not isinstance(diagnostics, (bool, np.bool_)):
            raise TypeError(f"diagnostics must be True or False, got {diagnostics!r}")
        # an environment's step: one plain row, decided without numpy's fixed costs
        one = filter_one(self, t, x, z, action, normalized, plan, diagnostics)
        if one is not None:
            return one
        tt, xs, zz, act, single, ref = self._inputs(t, x, z, action)
        N = len(xs)
        plans = check_plans(plan, N)
        applied, reason, value, nxt, ok, chosen, blend, new_plans = self.compiled(tt, xs, zz, act, normalized, plans,
                                                                                  diagnostics)
        after = tt >= self.lookahead.horizon - 1e-9
        reason = np.where(after, AFTER_HORIZON, reason)
        active = reason != PASS
        if normalized:
            # a passing action as the policy gave it
            applied = np.where(active[:, None], applied, act)
        info = {"value": value, "margin": np.full(N, self.constant_margin or 0.0), "active": active, "reason": reason,
                "optimal_action": chosen, "blend": blend, "lookahead": nxt, "certified": ok & ~after}
        if single:
            applied = applied[0]
            info = {k: v[0] for k, v in info.items()}
        if ref is not None:
            applied, info = to_torch(applied, info, ref, action)
        info["plan"] = new_plans[0] if single else new_plans
        return applied, info

    __call__ = filter
