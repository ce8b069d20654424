"""The filter's whole decision, compiled: one loop over the rows, the only implementation of the decision.

:class:`~softreach.filters.ValueFilter` decides, both rules included, by the one-period test and the cells' plans
(docs/filters.md, "The rule" and "How"), with the kernels the cells' builder runs too; a model must give its enclosure
and sets' maxima compiled (:func:`~softreach.reach.proof.enclosure_check.lacking`). The table only ranks
(:func:`~softreach.filters.judge.next_value`); ``tests/test_filter_reference.py`` checks against
``tests/reference_decision.py``."""

from __future__ import annotations

import math
import threading
from typing import Any

import numpy as np

from softreach.reach.jit import entry_point, njit
from softreach.reach.proof.blocks import run_in_blocks
from softreach.reach.proof.kernels import certificate_row, cover_row, frozen, plan_row, point_scratch
from softreach.reach.proof.lookahead import exact_normalized
from softreach.reach.proof.period import motion

from .compiled_args import (N_BOOL_J, N_FLOAT_J, N_FLOAT_M, N_FLOAT_N, N_FLOAT_N1, ActionMap, Cells, DecisionSpace,
                            TableArgs, named, packed_space, plain)
from .compiled_starts import start_plan_rows
from .judge import badness, judge, next_value, on_table
from .plans import PLAN_LAND, START_SEGMENTS
from .reasons import BLEND, FALLBACK, OPTIMAL, OUTSIDE, PASS, UNCERTIFIED
from .keeps import keeps


def decision_space(n: int, m: int, J: int) -> tuple[DecisionSpace, tuple]:
    """The work space of :func:`decide_rows` and :func:`~softreach.filters.compiled_starts.start_plan_rows`, so that
    the compiled loops allocate nothing: ``(named, packed)``, one memory."""
    packed = (np.empty((N_FLOAT_J, J)), np.empty((N_BOOL_J, J), np.bool_), np.empty((N_FLOAT_N, n)),
              np.empty((N_FLOAT_N1, n + 1)), np.empty((2, J + 1, n)), np.empty((N_FLOAT_M, m)), np.empty(J, np.int64),
              np.empty((8, n))) + point_scratch(n + 1)
    # the named views in Python: the compiled function's own code, run by the interpreter
    return packed_space.py_func(packed), packed


@njit(inline="always")
def _stable_order(keys, order):
    """``order`` = ``np.argsort(keys, kind="stable")`` (NaN last), by insertion, without allocating."""
    for i in range(len(keys)):
        j = i
        while j > 0 and _after(keys[order[j - 1]], keys[i]):
            order[j] = order[j - 1]
            j -= 1
        order[j] = i


@njit(forceinline=True)
def _after(a, b):
    """Whether ``a`` sorts after ``b`` (NaN after every number, as numpy sorts)."""
    return a > b or (math.isnan(a) and not math.isnan(b))


@njit(inline="always")
def _policy(space, action, actions, r, normalized):
    """Row ``r``'s policy action as an environment applies it into ``space.pol`` (:meth:`ValueFilter.physical` of a
    normalised one, else clipped to the control box) and, where ``normalized``, the normalised action whose image it
    is into ``space.pol_q``."""
    for i in range(len(space.pol)):
        a = actions[r, i]
        if normalized:
            space.pol_q[i] = min(max(a, -1.0), 1.0)
            space.pol[i] = action.mid[i] + action.half[i] * space.pol_q[i]
        else:
            space.pol[i] = min(max(a, action.lo[i]), action.hi[i])


@njit(inline="always")
def _blend(space, action, best, lam):
    """:meth:`ValueFilter.blend` of candidate ``best`` and the policy's action into ``space.act``, and the normalised
    action whose image it is into ``space.act_q``."""
    a_mid, a_half, cands_q, pol = action.mid, action.half, action.cands_q, space.pol
    for i in range(len(pol)):
        q = cands_q[best, i] + lam * ((pol[i] - a_mid[i]) / a_half[i] - cands_q[best, i])
        space.act_q[i] = min(max(q, -1.0), 1.0)
        space.act[i] = a_mid[i] + a_half[i] * space.act_q[i]


@njit(inline="always")
def _distance(cands, j, pol, a_half):
    """The normalised distance from candidate ``j`` to the policy's action ``pol`` (the smooth rule's preference)."""
    d = 0.0
    for i in range(cands.shape[1]):
        q = (cands[j, i] - pol[i]) / a_half[i]
        d += q * q
    return math.sqrt(d)


