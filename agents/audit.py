"""An adversarial audit of the safety filter: policies and winds nobody tuned to, from certified starts and others.

Each episode runs the filter at its control period and integrates with the environments' own integrator
(:func:`softreach.reach.sim.integrator.integrate_period`), but splits every period into ``pieces`` sub-intervals so that
the wind can switch *inside* a period; the hard constraint is checked at every sub-interval end (and the budget
accounts for every crossing of ``C2``, as the environment does). Landing is checked where the environment
checks it, at its sub-step ends (``ValueFilter.target_checks``), and the first event ends the episode. Counted
per row: hard violations, overspends (budget used beyond ``Q``), landings, the fraction of steps the policy acts,
and the interventions that a finer one-step check finds unneeded (the policy's action, held, would have kept
every sampled end state certified: see :func:`exact_pass`).
"""

from __future__ import annotations

from dataclasses import dataclass, field
from fractions import Fraction
from typing import Any, Callable

import numpy as np

from softreach.filters.core import PASS, ValueFilter
from softreach.filters.plans import advance_plan
from softreach.reach.sim.integrator import integrate_period

POLICIES = ("always_min", "always_max", "bang_bang", "random", "anti_optimal", "budget_burner")
WINDS = ("worst_case", "constant_min", "constant_max", "random_step", "switch_inside", "switch_on_filter",
         "helps_policy")


@dataclass
class Row:
    """One audit row: a policy, a wind, a start class, with or without the filter."""

    policy: str
    wind: str
    starts: str
    filtered: bool
    episodes: int = 0
    hard_violations: int = 0
    overspends: int = 0
    largest_overspend: float = 0.0
    landed: int = 0
    steps: int = 0
    policy_steps: int = 0
    interventions: int = 0
    unneeded: int = 0
    uncertified_steps: int = 0
    failures: list[dict[str, Any]] = field(default_factory=list)

    def as_dict(self) -> dict[str, Any]:
        d = {k: v for k, v in self.__dict__.items() if k != "failures"}
        d["policy_acting"] = self.policy_steps / self.steps if self.steps else None
        d["unneeded_fraction"] = self.unneeded / self.interventions if self.interventions else 0.0
        d["failures"] = self.failures[:5]
        return d


