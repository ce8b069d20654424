"""The batched core of the least-restrictive, sampled-data safety filter.

What the user runs: the policy's action is held for the environment's control period ``dt`` while the wind may
change at any instant, also inside the period and in answer to the filter. The filter therefore never judges an
action by the value at the current state (the pointwise ``a*`` of a continuous-time table, held for ``dt``, can
overshoot the constraint it is riding); it judges the *held* action by where one period of it can go
(:class:`~softreach.reach.proof.lookahead.Lookahead`):

* an action **passes** when holding it for one period provably keeps the state in ``C1`` and the budget
  non-negative and ends in the landing cells (:mod:`softreach.reach.proof.cell_certificate`), or surely lands;
* the policy's action is applied when it passes, or when its period keeps ``C1`` and the budget and some candidate
  passes again from every possible next state (so the next state is certified whatever the wind did);
* otherwise the filter applies a candidate held action (:meth:`FilterPart.held_candidates`) that passes: with
  ``rule="switch"`` the one whose worst next table value is lowest, with ``rule="smooth"`` the point closest to
  the policy's action on the segment from such a candidate; where none passes, the plan of the state's cell.

A state is **certified** when some candidate passes or a landing cell holds it. The cells are the whole proof;
the table (any ``W_eps`` or ``Q_min`` table of the model, continuous-time or sampled-data) only ranks the
candidates.

:class:`ValueFilter` runs this decision compiled, row by row (:mod:`softreach.filters.compiled`,
:attr:`ValueFilter.compiled`); a model that does not give its enclosure, its sets' maxima compiled and its cells is
refused at construction, with what to add (:meth:`~softreach.filters.compiled.CompiledDecision.missing`).
``tests/test_filter_reference.py`` checks the decision against ``tests/reference_decision.py``, a slow transcription
of ``docs/filters.md``.


Everything works on batches: ``t`` and ``z`` are scalars or ``(N,)``, ``x`` is ``(N, n)`` (or ``(n,)``), actions
``(N, m)`` (or ``(m,)``) in physical units unless ``normalized=True``. numpy in, numpy out; torch in, torch out.
Non-finite or wrongly shaped inputs raise :class:`ValueError` naming the value; states outside the table are
answered conservatively (not certified; the best candidate is applied).
"""

from __future__ import annotations

import math
from typing import Any

import numpy as np

from softreach.reach import Table, TableError
from softreach.reach.proof.blocks import default_threads
from softreach.reach.proof.lookahead import Lookahead, exact_normalized

