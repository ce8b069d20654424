"""A slow, readable reference of the safety filter's decision, transcribed from ``docs/filters.md`` ("The one-period
test", "Landing inside a period", "The filter with cells", "Sound to the last bit"): plain Python loops over one row
at a time, for tests only. The landing cells decide whether an action's end states pass; the table only ranks.

It shares with the filter only what is configuration or the model's, never the decision: the model's enclosure
(``held_boxes``, the model's own ``held_box_kernel``) and set functions, the cells' stored arrays, the table's
snapshots, and the filter's settings (candidates, period, allowances, rule). Everything the decision does with them is
written again here: the set maxima at box corners (``c1``, ``c2`` and the target are convex along each axis),
the budget charge piece by piece, whether a box lies in good cells, a cell's plan, the table's interpolant over a
box (by :func:`softreach.reach.tables.interpolation.interpolate` at the box's lattice points, the table's own
engine), the admissibility of an action, the rule's choice and the plans followed where no action is admissible.

The choice among candidates is made by lexicographic keys instead of the filter's numeric rank offsets
(``softreach.reach.proof.ranks``); where two keys lie within the interpolation's rounding of each other the
reference reports them as tied (:attr:`Decision.tied`), and either choice is right.
"""

from __future__ import annotations

import itertools
import math
from dataclasses import dataclass, field

import numpy as np

from softreach.filters.plans import NO_PLAN, PLAN_LAND, PLAN_SAFE
from softreach.filters.reasons import AFTER_HORIZON, BLEND, FALLBACK, OPTIMAL, OUTSIDE, PASS, UNCERTIFIED
from softreach.reach.proof.lookahead import exact_normalized
from softreach.reach.proof.model_kernels import held_boxes
from softreach.reach.tables.interpolation import interpolate