def _policy(name: str, vf: ValueFilter, rng: np.random.Generator) -> Callable[[int, float, np.ndarray, float], np.ndarray]:
    lo, hi, mid = vf.a_lo, vf.a_hi, vf.a_mid
    cands = vf.lookahead.candidates
    model = vf.model
    if name == "always_min":
        return lambda k, t, x, z: lo.copy()
    if name == "always_max":
        return lambda k, t, x, z: hi.copy()
    if name == "bang_bang":
        return lambda k, t, x, z: (hi if (k // 5) % 2 == 0 else lo).copy()
    if name == "random":
        return lambda k, t, x, z: rng.uniform(lo, hi)
    if name == "anti_optimal":
        def anti(k, t, x, z):
            a = vf.table.optimal_control(t, x[None], [max(z, vf.table.budget_resolution)], outside="nearest")[0]
            return np.clip(2 * mid - a, lo, hi)
        return anti
    if name == "budget_burner":
        # the candidate whose end box centre lies deepest outside C2 (but inside C1 if it can): it keeps the
        # state in the soft band and spends budget as fast as the dynamics allow
        def burner(k, t, x, z):
            X = np.repeat(x[None], len(cands), axis=0)
            _, _, e_lo, e_hi = model.held_enclosure(t, X, cands, vf.dt)
            c = 0.5 * (e_lo + e_hi)
            comps = [c[:, i] for i in range(len(x))]
            c1 = np.asarray(model.hard_constraint(t, comps), dtype=float)
            c2 = np.asarray(model.soft_constraint(t, comps), dtype=float)
            score = np.where(c1 < 0, c2, -np.inf)
            return cands[int(np.argmax(score))].copy()
        return burner
    raise ValueError(f"unknown policy {name!r}; choose from {POLICIES}")


def _wind(name: str, vf: ValueFilter, rng: np.random.Generator, pieces: int):
    """``wind(t, x, z, policy_action, applied_action, active, was_active) -> (pieces, k)`` winds for the period."""
    b_lo, b_hi = (np.asarray(v, dtype=float) for v in vf.model.disturbance_bounds)
    b_mid, b_rad = 0.5 * (b_lo + b_hi), 0.5 * (b_hi - b_lo)
    a_half = vf.a_half

    def hold(b):
        return np.repeat(np.asarray(b, dtype=float)[None], pieces, axis=0)

    if name == "worst_case":
        return lambda t, x, z, pol, app, act, was: hold(vf.worst_disturbance(t, x, z))
    if name == "constant_min":
        return lambda *args: hold(b_lo)
    if name == "constant_max":
        return lambda *args: hold(b_hi)
    if name == "random_step":
        return lambda *args: hold(rng.choice([-1.0, 1.0], size=b_mid.shape) * b_rad + b_mid)
    if name == "switch_inside":
        return lambda *args: rng.choice([-1.0, 1.0], size=(pieces,) + b_mid.shape) * b_rad + b_mid
    if name == "switch_on_filter":
        state = {"sign": 1.0}

        def toggles(t, x, z, pol, app, act, was):
            if act != was:
                state["sign"] = -state["sign"]
            return hold(b_mid + state["sign"] * b_rad)
        return toggles
    if name == "helps_policy":
        # along the first control axis: with the policy's push while it acts, against the filter's correction
        def helps(t, x, z, pol, app, act, was):
            d = (app - pol)[0] if act else (pol - vf.a_mid)[0]
            s = (-1.0 if act else 1.0) * np.sign(d / a_half[0]) if d != 0 else 1.0
            return hold(b_mid + s * b_rad)
        return helps
    raise ValueError(f"unknown wind {name!r}; choose from {WINDS}")


def exact_pass(vf: ValueFilter, t: float, x: np.ndarray, z: float, a: np.ndarray, n_winds: int = 9,
               substeps: int = 8) -> bool:
    """A finer check that holding ``a`` for one period keeps the state certified: integrate the period under
    constant winds on a grid of the box and one-switch bang-bang winds (which reach the extreme end states of an
    input-affine period), check ``c1`` at the path's nodes and the budget, and that a held action passes again
    from every end state (on the last period: that every end state is inside the target's certificate). It
    samples the wind, so it can only say "passes" more often than the true check: the unneeded fraction it
    gives is an upper bound."""
    model, dt, eps = vf.model, vf.dt, vf.eps
    b_lo, b_hi = (np.asarray(v, dtype=float) for v in model.disturbance_bounds)
    winds = [[(1.0, b_lo + s * (b_hi - b_lo))] for s in np.linspace(0, 1, n_winds)]
    for frac in (0.25, 0.5, 0.75):
        winds.append([(frac, b_lo), (1 - frac, b_hi)])
        winds.append([(frac, b_hi), (1 - frac, b_lo)])
    ends, zs = [], []
    for w in winds:
        xc, zc, tc = list(map(float, x)), float(z), float(t)
        for frac, b in w:
            for _ in range(2):
                h = 0.5 * frac * dt
                xc, cost, _, _ = integrate_period(model, tc, xc, list(map(float, a)), list(map(float, b)), h,
                                               max(1, substeps // 2), eps, 1e-6)
                tc += h
                zc -= cost
                if float(model.hard_constraint(tc, [np.float64(v) for v in xc])) > 0:
                    return False
        if zc < 0:
            return False
        ends.append(xc)
        zs.append(zc)
    ends = np.asarray(ends)
    t_next, zs = np.full(len(ends), t + dt), np.asarray(zs)
    if t + dt >= vf.lookahead.horizon - 1e-9:  # the last period: the end states must be inside the target
        return bool(np.all(vf.lookahead.certificate(t_next, ends, zs) <= 0))
    # "keeps the state certified": every sampled end state is certified, as the filter defines it
    return bool(np.all(vf.certify(t_next, ends, zs)[0]))


def run_episode(vf: ValueFilter | None, ref: ValueFilter, x0: np.ndarray, budget: float, policy, wind,
                pieces: int, substeps: int, row: Row, check_unneeded: bool,
                start_plan: np.ndarray | None = None) -> dict[str, Any]:
    """One episode from ``(0, x0, budget)``; adds its counts to ``row`` and returns its outcome
    (``hard``, ``budget_used``, ``landed``). ``start_plan``: the start's own plan to follow (by default
    :meth:`ValueFilter.certify_start`'s)."""
    model, dt, T = ref.model, ref.dt, ref.lookahead.horizon
    x, z, t = np.asarray(x0, dtype=float), float(budget), 0.0
    was = False
    row.episodes += 1
    hard = landed = False
    # a start certified by a plan of its own is certified for the run that follows it (SafetyFilter.reset)
    if start_plan is None and vf is not None:
        start_plan = vf.certify_start(0.0, x, z)[3]
    plan, queued = start_plan if vf is not None else (None, None)
    for k in range(int(round(T / dt))):
        pol = policy(k, t, x, z)
        if vf is not None:
            app, info = vf.filter(t, x, z, pol, plan=plan)
            plan, queued = advance_plan(info["plan"], queued)
            act = int(info["reason"]) != PASS
            row.steps += 1
            row.policy_steps += int(not act)
            row.interventions += int(act)
            row.uncertified_steps += int(not bool(info["certified"]))
            if act and check_unneeded and exact_pass(vf, t, x, z, pol):
                row.unneeded += 1
        else:
            app, act = pol, False
        b = wind(t, x, z, pol, app, act, was)
        was = act
        xs = list(map(float, x))
        # segments end at every wind switch and every landing check of the environment (its sub-step ends);
        # C1 is checked at every segment end, landing at the check instants: the first event ends the episode
        checks = ref.target_checks
        cuts = sorted({Fraction(j, pieces) for j in range(1, pieces + 1)} | {Fraction(i, checks)
                                                                               for i in range(1, checks + 1)})
        start = Fraction(0)
        for cut in cuts:
            j = min(int(start * pieces), pieces - 1)
            ts, h = t + float(start) * dt, float(cut - start) * dt
            xs, cost, _, _ = integrate_period(model, ts, xs, list(map(float, app)), list(map(float, b[j])), h,
                                              substeps, ref.eps, 1e-6)
            z -= cost
            start = cut
            pt = [np.float64(v) for v in xs]
            if float(model.hard_constraint(ts + h, pt)) > 0:
                hard = True
                break
            if (cut * checks).denominator == 1 and bool(model.landed(ts + h, pt)):
                landed = True
                break
        x, t = np.asarray(xs), (k + 1) * dt
        if hard or landed:
            break
    over = budget - z
    row.hard_violations += int(hard)
    if over > budget + 1e-9:
        row.overspends += 1
        row.largest_overspend = max(row.largest_overspend, over - budget)
    row.landed += int(landed)
    if hard or over > budget + 1e-9 or (vf is not None and not landed):
        row.failures.append({"start": list(map(float, x0)), "budget": budget, "hard": hard,
                             "overspend": max(0.0, over - budget), "landed": landed})
    return {"hard": hard, "budget_used": over, "landed": landed}


def sample_starts(vf: ValueFilter, budget: float, kind: str, n: int, rng: np.random.Generator,
                  pool: int = 4000) -> np.ndarray:
    """``n`` starts at ``t = 0`` with this budget: ``"certified"`` (by one period or a cell,
    :meth:`ValueFilter.certify`), ``"boundary"`` (so certified, the shallowest tenth of the certificate), ``"edge"``
    (so certified, exactly on a face of the hard-constraint box: one coordinate at its bound, where a rounded
    enclosure or a careless comparison decides), ``"planned"`` (certified only by a plan of its own,
    :meth:`ValueFilter.certify_start`) or ``"outside"`` (certified in neither way, certificate within 0.5 of the
    set's level)."""
    lo, hi = (np.asarray(v, dtype=float) for v in vf.model.hard_box)
    x = rng.uniform(lo, hi, size=(pool, len(lo)))
    if kind == "edge":
        axis = rng.integers(len(lo), size=pool)
        x[np.arange(pool), axis] = np.where(rng.random(pool) < 0.5, lo[axis], hi[axis])
    # the search for plans is the costly part: only the classes that depend on it run it
    if kind in ("planned", "outside"):
        ok, _, _, plans = vf.certify_start(0.0, x, budget)
    else:
        ok = vf.certify(0.0, x, budget)[0]
    val = vf.value(0.0, x, budget)
    if kind in ("certified", "edge"):
        pick = np.nonzero(ok)[0]
    elif kind == "planned":
        pick = np.nonzero(plans[:, 0, 0] >= 0)[0]
    elif kind == "boundary":
        idx = np.nonzero(ok)[0]
        pick = idx[np.argsort(-val[idx])][: max(1, len(idx) // 10)]
    elif kind == "outside":
        pick = np.nonzero(~ok & (val < 0.5))[0]
    else:
        raise ValueError(f"unknown start class {kind!r}")
    if len(pick) == 0:
        return np.zeros((0, len(lo)))
    return x[rng.choice(pick, size=min(n, len(pick)), replace=False)]


def audit(vf: ValueFilter, budgets, *, starts_per_row: int = 5, kinds=("certified", "boundary", "outside"),
          policies=POLICIES, winds=WINDS, pieces: int = 4, substeps: int = 2, seed: int = 0,
          unfiltered: bool = True, check_unneeded: bool = True) -> list[Row]:
    """Run the audit grid; one :class:`Row` per (start class, policy, wind, filtered) over all budgets."""
    rng = np.random.default_rng(seed)
    rows = []
    start_sets = {(kind, q): sample_starts(vf, q, kind, starts_per_row, rng) for kind in kinds for q in budgets}
    for kind in kinds:
        for pname in policies:
            for wname in winds:
                seeds = rng.integers(1 << 31, size=(len(budgets), starts_per_row, 2))
                for filtered in ((True, False) if unfiltered else (True,)):
                    row = Row(pname, wname, kind, filtered)
                    for i, q in enumerate(budgets):
                        for s, x0 in enumerate(start_sets[(kind, q)]):
                            # the same policy and wind draws with and without the filter: a paired comparison
                            pol = _policy(pname, vf, np.random.default_rng(seeds[i, s, 0]))
                            wind = _wind(wname, vf, np.random.default_rng(seeds[i, s, 1]), pieces)
                            run_episode(vf if filtered else None, vf, x0, q, pol, wind, pieces, substeps, row,
                                        check_unneeded and filtered)
                    rows.append(row)
    return rows