from .compiled import CompiledDecision
from .plans import NO_PLAN, PLAN_LAND, PLAN_SAFE, START_SEGMENTS, check_plans, resolve_cells, start_plans
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

    :param table: a table of the model with ``W_eps`` or the budget surface ``Q_min`` (``softreach solve MODEL``,
        continuous-time or ``--held``): it ranks the candidates; the cells certify
    :param dt: the control period [s] over which every action is held
    :param margin: ``None`` or 0: the cells' proof needs no tightening (any other value is refused)
    :param rule: ``"switch"`` (most robust certified candidate) or ``"smooth"`` (closest to the policy)
    :param model: if given, the table must have been solved for it, else :class:`~softreach.reach.TableError`
    :param fallback_action: physical action where no candidate can be bounded; default the control box's centre
    :param smooth_iterations: bisection steps of the smooth rule
    :param eps: the ``h_eps`` width with which the environment drains the budget (default: the table's)
    :param target_checks: the equally spaced instants per period at which the environment checks for landing
        (its sub-step ends; :class:`SafetyFilter` passes the env's ``n_substeps``). An action that surely lands
        at one of them passes. The default 1 (the period's end) is right for any environment.
    :param safe_cells: ``"auto"`` (built or read from the cache), ``None`` (none: outside the landing cells the
        choice is not bounded by cells that prove ``C1`` and the budget), or a
        :class:`~softreach.reach.proof.cell_certificate.CellCertificate` of the ``"safe"`` game for this filter
    :param landing_cells: ``"auto"`` or a :class:`~softreach.reach.proof.cell_certificate.CellCertificate` of the
        ``"land"`` game for this filter: the certificate
    :param start_periods: the longest plan :meth:`certify_start` searches from a start state (0: none)
    :raises ValueError: the model does not give what the decision needs (a compiled ``held_box_kernel``, its sets'
        maxima compiled, ``cell_shape``), naming what to add, before any cell is built; a ``margin`` other than 0
    """

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
        if not (table.has_budget or table.has_budget_surface):
            raise TableError(f"table {table.path} holds only the classical V; the filter needs W_eps or Q_min (solve "
                             f"it without --classical)")
        if model is not None:
            table.check_compatible(model)
        self.table = table
        self.model = model if model is not None else table.model
        if table.grid("V").ndim != self.model.state_dim:
            raise TableError(f"table {table.path} has {table.grid('V').ndim} states, the model "
                             f"{self.model.state_dim}")
        missing = CompiledDecision.missing(self.model)
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
        #: the cells that prove C1 and the budget, and landing by T (:mod:`softreach.reach.proof.cell_certificate`);
        #: every applied action ends in them where the state is in them
        self.safe_cells = resolve_cells(self, safe_cells, "safe")
        self.landing_cells = resolve_cells(self, landing_cells, "land")
        #: the decision, compiled (:mod:`softreach.filters.compiled`)
        self.compiled = CompiledDecision(self)
        #: threads that share a large batch of the compiled decision (blocks of at least
        #: :data:`~softreach.reach.proof.blocks.PARALLEL_MIN_ROWS` rows); 1: the calling thread alone. By default two
        #: where the machine has them: ``benchmarks/bench_filter.py`` times 1,024 rows both ways
        self.threads = default_threads()

    # ---------------------------------------------------------------- conversions
    def physical(self, action: Any) -> np.ndarray:
        """Normalised ``[-1, 1]`` actions to physical ones (clipped; the environments' affine map)."""
        return self.a_mid + self.a_half * clip_unit(np.asarray(action, dtype=np.float64))

    def normalized(self, physical: Any) -> np.ndarray:
        """Physical actions to the normalised ``[-1, 1]`` space (inverse of :meth:`physical`)."""
        return (np.asarray(physical, dtype=np.float64) - self.a_mid) / self.a_half

    def blend(self, best: np.ndarray, pol: np.ndarray, lam: np.ndarray) -> np.ndarray:
        """The smooth rule's point ``lam`` of the way from the candidates ``best`` to the policy's actions ``pol``
        (physical, ``(N, m)``), taken in the normalised space and mapped back as an environment maps it: so the
        point judged is one an environment applies exactly (the candidate itself at ``lam = 0``)."""
        qb = exact_normalized(best, self.a_mid, self.a_half)
        return self.a_mid + self.a_half * (qb + lam[:, None] * ((pol - self.a_mid) / self.a_half - qb))

    def _inputs(self, t: Any, x: Any, z: Any, action: Any | None):
        return batch_inputs(t, x, z, action, self.n, self.m, self.model.state_names)

    # ---------------------------------------------------------------- queries
    def value(self, t: Any, x: Any, z: Any) -> np.ndarray:
        """The table's value ``D = min(V~, W~_eps)`` (``+inf`` outside the table), which ranks; numpy out."""
        tt, xs, zz, _, single, _ = self._inputs(t, x, z, None)
        out = self.lookahead.certificate(tt, xs, zz)
        return out[0] if single else out

    def certify(self, t: Any, x: Any, z: Any) -> tuple[np.ndarray, list[str], np.ndarray]:
        """Is each state certified: does some candidate held action pass the one-period test there?

        :return: ``(certified (N,), reasons, best next table value (N,))``; reasons from :data:`CERTIFY_REASONS`
        """
        tt, xs, zz, _, single, _ = self._inputs(t, x, z, None)
        ok, nxt, value, inside, in_cells = self.compiled.certify(tt, xs, zz)
        # a state in a landing cell has its cell's plan even where no single period ends in the cells
        ok = ok | in_cells
        after = tt >= self.lookahead.horizon - 1e-9
        reasons = []
        for i in range(len(xs)):
            if after[i]:
                reasons.append("after_horizon")
            elif not inside[i]:
                reasons.append("outside_table")
            elif ok[i]:
                reasons.append("certified")
            elif value[i] > 0:
                reasons.append("not_in_set")
            else:
                reasons.append("no_certified_action")
        certified = np.array([r == "certified" for r in reasons], dtype=bool)
        if single:
            return certified[0], reasons[0], nxt[0]
        return certified, reasons, nxt

    def certify_start(self, t: Any, x: Any, z: Any) -> tuple[np.ndarray, list[str], np.ndarray, np.ndarray]:
        """:meth:`certify` for the start of a run, which may also begin with a plan of its own: where no period
        or cell certifies the state, one candidate held for up to :attr:`start_periods` periods whose boxes keep
        ``C1`` and the budget and end in the landing cells, or, where the model allows two
        (:attr:`~softreach.reach.problem.Model.start_segments`) and the table puts the state in its set (reason
        ``"no_certified_action"``), two in sequence (:func:`~softreach.filters.plans.start_plans`). Such a
        start is certified only for a run whose :meth:`filter` calls get that plan: the first segment at the first
        step, the second as the first ends (:func:`~softreach.filters.plans.advance_plan`; :class:`SafetyFilter`
        does both).

        :return: ``(certified, reasons, best next table value, plans (N, START_SEGMENTS, 3))``; each row's
            segments, :data:`NO_PLAN` where none is needed or none was found
        """
        tt, xs, zz, _, single, _ = self._inputs(t, x, z, None)
        certified, reasons, nxt = self.certify(tt, xs, zz)
        rows = np.nonzero([r in ("not_in_set", "no_certified_action") for r in reasons])[0]
        plans = np.tile(np.array(NO_PLAN, np.int64), (len(xs), START_SEGMENTS, 1))
        second = np.array([self.model.start_segments > 1 and reasons[r] == "no_certified_action" for r in rows],
                          dtype=bool)
        plans[rows] = start_plans(self, tt[rows], xs[rows], zz[rows], self.start_periods, second)
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

    # ---------------------------------------------------------------- the filter
    def filter(self, t: Any, x: Any, z: Any, action: Any, *, normalized: bool = False, plan: Any = None,
               diagnostics: bool = True):
        """Filter a batch of actions.

        :param t: time(s) [s], scalar or ``(N,)``
        :param x: state(s), ``(N, n)`` or ``(n,)``, physical units
        :param z: remaining budget(s) [s], scalar or ``(N,)``
        :param action: the policy's action(s), ``(N, m)`` or ``(m,)``: physical units, or ``[-1, 1]`` with
            ``normalized=True`` (then every returned action is normalised too)
        :return: ``(applied, info)``; where the policy's action passes, ``applied`` holds the numbers given (bit for
            bit). ``info``: ``value`` (the table's ``D`` at the state), ``margin``, ``active`` (the filter
            changed the action), ``reason`` (codes of :data:`REASONS`), ``optimal_action`` (the candidate the
            filter chose; NaN where the policy passed and none was needed), ``blend`` (``1`` where the policy's
            action passed), ``lookahead`` (the worst next table value of the applied action, ``+inf`` where it
            does not pass), ``certified`` (the applied action passed the test, or follows a landing cell's plan),
            ``plan`` (numpy ``(N, 3)`` ints: the cells' plan the filter follows: candidate index, periods still to
            hold it, and whose plan, :data:`PLAN_LAND` or :data:`PLAN_SAFE`; :data:`NO_PLAN`: none)
        :param plan: the ``info["plan"]`` this filter returned at the previous step of the same runs (``None`` at the
            first): where no action ends in the landing cells the filter keeps following it, which is what makes
            landing by ``T`` a proof (:mod:`softreach.reach.proof.cell_certificate`)
        :param diagnostics: ``False`` leaves out what decides nothing, for batches that want only the actions
            (about twice as fast where most policy actions pass, ``benchmarks/bench_filter.py``): ``value`` is NaN,
            and so is ``lookahead`` where the policy's action passed. The applied actions and every other entry are
            the same.
        :raises ValueError: non-finite or wrongly shaped inputs, or :attr:`threads` below 1
        :raises TypeError: ``diagnostics`` is not a bool
        """
        if not isinstance(diagnostics, (bool, np.bool_)):
            raise TypeError(f"diagnostics must be True or False, got {diagnostics!r}")
        # an environment's step: one plain row, decided without numpy's fixed costs
        one = filter_one(self, t, x, z, action, normalized, plan, diagnostics)
        if one is not None:
            return one
        tt, xs, zz, act, single, ref = self._inputs(t, x, z, action)
        N = len(xs)
        plans = check_plans(plan, N)
        pol = self.physical(act) if normalized else np.minimum(np.maximum(act, self.a_lo), self.a_hi)
        applied, reason, value, nxt, ok, chosen, blend, new_plans = self.compiled(tt, xs, zz, pol, plans, diagnostics)
        after = tt >= self.lookahead.horizon - 1e-9
        reason = np.where(after, AFTER_HORIZON, reason)
        active = reason != PASS
        if normalized:
            # what the filter judged, exactly: an environment maps it back to the same physical action
            applied = np.where(active[:, None], exact_normalized(applied, self.a_mid, self.a_half), act)
            chosen = self.normalized(chosen)
        margin = np.full(N, self.constant_margin or 0.0)
        info = {"value": value, "margin": margin, "active": active, "reason": reason, "optimal_action": chosen,
                "blend": blend, "lookahead": nxt, "certified": ok & ~after}
        if single:
            applied = applied[0]
            info = {k: v[0] for k, v in info.items()}
        if ref is not None:
            applied, info = to_torch(applied, info, ref, action)
        info["plan"] = new_plans[0] if single else new_plans
        return applied, info

    __call__ = filter