#: the table's box maximum is exact for boxes with at most this many grid nodes strictly inside, per axis
#: (``softreach.reach.proof.box_max.box_max``'s documented ``max_nodes``); wider boxes get the largest node value of
#: every cell they touch
MAX_NODES = 3
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
    proven: bool
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
        self.slack, self.budget_slack, self.first, self.exact_env = la.slack, la.budget_slack, la.first_check, \
            la.exact_env
        self.cands = np.asarray(la.candidates, dtype=np.float64)
        self.a_lo, self.a_hi = vf.a_lo, vf.a_hi
        self.a_mid, self.a_half = la.a_mid, la.a_half
        self.rule, self.iterations, self.fallback = vf.rule, vf.smooth_iterations, vf.fallback_action
        self.land, self.safe = vf.landing_cells, vf.safe_cells
        self.fields = la.fields
        tb = self.model.target_box
        self.target = None if tb is None else (np.asarray(tb[0], float), np.asarray(tb[1], float))

    # ------------------------------------------------------------ the model's enclosure and sets
    def boxes(self, lo, hi, a, s0, s1):
        b_lo, b_hi = held_boxes(self.model, lo[None], hi[None], np.asarray(a, float)[None], float(s0), float(s1))
        return b_lo[0], b_hi[0]

    def widened(self, lo, hi):
        """Every box compared with a set or a cell holds the environment's states: widened by the allowance."""
        return (lo - self.slack, hi + self.slack) if self.exact_env else (lo, hi)

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
        if self.exact_env:
            moved = self.set_max("hard_constraint", *self.widened(*self.boxes(lo, hi, a, min(self.first, length),
                                                                               length)))
            c1 = moved if (math.isnan(moved) or moved > c1) else c1
        return c1

    def may_spend(self, lo, hi, a, length, tube_lo, tube_hi):
        if not self.set_max("soft_constraint", tube_lo, tube_hi) <= 0:
            return True
        if not self.exact_env:
            return False
        return not self.set_max("soft_constraint", *self.widened(*self.boxes(lo, hi, a, min(0.5 * self.first, length),
                                                                              length))) <= 0

    def spent(self, lo, hi, a, length):
        """Each of the ``P`` pieces of ``[0, length]`` charged ``length / P`` times the largest ``h_eps`` over its
        widened box; the rounding allowance where the charge is positive."""
        edges = np.linspace(0.0, length, self.P + 1)
        out = 0.0
        for j in range(self.P):
            p_lo, p_hi = self.widened(*self.boxes(lo, hi, a, edges[j], edges[j + 1]))
            out += (length / self.P) * min(max(self.set_max("soft_constraint", p_lo, p_hi) / self.eps, 0.0), 1.0)
        return out + self.budget_slack if out > 0 else out

    # ------------------------------------------------------------ cells
    @staticmethod
    def _span(cells, lo, hi):
        """Per axis the first and last cell a closed box touches, and whether it lies on the cell grid."""
        spans, on = [], True
        for i in range(len(lo)):
            f = math.floor((lo[i] - cells.lo[i]) / cells.width[i]) if math.isfinite(lo[i]) else math.nan
            g = math.floor((hi[i] - cells.lo[i]) / cells.width[i]) if math.isfinite(hi[i]) else math.nan
            if hi[i] == cells.hi[i]:
                g = cells.shape[i] - 1  # a box reaching the grid's upper end touches the last cell only
            if not (math.isfinite(f) and math.isfinite(g) and f >= 0 and g <= cells.shape[i] - 1):
                on = False
                f = g = 0
            f = min(f, cells.shape[i] - 1)  # a box starting on the grid's upper end lies in the last cell
            spans.append((int(f), max(int(f), int(g))))
        return spans, on

    @staticmethod
    def _sample(cells, t):
        """The safe game's sample at or before ``t``, the landing game's at or after it."""
        r = t / cells.dt
        k = math.floor(r + 1e-9) if cells.game == "safe" else math.ceil(r - 1e-9)
        return min(max(k, 0), cells.steps)

    def covered(self, cells, t, lo, hi, z):
        """Every cell the box touches at ``t`` is good at the budget cell holding ``z``."""
        spans, on = self._span(cells, lo, hi)
        if not on or not t <= cells.horizon + 1e-9 * cells.dt or not z >= 0:
            return False
        j = math.floor(min(z, cells.top * cells.dz) / cells.dz + 1e-12)
        if j * cells.dz > z:
            j -= 1
        block = np.asarray(cells.m[self._sample(cells, t)])[tuple(slice(f, g + 1) for f, g in spans)]
        return bool((block.astype(np.int64) <= j).all())

    def cell_plan(self, cells, t, x):
        spans, on = self._span(cells, x, x)
        if not on:
            return -1, 0
        k = self._sample(cells, t)
        idx = tuple(f for f, _ in spans)
        j = int(np.asarray(cells.action[k])[idx])
        return (j, int(np.asarray(cells.hold[k])[idx])) if j >= 0 else (-1, 0)

    # ------------------------------------------------------------ the table
    def box_max(self, name, t, lo, hi):
        """The largest value of the field's interpolant over the box at time ``t``: at the box's lattice points
        (its ends and the grid nodes strictly inside, per axis) where each axis holds at most :data:`MAX_NODES`
        nodes, else the largest node of the cells it touches at the snapshots around ``t``; ``+inf`` off the grid."""
        values, times, grid = self.fields[name]
        glo, ghi = np.asarray(grid.lo, float), np.asarray(grid.hi, float)
        shape, h, periodic = np.asarray(grid.shape), np.asarray(grid.spacing, float), grid.periodic
        axes, wide = [], False
        for i in range(len(lo)):
            s_lo, s_hi = (lo[i] - glo[i]) / h[i], (hi[i] - glo[i]) / h[i]
            tol = 1e-9 * max(1.0, shape[i])
            if not periodic[i] and not (s_lo >= -tol and s_hi <= shape[i] - 1 + tol):
                return math.inf
            inner = list(range(math.floor(s_lo) + 1, math.ceil(s_hi)))
            wide = wide or len(inner) > MAX_NODES
            axes.append((s_lo, s_hi, inner))
        if wide:
            k = min(max(int(np.searchsorted(times, t, side="right")) - 1, 0), len(times) - 2)
            wt = min(max((t - times[k]) / (times[k + 1] - times[k]), 0.0), 1.0)
            snaps = [k, k + 1] if wt > 0 else [k]
            nodes = []
            for i, (a, b, _) in enumerate(axes):
                if periodic[i]:  # every node the box touches, wrapped (at most the whole ring)
                    nodes.append(sorted({n % shape[i] for n in range(math.floor(a), math.ceil(b) + 1)}))
                else:
                    nodes.append(list(range(max(math.floor(a), 0), min(math.ceil(b), shape[i] - 1) + 1)))
            return float(max(np.asarray(values[s])[np.ix_(*nodes)].max() for s in snaps))
        # the box's ends and the nodes strictly between (unwrapped along a periodic axis: the engine wraps them)
        points = [[lo[i]] + [glo[i] + n * h[i] for n in inner] + [hi[i]] for i, (_, _, inner) in enumerate(axes)]
        pts = np.array(list(itertools.product(*points)), dtype=np.float64)
        pts = np.where(np.asarray(periodic, bool), pts, np.clip(pts, glo, ghi))
        v, _ = interpolate(values, times, grid, np.full(len(pts), t), pts)
        return float(np.max(v)) if not np.isnan(v).any() else math.nan

    def next_value(self, t_next, end_lo, end_hi, z_end, z_hi):
        """The worst certificate ``min(max W_eps, max V)`` over the end box and the budgets ``[z_end, z_hi]``
        (``V`` only at a budget kept); ``+inf`` where the table has no number."""
        _, _, w_grid = self.fields["W_eps"]
        z_floor, z_top = float(w_grid.lo[-1]), float(w_grid.hi[-1])
        z_lo = max(z_end, z_floor)
        best = self.box_max("W_eps", t_next, np.r_[end_lo, z_lo], np.r_[end_hi, max(min(z_hi, z_top), z_lo)])
        if "V" in self.fields and z_end >= 0 and not math.isnan(best):
            v = self.box_max("V", t_next, end_lo, end_hi)
            best = math.nan if math.isnan(v) else min(best, v)
        return math.inf if math.isnan(best) else best

    def safe_value_keeps(self, t_next, end_lo, end_hi):
        """``V_safe <= 0`` over the end box (true where the table has no ``V_safe``)."""
        return "V_safe" not in self.fields or self.box_max("V_safe", t_next, end_lo, end_hi) <= 0

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
        return math.isfinite(self.box_max("W_eps", t, np.r_[x, min(z, Wg.hi[-1])], np.r_[x, min(z, Wg.hi[-1])]))

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
        safe_end = kept and (self.safe is None or self.covered(self.safe, t_next, end_lo, end_hi, z_end))
        ok = safe_end and self.covered(self.land, t_next, end_lo, end_hi, z_end)
        lands = False
        if not ok and bounded and in_time and self._meets_target(tube_lo, tube_hi):
            lands = self._lands(lo, hi, z, a)
        return Judged(bounded, in_c1, kept, ok, lands, safe_end and self.safe is not None, c1, z_end, t_next,
                      end_lo, end_hi)

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

    def keeps(self, t, v: Judged, z) -> bool:
        """The next state is certified whatever the wind does: where the action passes (its end lies in landing
        cells, or it surely lands); else where its period keeps ``C1`` and the budget before the horizon and one
        candidate passes from every state of its end box."""
        if v.passes:
            return True
        last = t + self.dt >= self.horizon - 1e-9 * max(1.0, self.horizon)
        if not v.kept or last:
            return False
        z_lo = max(v.z_end, 0.0)
        return any(self.judge(t + self.dt, v.end_lo, v.end_hi, z_lo, c).passes for c in self.cands)

    def _next(self, v: Judged, z):
        """The next value the filter reports for an action: ``-inf`` where it lands; the table's over its end box
        where it passes, ``+inf`` otherwise."""
        if v.lands:
            return -math.inf
        return self.next_value(v.t_next, v.end_lo, v.end_hi, v.z_end, z) if v.ok else math.inf

    def _bad_key(self, v: Judged, z):
        """Where no candidate passes: end in safe cells first, then ``V_safe`` keeps the end box, then the rest;
        budget kept before overspent; within those the lower next value, then the smaller overspend; then those
        that may leave ``C1``, the least far first; last those the enclosure cannot bound."""
        if not v.bounded:
            return (7, 0.0)
        if not v.in_c1:
            return (6, max(v.c1, 0.0))
        nxt = self.next_value(v.t_next, v.end_lo, v.end_hi, v.z_end, z)
        tie = math.atan(1e12 if nxt == math.inf else nxt) / math.pi + 1e3 * max(-v.z_end, 0.0)
        if v.proven:
            return (0, tie)
        cls = 1 if self.safe_value_keeps(v.t_next, v.end_lo, v.end_hi) else 3
        return (cls + (0 if v.kept else 1), tie)

    def blend(self, j, pol, lam):
        q = exact_normalized(self.cands[j], self.a_mid, self.a_half)
        return self.a_mid + self.a_half * (q + lam * ((pol - self.a_mid) / self.a_half - q))

    # ------------------------------------------------------------ the decision
    def decide(self, t, x, z, pol, plan=None) -> Decision:
        x = np.asarray(x, dtype=np.float64)
        pol = np.minimum(np.maximum(np.asarray(pol, dtype=np.float64), self.a_lo), self.a_hi)
        after = t >= self.horizon - 1e-9
        v = self.judge(t, x, x, z, pol)
        if self.keeps(t, v, z):
            nxt = self._next(v, z)
            return Decision(pol, AFTER_HORIZON if after else PASS, not after, -1, 1.0, nxt, NO_PLAN)
        J = len(self.cands)
        judged = [self.judge(t, x, x, z, c) for c in self.cands]
        any_ok = any(c.passes for c in judged)
        tied: set = set()
        if self.rule == "switch" and any_ok:
            # the passing candidate of lowest next value that keeps the next state certified, else of lowest next value
            keys = {j: self._next(judged[j], z) for j in range(J) if judged[j].passes}
            order = sorted(keys, key=lambda j: (keys[j], j))
            best = next((j for j in order if self.keeps(t, judged[j], z)), order[0])
            tied = {j for j in keys if _close(keys[j], keys[best])}
            best_bad = keys[best]
            best_next = keys[best]
        else:
            keeping = -1
            if self.rule == "smooth":
                dist = [float(np.linalg.norm((c - pol) / self.a_half)) for c in self.cands]
                for j in sorted((j for j in range(J) if judged[j].passes or judged[j].kept), key=lambda j: dist[j]):
                    if self.keeps(t, judged[j], z):
                        keeping = j
                        break
            if keeping >= 0:
                best = keeping
                best_next = self._next(judged[best], z)
                best_bad = best_next if judged[best].passes else self._bad_key(judged[best], z)
            elif any_ok:  # the smooth rule, where no passing candidate keeps: the nearest passing one
                best = min((j for j in range(J) if judged[j].passes), key=lambda j: (dist[j], j))
                best_next = best_bad = self._next(judged[best], z)
            else:
                keys = {j: self._bad_key(judged[j], z) for j in range(J)}
                best = min(keys, key=lambda j: (keys[j], j))
                tied = {j for j in keys if keys[j][0] == keys[best][0] and _close(keys[j][1], keys[best][1])}
                best_next, best_bad = self._next(judged[best], z), keys[best]
        lam = 0.0
        if self.rule == "smooth" and self.iterations:
            lo, hi = 0.0, 1.0
            for _ in range(self.iterations):
                mid = 0.5 * (lo + hi)
                b = self.judge(t, x, x, z, self.blend(best, pol, mid))
                if any_ok and self.keeps(t, b, z):
                    lo, best_next = mid, self._next(b, z)
                else:
                    hi = mid
            lam = lo
        act = self.blend(best, pol, lam)
        new_plan = NO_PLAN
        # the safe cells' plan where the choice's end is not proven safe (a passing choice with a finite next
        # value, or one ending in safe cells, is)
        proven_or_better = best_bad < math.inf if isinstance(best_bad, float) else best_bad[0] == 0
        for game, cells, weak in ((PLAN_LAND, self.land, not any_ok), (PLAN_SAFE, self.safe, None)):
            if game == PLAN_SAFE:
                weak = not proven_or_better
            if cells is None or not weak:
                continue
            if plan is not None and plan[1] > 0 and 0 <= plan[0] < J and plan[2] == game:
                jj, left = int(plan[0]), int(plan[1]) - 1
            else:
                cj, ck = self.cell_plan(cells, t, x)
                if not (0 <= cj < J and self.covered(cells, t, x, x, z)):
                    continue
                jj, left = cj, ck - 1
            best, act, lam, tied = jj, self.cands[jj].copy(), 0.0, set()
            best_next = self._next(judged[jj], z) if judged[jj].passes else math.inf
            new_plan = (jj, left, game)
            proven_or_better, best_bad = True, -1.0
            if game == PLAN_LAND:
                any_ok = True
        bounded = best_bad != (7, 0.0) and best_bad != math.inf
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