@njit(inline="always")
def _keeping(enclose, M, C, cands, smooth, tr, space):
    """The first candidate in the rule's order that keeps (:func:`~softreach.filters.keeps.keeps`); ``-1``: none."""
    c_ok, c_kept, c_zend = space.c_ok, space.c_kept, space.c_zend
    _stable_order(space.c_pref, space.c_order)
    for k in space.c_order:
        if not (c_ok[k] or (smooth and c_kept[k])):
            break
        if c_ok[k] or keeps(enclose, M, C, cands, tr, space.end_lo[k], space.end_hi[k], c_zend[k], c_kept[k],
                            space.work, space.work_box, space.slab_box, np.bool_(False)):
            return k
    return -1


@njit(inline="always")
def _choose(enclose, M, C, T, cands, smooth, tr, t_next, space):
    """Every candidate judged: ``(the rule's choice, whether it is bounded)``. The switch rule's is the passing
    candidate of lowest next value; the smooth rule's the nearest to the policy's action that passes or keeps, else
    the nearest passing one; where none passes or keeps, the least bad (:func:`~softreach.filters.judge.badness`)."""
    J = cands.shape[0]
    work, end_lo, end_hi = space.work, space.end_lo, space.end_hi
    c_ok, c_next, c_kept, c_dist, c_bad = space.c_ok, space.c_next, space.c_kept, space.c_dist, space.c_bad
    for k in range(J):
        if c_ok[k] and c_next[k] == np.inf:
            c_next[k] = next_value(T, t_next, end_lo[k], end_hi[k], space.c_zend[k], work)
        if smooth:
            space.c_pref[k] = c_dist[k] if (c_ok[k] or c_kept[k]) else np.inf
        else:
            space.c_pref[k] = c_next[k] if c_ok[k] else np.inf
    best = _keeping(enclose, M, C, cands, smooth, tr, space)
    if best >= 0:
        return best, True
    nearest = -1
    for k in range(J):
        if c_ok[k] and (nearest < 0 or c_dist[k] < c_dist[nearest]):
            nearest = k
    if nearest >= 0:
        return nearest, True
    badness(T, t_next, end_lo, end_hi, work, space.c_in, space.c_bounded, c_kept, space.c_c1, space.c_zend, c_bad)
    best = np.argmin(c_bad)
    return best, c_bad[best] < np.inf


# called, not inlined: large and run at most once a row (softreach.filters.judge, "Inlined or called")
@njit(_nrt=False)
def _follow_plan(C, cands, cands_q, r, tr, xr, zr, plans, has_plans, best, best_next, lam, act, act_q, c_next,
                 new_plans):
    """Row ``r``'s landing-cell plan where no candidate passes: the one followed, else the state's cell's. Writes
    ``act``, ``act_q`` (its normalised action) and ``new_plans[r]``; returns ``(best, best_next, lam, followed)``."""
    J = cands.shape[0]
    if has_plans and plans[r, 1] > 0 and 0 <= plans[r, 0] < J and plans[r, 2] == PLAN_LAND:
        jj, left = plans[r, 0], plans[r, 1] - 1
    else:
        cj, ck = plan_row(C.land, C.plan[0], C.plan[1], tr, xr)
        # (a candidate index past the set can only come from a damaged file: no plan, never a wild read)
        if not (0 <= cj < J and cover_row(C.land, tr, xr, xr, zr)):
            return best, best_next, lam, False
        jj, left = cj, ck - 1
    for i in range(cands.shape[1]):
        act[i], act_q[i] = cands[jj, i], cands_q[jj, i]
    new_plans[r, 0], new_plans[r, 1], new_plans[r, 2] = jj, left, PLAN_LAND
    # the plan's candidate itself is applied, not a blend towards the policy's action
    return jj, c_next[jj], 0.0, True


