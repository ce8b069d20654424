"""A slow, readable reference of the safety filter's decision, transcribed from ``docs/filters.md`` ("The one-period
test", "Landing inside a period", "The filter with cells", "Sound to the last bit"): plain Python loops over one row
at a time, for tests only. The landing cells decide whether an action's end states pass; the table only ranks.

It shares with the filter only what is configuration or the model's, never the decision: the model's enclosure
(``held_boxes``, the model's own ``held_box_kernel``) and set functions, the cells' stored arrays, the table's
snapshots, and the filter's settings (candidates, period, allowances, rule). Everything the decision does with them is
written again here: the set maxima at box corners (``c1``, ``c2`` and the target are convex along each axis),
the budget charge piece by piece, whether a box lies in good cells, a cell's plan, the table's value at a box's
centre (by :func:`softreach.reach.tables.interpolation.interpolate`, the table's own engine), the admissibility of
an action, the rule's choice and the plans followed where no action is admissible.

The choice among candidates is made by lexicographic keys instead of the filter's numeric rank offsets
(``softreach.filters.reasons``); where two keys lie within the interpolation's rounding of each other the
reference reports them as tied (:attr:`Decision.tied`), and either choice is right.
"""

from __future__ import annotations

import itertools
import math
from dataclasses import dataclass, field

import numpy as np

from softreach.filters.plans import NO_PLAN, PLAN_LAND
from softreach.filters.reasons import AFTER_HORIZON, BLEND, FALLBACK, OPTIMAL, OUTSIDE, PASS, UNCERTIFIED
from softreach.reach.proof.kernels import WRAP_ULPS
from softreach.reach.proof.lookahead import exact_normalized
from softreach.reach.proof.model_kernels import held_boxes
from softreach.reach.tables.interpolation import interpolate

#: the slab cover of an end box (docs/filters.md, "The rule"): bisection steps for a slab's upper edge, most slabs
SLAB_STEPS, MAX_SLABS = 8, 4
#: relative closeness below which two keys count as tied: the interpolation's rounding, far below any difference
#: between values that decides
TIE = 1e-9


@dataclass
class Judged:
    """One held action judged by the one-period test from a box of starts."""

    bounded: bool
    in_c1: bool
    kept: bool
    ok: bool
    lands: bool
    c1: float
    z_end: float
    t_next: float
    end_lo: np.ndarray
    end_hi: np.ndarray

    @property
    def passes(self) -> bool:
        return self.ok or self.lands


@dataclass
class Decision:
    """The reference's decision of one row (the entries of ``ValueFilter.filter``'s info)."""

    applied: np.ndarray
    reason: int
    certified: bool
    chosen: int  # candidate index, -1 where the policy's action passed
    blend: float
    lookahead: float
    plan: tuple
    tied: set = field(default_factory=set)  # candidates whose keys tie the chosen one's