# _nrt=False here and in the kernels it calls: reference counting costs, and they allocate nothing (docs/filters.md)
@njit(nogil=True, _nrt=False)
def decide_rows(enclose, m_args, c_args, t_args, cands, smooth, iterations, a_args, t, x, z, actions, normalized,
                plans, has_plans, diagnostics, with_policy, applied, reason, value, nxt, certified, chosen, blend,
                new_plans, space_args):
    """The decision for every row (:meth:`ValueFilter.filter`): the ``"smooth"`` rule with ``iterations`` bisection
    steps where ``smooth``, else ``"switch"``; ``*_args`` as plain tuples (:mod:`softreach.filters.compiled_args`).
    The policy's ``actions`` and the ``applied`` and ``chosen`` ones are normalised where ``normalized``, else
    physical; a normalised applied action is the one whose image (``mid + half * q``) was judged.
    Without ``diagnostics`` the value at the state and a passing policy's next value (deciding nothing) are NaN. Without
    ``with_policy`` only the candidates are judged: the certificate at a state (:meth:`CompiledDecision.certify`)."""
    M, C, T, action = named(m_args, c_args, t_args, a_args)
    space = packed_space(space_args)
    J, m = cands.shape
    work, end_lo, end_hi, act = space.work, space.end_lo, space.end_hi, space.act
    a_mid, a_half = action.mid, action.half
    for r in range(x.shape[0]):
        tr, xr, zr = t[r], x[r], z[r]
        _policy(space, action, actions, r, normalized)
        value[r] = (certificate_row(T.W, T.z_top, T.z_floor, T.z_left, T.V, T.has_V, tr, xr, zr, work.point,
                                    work.buf, work.node) if diagnostics else np.nan)
        new_plans[r, 0], new_plans[r, 1], new_plans[r, 2] = -1, 0, 0
        # one inlined judge serves every action a row tries (each copy adds to the first compilation): the policy's,
        # every candidate, then the smooth rule's bisection towards the policy's action
        passed, any_ok, bounded = False, False, False
        best, best_next = 0, np.inf
        lo, hi, mid = 0.0, 1.0, 0.0
        for s in range(0 if with_policy else 1, 1 + J + (iterations if smooth else 0)):
            slot = s - 1 if 1 <= s <= J else J
            # the action of step s: the policy's, candidate s - 1, or the bisection point
            if s > J:
                mid = 0.5 * (lo + hi)
                _blend(space, action, best, mid)
            else:
                for i in range(m):
                    act[i] = space.pol[i] if s == 0 else cands[s - 1, i]
            v = judge(enclose, M, C, tr, xr, xr, zr, act, end_lo[slot], end_hi[slot], work)
            a_lands, a_zend, t_next = v.lands, v.z_end, v.t_next
            a_ok, a_kept = v.ok or a_lands, v.kept or a_lands
            # a surely landing action's next value is -inf; a passing one's is read below where it is needed
            a_next = -np.inf if a_lands else np.inf
            # the policy's and the bisection's next value (the policy's, a diagnostic, only with diagnostics)
            if a_ok and not a_lands and (s > J or (s == 0 and diagnostics)):
                a_next = next_value(T, t_next, end_lo[slot], end_hi[slot], a_zend, work)
            # a passing action keeps: the call of keeps, with its large tuples, is skipped
            if s == 0:
                # slabs for the policy's own action only: the filter's own choices need one candidate
                if a_ok or keeps(enclose, M, C, cands, tr, end_lo[J], end_hi[J], a_zend, a_kept, work,
                                 space.work_box, space.slab_box, np.bool_(True)):
                    for i in range(m):
                        applied[r, i] = space.pol_q[i] if normalized else space.pol[i]
                    reason[r], nxt[r], certified[r], blend[r] = PASS, a_next if diagnostics else np.nan, True, 1.0
                    chosen[r] = np.nan
                    passed = True
                    break
                continue
            if s > J:
                if any_ok and (a_ok or keeps(enclose, M, C, cands, tr, end_lo[J], end_hi[J], a_zend, a_kept, work,
                                             space.work_box, space.slab_box, np.bool_(False))):
                    lo, best_next = mid, a_next
                else:
                    hi = mid
                continue
            j = s - 1
            space.c_ok[j], space.c_next[j], space.c_zend[j], space.c_kept[j] = a_ok, a_next, a_zend, a_kept
            space.c_in[j], space.c_bounded[j], space.c_c1[j] = v.in_c1, v.bounded, v.c1
            any_ok = any_ok or a_ok
            space.c_dist[j] = _distance(cands, j, space.pol, a_half)
            if s == J:
                best, bounded = _choose(enclose, M, C, T, cands, smooth, tr, t_next, space)
                best_next = space.c_next[best]
        if passed:
            continue
        lam = lo
        _blend(space, action, best, lam)
        if not any_ok:
            # np.int64: a literal 0 would compile _follow_plan once more
            best, best_next, lam, any_ok = _follow_plan(C, cands, action.cands_q, r, tr, xr, zr, plans, has_plans,
                                                        np.int64(best), best_next, lam, act, space.act_q,
                                                        space.c_next, new_plans)
            bounded = bounded or any_ok
        for i in range(m):
            if normalized:
                applied[r, i] = space.act_q[i] if bounded else action.fallback_q[i]
                chosen[r, i] = (cands[best, i] - a_mid[i]) / a_half[i]
            else:
                applied[r, i] = act[i] if bounded else action.fallback[i]
                chosen[r, i] = cands[best, i]
        nxt[r], certified[r], blend[r] = best_next, any_ok, lam
        reason[r] = ((BLEND if lam > 0 else OPTIMAL) if any_ok else UNCERTIFIED) if bounded else FALLBACK
        if not on_table(T.inside, tr, xr, max(zr, 0.0), work.point, work.buf, work.node):
            reason[r] = OUTSIDE


def _writable(v: np.ndarray) -> np.ndarray:
    """``v``, or a copy where read-only: numba compiles once per writability, so rows reach the loops writable (tables
    and cells read-only, :func:`~softreach.reach.proof.kernels.frozen`); only the rare read-only input is copied."""
    return v if v.flags.writeable else v.copy()


class _OneRow:
    """One thread's one-row inputs and outputs for :meth:`CompiledDecision.one`, their first rows as views (written
    and read without indexing at each call), and per kind of call the compiled code and its argument list."""

    def __init__(self, n: int, m: int):
        self.t, self.x, self.z, self.actions = np.empty(1), np.empty((1, n)), np.empty(1), np.empty((1, m))
        self.plan = np.empty((1, 3), np.int64)
        #: ``(applied, reason, value, next_value, certified, chosen, blend, new_plans)``
        self.outs = (np.empty((1, m)), np.empty(1, np.int64), np.empty(1), np.empty(1), np.empty(1, bool),
                     np.empty((1, m)), np.empty(1), np.empty((1, 3), np.int64))
        self.x0, self.action0, self.plan0 = self.x[0], self.actions[0], self.plan[0]
        self.applied0, self.chosen0, self.new_plan0 = self.outs[0][0], self.outs[5][0], self.outs[7][0]
        self.calls: dict[tuple, tuple] = {}