class ReferenceDecision:
    """The decision of ``vf`` (a :class:`~softreach.filters.ValueFilter` of a ``W_eps`` table), row by row."""

    def __init__(self, vf):
        la = vf.lookahead
        self.model, self.dt, self.eps = vf.model, la.dt, la.eps
        self.P, self.checks, self.horizon = la.pieces, la.target_checks, la.horizon
        self.slack, self.stage_slack, self.budget_slack = la.slack, la.stage_slack, la.budget_slack
        self.first, self.env_covered = la.first_check, la.env_covered
        self.cands = np.asarray(la.candidates, dtype=np.float64)
        self.a_lo, self.a_hi = vf.a_lo, vf.a_hi
        self.a_mid, self.a_half = la.a_mid, la.a_half
        self.rule, self.iterations, self.fallback = vf.rule, vf.smooth_iterations, vf.fallback_action
        self.land = vf.landing_cells
        self.fields = la.fields
        tb = self.model.target_box
        self.target = None if tb is None else (np.asarray(tb[0], float), np.asarray(tb[1], float))

    # ------------------------------------------------------------ the model's enclosure and sets
    def boxes(self, lo, hi, a, s0, s1):
        b_lo, b_hi = held_boxes(self.model, lo[None], hi[None], np.asarray(a, float)[None], float(s0), float(s1))
        return b_lo[0], b_hi[0]

    def widened(self, lo, hi, stages=False):
        """Every box compared with a set or a cell holds the environment's states: widened by the allowance; a box
        the budget's rate is read over holds its stage states too: widened by their allowance."""
        slack = self.stage_slack if stages else self.slack
        return (lo - slack, hi + slack) if self.env_covered else (lo, hi)

    def set_max(self, name, lo, hi):
        """The largest value of the model's set function over the box: the model's own bound where it gives one
        (``set_box_max``: sets not convex along each axis, as Dubins's obstacle), else at a corner."""
        bound = self.model.set_box_max(name, 0.0, np.asarray(lo, float)[None], np.asarray(hi, float)[None])
        if bound is not None:
            return float(bound[0])
        fn = getattr(self.model, name)
        best = -np.inf
        for corner in itertools.product((0, 1), repeat=len(lo)):
            v = float(np.asarray(fn(0.0, [np.float64(hi[i] if c else lo[i]) for i, c in enumerate(corner)])))
            if math.isnan(v):
                return math.nan
            best = max(best, v)
        return best

    def c1_over(self, lo, hi, a, length, tube_lo, tube_hi):
        """``max c1`` over the exact tube, and over the widened box of the states the env checks (from its first
        check instant on)."""
        c1 = self.set_max("hard_constraint", tube_lo, tube_hi)
        if self.env_covered:
            moved = self.set_max("hard_constraint", *self.widened(*self.boxes(lo, hi, a, min(self.first, length),
                                                                               length)))
            c1 = moved if (math.isnan(moved) or moved > c1) else c1
        return c1

    def may_spend(self, lo, hi, a, length, tube_lo, tube_hi):
        if not self.set_max("soft_constraint", tube_lo, tube_hi) <= 0:
            return True
        if not self.env_covered:
            return False
        return not self.set_max("soft_constraint", *self.widened(*self.boxes(lo, hi, a, min(0.5 * self.first, length),
                                                                              length), stages=True)) <= 0

    def spent(self, lo, hi, a, length):
        """Each of the ``P`` pieces of ``[0, length]`` charged ``length / P`` times the largest ``h_eps`` over its
        box widened for the stage states; the rounding allowance where the charge is positive."""
        edges = np.linspace(0.0, length, self.P + 1)
        out = 0.0
        for j in range(self.P):
            p_lo, p_hi = self.widened(*self.boxes(lo, hi, a, edges[j], edges[j + 1]), stages=True)
            out += (length / self.P) * min(max(self.set_max("soft_constraint", p_lo, p_hi) / self.eps, 0.0), 1.0)
        return out + self.budget_slack if out > 0 else out

    # ------------------------------------------------------------ cells
    @staticmethod
    def _held(cells, i, v, c, first, last):
        """Cell ``c`` of axis ``i`` (``floor``'s guess for ``v``) moved, within ``[first, last]``, to a neighbour
        while its float box, ``lo + c width`` to ``lo + (c + 1) width`` as the builder computes it, misses ``v``."""
        def edge(k):
            return cells.lo[i] + k * cells.width[i]
        while c > first and edge(c) > v:
            c -= 1
        while c < last and edge(c + 1) < v:
            c += 1
        return c

    @classmethod
    def _span(cls, cells, lo, hi, wrapped=False):
        """Per axis the cells a closed box touches, and whether it lies on the cell grid: from the cell whose float
        box holds its lower end to the one whose float box holds its upper end (``floor``'s guess, moved where the
        quotient rounded across an edge). Along a periodic axis the box is first widened by ``WRAP_ULPS`` ulps of
        the period, unless it is a state the environment has ``wrapped`` already (a state it wraps from the box then
        lies in a touched cell), and the cells run past either end of the grid, up to a period, onto those one
        period on: their indices modulo the axis's cells."""
        spans, on = [], True
        for i in range(len(lo)):
            n = cells.shape[i]
            if cells.periodic[i] and math.isfinite(lo[i]) and math.isfinite(hi[i]):
                pad = 0.0 if wrapped else WRAP_ULPS * np.spacing(cells.hi[i] - cells.lo[i])
                a, b = lo[i] - pad, hi[i] + pad
                f, g = (math.floor((v - cells.lo[i]) / cells.width[i]) for v in (a, b))
                if -n <= f and g < 2 * n:  # else off the grid, below
                    f, g = cls._held(cells, i, a, f, -n, 2 * n - 1), cls._held(cells, i, b, g, -n, 2 * n - 1)
                    spans.append(sorted({c % n for c in range(f, min(g, f + n - 1) + 1)}))
                    continue
            if not (cells.lo[i] <= lo[i] and hi[i] <= cells.lo[i] + n * cells.width[i]):
                on = False
                spans.append([0])
                continue
            f, g = (min(math.floor((v - cells.lo[i]) / cells.width[i]), n - 1) for v in (lo[i], hi[i]))
            f, g = cls._held(cells, i, lo[i], f, 0, n - 1), cls._held(cells, i, hi[i], g, 0, n - 1)
            spans.append(list(range(f, max(f, g) + 1)))
        return spans, on

    @staticmethod
    def _sample(cells, t):
        """The sample at or after ``t``: a plan that lands by ``T`` from it lands by ``T`` from ``t``."""
        return min(max(math.ceil(t / cells.dt - 1e-9), 0), cells.steps)

    def covered(self, cells, t, lo, hi, z):
        """Every cell the box touches at ``t`` is good at the budget cell holding ``z``."""
        spans, on = self._span(cells, lo, hi)
        if not on or not t <= cells.horizon + 1e-9 * cells.dt or not z >= 0:
            return False
        j = math.floor(min(z, cells.top * cells.dz) / cells.dz + 1e-12)
        if j * cells.dz > z:
            j -= 1
        block = np.asarray(cells.m[self._sample(cells, t)])[np.ix_(*spans)]
        return bool((block.astype(np.int64) <= j).all())

    def cell_plan(self, cells, t, x):
        spans, on = self._span(cells, x, x, wrapped=True)
        if not on:
            return -1, 0
        k = self._sample(cells, t)
        idx = tuple(touched[0] for touched in spans)
        j = int(np.asarray(cells.action[k])[idx])
        return (j, int(np.asarray(cells.hold[k])[idx])) if j >= 0 else (-1, 0)

    # ------------------------------------------------------------ the table
    def next_value(self, t_next, end_lo, end_hi, z_end):
        """The certificate ``D`` at the end box's centre at the budget ``z_end`` (``+inf`` off the table)."""
        return self.certificate(t_next, 0.5 * (np.asarray(end_lo, float) + np.asarray(end_hi, float)), z_end)

    def certificate(self, t, x, z):
        """``D = min(W_eps(x, min(z, z_top)), V(x))`` at the state (``+inf`` off the table)."""
        W, Wt, Wg = self.fields["W_eps"]
        if not (Wt[0] - 1e-9 <= t <= Wt[-1] + 1e-9):
            return math.inf
        w, inside = interpolate(W, Wt, Wg, np.array([t]), np.r_[x, min(z, Wg.hi[-1])][None])
        out = float(w[0]) if (inside[0] and z >= Wg.lo[-1] and math.isfinite(w[0])) else math.inf
        if "V" in self.fields:
            V, Vt, Vg = self.fields["V"]
            v, vin = interpolate(V, Vt, Vg, np.array([t]), np.asarray(x, float)[None])
            if vin[0] and z >= 0 and math.isfinite(v[0]):
                out = min(out, float(v[0]))
        return out

    def on_table(self, t, x, z):
        W, Wt, Wg = self.fields["W_eps"]
        if not (Wt[0] - 1e-9 <= t <= Wt[-1] + 1e-9) or not z >= Wg.lo[-1]:
            return False
        w, inside = interpolate(W, Wt, Wg, np.array([t]), np.r_[x, min(z, Wg.hi[-1])][None])
        return bool(inside[0]) and math.isfinite(w[0])

    # ------------------------------------------------------------ the one-period test
    def judge(self, t, lo, hi, z, a) -> Judged:
        """Holding ``a`` for one period from every state of ``[lo, hi]`` at budget ``z``."""
        dt = self.dt
        tube_lo, tube_hi = self.boxes(lo, hi, a, 0.0, dt)
        end_lo, end_hi = self.widened(*self.boxes(lo, hi, a, dt, dt))
        bounded = bool(np.isfinite(tube_lo).all() and np.isfinite(tube_hi).all())
        c1 = self.c1_over(lo, hi, a, dt, tube_lo, tube_hi)
        z_end = z - self.spent(lo, hi, a, dt) if self.may_spend(lo, hi, a, dt, tube_lo, tube_hi) else z
        in_time = t + dt <= self.horizon + 1e-9 * max(1.0, self.horizon)
        t_next = min(t + dt, self.horizon)
        in_c1 = bounded and c1 <= 0 and in_time
        kept = in_c1 and z_end >= 0
        ok = kept and self.covered(self.land, t_next, end_lo, end_hi, z_end)
        lands = False
        if not ok and bounded and in_time and self._meets_target(tube_lo, tube_hi):
            lands = self._lands(lo, hi, z, a)
        return Judged(bounded, in_c1, kept, ok, lands, c1, z_end, t_next, end_lo, end_hi)

    def _meets_target(self, lo, hi):
        if self.target is None:
            return True
        return bool(((hi >= self.target[0]) & (lo <= self.target[1])).all())

    def _lands(self, lo, hi, z, a):
        """At some check instant ``s`` every run is in the target inside ``C2``, the motion until ``s`` kept ``C1``
        and the budget spent until ``s`` is at most ``z``."""
        for j in range(1, self.checks + 1):
            s = self.dt * j / self.checks
            s_lo, s_hi = self.boxes(lo, hi, a, 0.0, s)
            if not (np.isfinite(s_lo).all() and np.isfinite(s_hi).all()):
                continue
            e_lo, e_hi = self.widened(*self.boxes(lo, hi, a, s, s))
            if not (self.set_max("target", e_lo, e_hi) <= 0 and self.set_max("soft_constraint", e_lo, e_hi) <= 0):
                continue
            if not self.c1_over(lo, hi, a, s, s_lo, s_hi) <= 0:
                continue
            cost = self.spent(lo, hi, a, s) if self.may_spend(lo, hi, a, s, s_lo, s_hi) else 0.0
            if z - cost >= 0:
                return True
        return False

    def keeps(self, t, v: Judged, z, slabs=False) -> bool:
        """The next state is certified whatever the wind does: where the action passes (its end lies in landing
        cells, or it surely lands); else where its period keeps ``C1`` and the budget before the horizon and one
        candidate passes from every state of its end box, or (``slabs``: the policy's own action) slabs of it each
        are certified (:meth:`slabs_cover`)."""
        if v.passes:
            return True
        last = t + self.dt >= self.horizon - 1e-9 * max(1.0, self.horizon)
        if not v.kept or last:
            return False
        z_lo = max(v.z_end, 0.0)
        return (any(self.judge(t + self.dt, v.end_lo, v.end_hi, z_lo, c).passes for c in self.cands)
                or (slabs and self.slabs_cover(t + self.dt, v.end_lo, v.end_hi, z_lo)))

    def slab_certified(self, t, lo, hi, z, j):
        """Every state of the box is certified at ``t`` with ``z`` left: candidate ``j`` passes from all of it, or
        (``j = -1``) it lies in the landing cells."""
        if j >= 0:
            return self.judge(t, lo, hi, z, self.cands[j]).passes
        return self.covered(self.land, min(t, self.horizon), lo, hi, z)

    def slabs_cover(self, t, end_lo, end_hi, z):
        """At most :data:`MAX_SLABS` slabs ``[a, b] x`` (the end box's other axes), consecutive along the first
        axis from ``end_lo[0]`` to ``end_hi[0]``, each certified (:meth:`slab_certified`) by one option (the cells,
        then each candidate), found greedily: each slab's upper edge is the largest that :data:`SLAB_STEPS`
        bisection steps find over the options that are certified on the slab so far; where both corners of the
        box are not certified by some option, none is sought."""
        options = range(-1, len(self.cands))

        def slab(a, b):
            lo, hi = np.array(end_lo, float), np.array(end_hi, float)
            lo[0], hi[0] = a, b
            return lo, hi

        for corner in (end_lo, end_hi):
            if not any(self.slab_certified(t, corner, corner, z, j) for j in options):
                return False
        cur, top = end_lo[0], end_hi[0]
        for k in range(MAX_SLABS):
            best = cur
            for j in options:
                if not self.slab_certified(t, *slab(cur, best), z, j):
                    continue
                if k > 0 and self.slab_certified(t, *slab(cur, top), z, j):
                    return True
                good, bad = best, top
                for _ in range(SLAB_STEPS):
                    mid = 0.5 * (good + bad)
                    if self.slab_certified(t, *slab(cur, mid), z, j):
                        good = mid
                    else:
                        bad = mid
                best = max(best, good)
            if not best > cur:
                return False
            cur = best
        return False

    def _next(self, v: Judged):
        """The next value the filter reports for an action: ``-inf`` where it lands; :meth:`next_value`, the table's
        at its end box's centre, where it passes; ``+inf`` otherwise."""
        if v.lands:
            return -math.inf
        return self.next_value(v.t_next, v.end_lo, v.end_hi, v.z_end) if v.ok else math.inf

    def _bad_key(self, v: Judged):
        """Where no candidate passes: budget kept before overspent; within those the lower next value, then the
        smaller overspend; then those that may leave ``C1``, the least far first; last those the enclosure cannot
        bound."""
        if not v.bounded:
            return (3, 0.0)
        if not v.in_c1:
            return (2, max(v.c1, 0.0))
        nxt = self.next_value(v.t_next, v.end_lo, v.end_hi, v.z_end)
        tie = math.atan(1e12 if nxt == math.inf else nxt) / math.pi + 1e3 * max(-v.z_end, 0.0)
        return (0 if v.kept else 1, tie)

    def blend(self, j, pol, lam):
        q = exact_normalized(self.cands[j], self.a_mid, self.a_half)
        return self.a_mid + self.a_half * np.clip(q + lam * ((pol - self.a_mid) / self.a_half - q), -1.0, 1.0)

    # ------------------------------------------------------------ the decision
    def decide(self, t, x, z, pol, plan=None) -> Decision:
        x = np.asarray(x, dtype=np.float64)
        pol = np.minimum(np.maximum(np.asarray(pol, dtype=np.float64), self.a_lo), self.a_hi)
        after = t >= self.horizon - 1e-9
        v = self.judge(t, x, x, z, pol)
        if self.keeps(t, v, z, slabs=True):
            return Decision(pol, AFTER_HORIZON if after else PASS, not after, -1, 1.0, self._next(v), NO_PLAN)
        J = len(self.cands)
        judged = [self.judge(t, x, x, z, c) for c in self.cands]
        any_ok = any(c.passes for c in judged)
        dist = [float(np.linalg.norm((c - pol) / self.a_half)) for c in self.cands]
        tied: set = set()
        keeping = -1
        if self.rule == "switch" and any_ok:
            # the passing candidate of lowest next value (a passing one keeps the next state certified)
            keys = {j: self._next(judged[j]) for j in range(J) if judged[j].passes}
            keeping = min(keys, key=lambda j: (keys[j], j))
            tied = {j for j in keys if _close(keys[j], keys[keeping])}
        elif self.rule == "smooth":
            # the nearest candidate to the policy's action that passes, or keeps the next state certified
            for j in sorted((j for j in range(J) if judged[j].passes or judged[j].kept), key=lambda j: dist[j]):
                if self.keeps(t, judged[j], z):
                    keeping = j
                    break
        bounded = True
        if keeping >= 0:
            best = keeping
        elif any_ok:  # the smooth rule, where no passing candidate keeps: the nearest passing one
            best = min((j for j in range(J) if judged[j].passes), key=lambda j: (dist[j], j))
        else:
            keys = {j: self._bad_key(judged[j]) for j in range(J)}
            best = min(keys, key=lambda j: (keys[j], j))
            tied = {j for j in keys if keys[j][0] == keys[best][0] and _close(keys[j][1], keys[best][1])}
            bounded = keys[best] != (4, 0.0)
        best_next = self._next(judged[best])
        lam = 0.0
        if self.rule == "smooth" and self.iterations:
            lo, hi = 0.0, 1.0
            for _ in range(self.iterations):
                mid = 0.5 * (lo + hi)
                b = self.judge(t, x, x, z, self.blend(best, pol, mid))
                if any_ok and self.keeps(t, b, z):
                    lo, best_next = mid, self._next(b)
                else:
                    hi = mid
            lam = lo
        act = self.blend(best, pol, lam)
        new_plan = NO_PLAN
        # where no candidate passes: the plan followed, else the landing cell's plan
        jj = -1
        if any_ok:
            pass
        elif plan is not None and plan[1] > 0 and 0 <= plan[0] < J and plan[2] == PLAN_LAND:
            jj, left = int(plan[0]), int(plan[1]) - 1
        else:
            cj, ck = self.cell_plan(self.land, t, x)
            if 0 <= cj < J and self.covered(self.land, t, x, x, z):
                jj, left = cj, ck - 1
        if jj >= 0:
            best, act, lam, tied, bounded = jj, self.cands[jj].copy(), 0.0, set(), True
            best_next = self._next(judged[jj])
            new_plan = (jj, left, PLAN_LAND)
            any_ok = True
        reason = ((BLEND if lam > 0 else OPTIMAL) if any_ok else UNCERTIFIED) if bounded else FALLBACK
        if not self.on_table(t, x, max(z, 0.0)):
            reason = OUTSIDE
        if after:
            reason = AFTER_HORIZON
        return Decision(act if bounded else self.fallback.copy(), reason, any_ok and not after, best, lam, best_next,
                        new_plan, tied)

    def certified(self, t, x, z) -> bool:
        """``ValueFilter.certify``: in a landing cell, or some candidate's period passes."""
        x = np.asarray(x, dtype=np.float64)
        if t >= self.horizon - 1e-9 or not self.on_table(t, x, max(z, 0.0)):
            return False
        in_cell = self.covered(self.land, t, x, x, z)
        return in_cell or any(self.judge(t, x, x, z, c).passes for c in self.cands)


def _close(a: float, b: float) -> bool:
    if a == b:
        return True
    return math.isfinite(a) and math.isfinite(b) and abs(a - b) <= TIE * max(1.0, abs(a), abs(b))