class CompiledDecision:
    """:func:`decide_rows` bound to one filter, whose model gives what it needs
    (:func:`~softreach.reach.proof.enclosure_check.lacking`)."""

    def __init__(self, vf: Any):
        la = vf.lookahead
        self.filter = vf
        #: the model's enclosure (an address) and its side of the one-period test
        self.enclose, self.M = motion(la)
        self.C = Cells(vf.landing_cells.kernel_args, vf.landing_cells.plan_args)
        self.T = TableArgs(*la.table_args)
        # a private writable copy: a candidate row has the type of a judged work array, so judge compiles once
        self.cands = np.array(la.candidates, dtype=np.float64, order="C")
        fallback = np.asarray(vf.fallback_action, dtype=np.float64)
        self.action = ActionMap(*(frozen(np.ascontiguousarray(v, dtype=np.float64)) for v in (
            la.a_mid, la.a_half, vf.a_lo, vf.a_hi, exact_normalized(self.cands, la.a_mid, la.a_half), fallback,
            exact_normalized(fallback, la.a_mid, la.a_half))))
        self.no_plans = np.zeros((1, 3), np.int64)
        self.args = plain((self.M, self.C, self.T, self.action))
        # one work space per thread: decide_rows writes into it
        self._local = threading.local()

    def __call__(self, t: np.ndarray, x: np.ndarray, z: np.ndarray, actions: np.ndarray, normalized: bool,
                 plans: np.ndarray | None, diagnostics: bool = True, with_policy: bool = True):
        """``(applied, reason, value, next_value, certified, chosen, blend, new_plans)`` for ``N`` rows (the policy's
        ``actions``, normalised where ``normalized``, else physical; ``plans`` the previous step's or ``None``;
        ``diagnostics``, ``with_policy`` as :func:`decide_rows`, which then decides by the switch rule)."""
        N, m = len(x), self.cands.shape[1]
        applied, chosen = np.empty((N, m)), np.empty((N, m))
        reason, new_plans = np.empty(N, np.int64), np.empty((N, 3), np.int64)
        value, nxt, certified, blend = np.empty(N), np.empty(N), np.empty(N, bool), np.empty(N)
        # the enclosure reads rows by address: contiguous rows
        t, x, z, actions = (_writable(np.ascontiguousarray(v, dtype=np.float64)) for v in (t, x, z, actions))
        plans = None if plans is None else _writable(np.ascontiguousarray(plans, dtype=np.int64))
        outs = (applied, reason, value, nxt, certified, chosen, blend, new_plans)
        rows = (t, x, z, actions, self.no_plans if plans is None else plans) + outs

        def run(lo: int, hi: int) -> None:
            # a block of rows; a whole batch goes unsliced (slicing costs about as much as deciding a row)
            block = rows if hi - lo == N else tuple(v if v is self.no_plans else v[lo:hi] for v in rows)
            decide_rows(*self._arguments(block, normalized, plans is not None, diagnostics, with_policy))

        # each thread in its own work space (decide_rows releases the GIL)
        run_in_blocks(run, N, self.filter.threads)
        return outs

    def one(self, t: float, x: np.ndarray, z: float, action: np.ndarray, normalized: bool, plan: np.ndarray | None,
            diagnostics: bool) -> _OneRow:
        """:meth:`__call__` of one row (``x`` and ``action`` float arrays, ``plan`` a ``(3,)`` int array or ``None``),
        in the calling thread, into this thread's one-row outputs (:class:`_OneRow`): valid until its next call, copy
        what is kept."""
        row = getattr(self._local, "row", None)
        if row is None:
            row = self._local.row = _OneRow(len(x), self.cands.shape[1])
        row.t[0], row.z[0] = t, z
        row.x0[:] = x
        row.action0[:] = action
        if plan is not None:
            row.plan0[:] = plan
        has_plan = plan is not None
        key = (has_plan, normalized, diagnostics, self.filter.rule, self.filter.smooth_iterations)
        call = row.calls.get(key)
        if call is None:
            # the whole argument list, made once per kind of call, and the compiled code it runs: one row's fixed
            # costs are mostly the call's
            rows = (row.t, row.x, row.z, row.actions, row.plan if has_plan else self.no_plans, *row.outs)
            args = self._arguments(rows, normalized, has_plan, diagnostics, True)
            decide_rows(*args)
            row.calls[key] = (entry_point(decide_rows, args), args)
        else:
            run, args = call
            run(*args)
        return row

    def _arguments(self, rows: tuple, normalized: bool, has_plans: bool, diagnostics: bool, with_policy: bool
                   ) -> tuple:
        """:func:`decide_rows`'s arguments for ``rows`` (``t, x, z, actions, plans``, the outputs), in this thread's
        work space, under the filter's rule now."""
        vf = self.filter
        M, C, T, action = self.args
        # bool(): an int or numpy flag would have numba compile the decision once more for its type
        return (self.enclose, M, C, T, self.cands, with_policy and vf.rule == "smooth", vf.smooth_iterations, action,
                *rows[:4], bool(normalized), rows[4], has_plans, diagnostics, with_policy, *rows[5:],
                self._space()[1])

    def certify(self, t: np.ndarray, x: np.ndarray, z: np.ndarray) -> tuple:
        """``(certified, next_value, value, inside)`` for ``N`` rows: the decision without a policy's action, whose
        candidates the switch rule ranks; certified where one passes or the state's landing cell has a plan."""
        actions = np.zeros((len(x), self.cands.shape[1]))
        _, reason, value, nxt, certified, _, _, _ = self(t, x, z, actions, False, None, True, with_policy=False)
        return certified, nxt, value, reason != OUTSIDE

    def start_plans(self, t: np.ndarray, x: np.ndarray, z: np.ndarray, periods: int, second: np.ndarray
                    ) -> np.ndarray:
        """Plans from start states themselves (docs/filters.md, 'A start's own plan'; :func:`start_plan_rows`), valid
        only as a run's first ``plan`` from its state, the second segment handed over as the first ends
        (:func:`~softreach.filters.plans.advance_plan`).

        :param periods: the most periods a plan holds, its segments together
        :param second: per row, whether to search two segments where one does not do
        :return: ``(N, START_SEGMENTS, 3)``, each segment ``(candidate, periods, PLAN_LAND)`` or ``NO_PLAN``"""
        out = np.empty((len(x), START_SEGMENTS, 3), np.int64)
        t, x, z = (_writable(np.ascontiguousarray(v, dtype=np.float64)) for v in (t, x, z))
        space = self._space()[0]
        M, C, _, _ = self.args
        start_plan_rows(self.enclose, M, C, self.cands, int(periods), t, x, z,
                        _writable(np.ascontiguousarray(second, dtype=np.bool_)), out, plain(space.work), space.boxes)
        return out

    def __getstate__(self) -> dict:
        # a thread's work space stays with the thread (and threading.local does not pickle)
        return {k: v for k, v in self.__dict__.items() if k != "_local"}

    def __setstate__(self, state: dict) -> None:
        self.__dict__.update(state)
        self._local = threading.local()

    def _space(self) -> tuple[DecisionSpace, tuple]:
        """This thread's work space for :func:`decide_rows`, made at its first call, named and as a plain tuple."""
        space = getattr(self._local, "space", None)
        if space is None:
            J, m = self.cands.shape
            space = self._local.space = decision_space(self.filter.lookahead.n, m, J)
        return space
