"""Test helpers for the cell certificates: every cell's box, flying a cell's stored plan with the environment's
integrator under a wind that switches inside the period, the landing cells' nesting, and a filtered episode that
keeps the promise (``tests/test_cell_certificate.py``, ``tests/test_glider_cells.py``, ``tests/test_dubins_cells.py``,
``tests/test_models_api.py``), a model without cells (:func:`without_cells`), and the recursion asked again of stored
cells (:func:`recheck`)."""

from __future__ import annotations

from typing import Any

import numpy as np

from softreach.reach.proof import cell_game
from softreach.reach.proof.cell_certificate import cell_key
from softreach.reach.sim.integrator import integrate_period


def without_cells(monkeypatch) -> None:
    """Make the filter's check of a model (:func:`~softreach.reach.proof.enclosure_check.lacking`) see every model as
    one that declares no ``cell_shape``: a copy of it without, so that the check itself runs."""
    import copy

    from softreach.reach.proof import enclosure_check

    check = enclosure_check.lacking

    def lacking(model):
        bare = copy.copy(model)
        bare.cell_shape = None
        return check(bare)

    monkeypatch.setattr(enclosure_check, "lacking", lacking)


def cell_boxes(cells, k: int):
    """``(lo, hi, m)`` of every cell at sample ``k``: its box and its lowest good budget index."""
    idx = np.stack(np.meshgrid(*[np.arange(s) for s in cells.shape], indexing="ij"), -1).reshape(-1, len(cells.shape))
    return cells.lo + idx * cells.width, cells.lo + (idx + 1) * cells.width, cells.m[k].reshape(-1)


def fly_plan_from_a_good_cell(cells, model, eps: float, rng: np.random.Generator, faces: bool = False) -> bool:
    """Draw a good cell, a state in it and a budget it is good at, fly the cell's plan with each wind axis jumping
    between its extremes at three random instants of each period, and assert the claim: ``C1`` and the budget kept
    at every jump, and the run landed or in a good cell at the plan's end.

    :param faces: half the time put the state on one of its cell's faces; where the look-up reads it in a worse
        neighbour (a face they share) nothing is flown and ``False`` returned
    :return: whether a plan was flown
    """
    dt = cells.dt
    d_lo, d_hi = model.disturbance_bounds
    k = int(rng.integers(0, cells.steps))
    lo, hi, m = cell_boxes(cells, k)
    good = np.nonzero(m < cells.never)[0]
    c = int(rng.choice(good))
    x = rng.uniform(lo[c], hi[c])
    if faces and rng.random() < 0.5:
        axis = int(rng.integers(len(x)))
        x[axis] = (lo if rng.random() < 0.5 else hi)[c, axis]
    z = (m[c] + rng.uniform(0, 3)) * cells.dz
    if not cells.contains(k * dt, x, z)[0]:
        assert faces, (k, x, z)
        return False
    j, K = (int(v[0]) for v in cells.plan(k * dt, x))
    t, xs, spent, landed = k * dt, list(map(float, x)), 0.0, False
    for _p in range(K):
        cuts = np.sort(rng.uniform(0, dt, 3))
        for s0, s1 in zip(np.r_[0, cuts], np.r_[cuts, dt]):
            if s1 - s0 <= 0 or landed:
                continue
            b = [float(rng.choice([w_lo, w_hi])) for w_lo, w_hi in zip(d_lo, d_hi)]
            xs, cost, _, _ = integrate_period(model, t, xs, [float(cells.candidates[j, 0])], b, s1 - s0, 4, eps,
                                              1e-9)
            spent += cost
            t += s1 - s0
            pt = [np.float64(v) for v in xs]
            assert float(model.hard_constraint(t, pt)) <= 0 and z - spent >= -1e-12, (k, x, z, xs)
            landed = bool(model.landed(t, pt))
    assert landed or cells.contains(k * dt + K * dt, np.asarray(xs), z - spent)[0], (k, x, z, K, xs)
    return True


def assert_landing_cells_nested(vf, budgets, least: int = 1) -> None:
    """At ``t = 0``, over 20,000 states uniform over ``C1``: the landing cells hold at least ``least`` of them at each
    budget and grow with the budget (``budgets`` increasing)."""
    rng = np.random.default_rng(2)
    lo, hi = (np.asarray(b, float) for b in vf.model.hard_box)
    x = rng.uniform(lo, hi, (20000, len(lo)))
    before = None
    for q in budgets:
        inside = vf.landing_cells.contains(0.0, x, q)
        assert inside.sum() >= least, (q, int(inside.sum()))
        if before is not None:
            assert not (before & ~inside).any()
        before = inside


def run_certified_episode(env, q: float) -> None:
    """Step a filtered env from a start its ``reset`` certified, with random actions, to the episode's end: every
    step certified, and the episode landed with no hard violation and at most ``q`` of budget used."""
    done = False
    while not done:
        _, _, terminated, truncated, info = env.step(env.action_space.sample())
        assert info["certified"], info["filter_reason"]
        done = terminated or truncated
    assert info["landed"] and not info["hard_violation"] and info["budget_used"] <= q + 1e-9


def recheck(cells: Any, lookahead: Any, flat: Any) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """The cell game's recursion (:mod:`softreach.reach.proof.cell_game`) asked again of a stored certificate at the
    cells ``flat``, each sample from the stored later ones: ``(m, action, hold)``, the stored ones where the file is
    the build's answer there.

    :raises ValueError: the look-ahead is not the one the certificate was built for
    """
    key = cells.key
    asked = cell_key(lookahead, key["shape"], key["dz"], key["holds"], key["span_cap"])
    if asked != key:
        differ = {k: (asked.get(k), key.get(k)) for k in sorted(set(asked) | set(key)) if asked.get(k) != key.get(k)}
        raise ValueError(f"the look-ahead is not the one the cells were built for: (look-ahead, cells) {differ}")
    flat = np.asarray(flat, dtype=np.int64)
    N, C = cells.steps, len(flat)
    m_all = np.asarray(cells.m).reshape(N + 1, -1)
    lo, hi = cell_game.cell_boxes(cells, flat)
    m, action, hold = np.empty((N + 1, C), np.int64), np.full((N + 1, C), -1, np.int8), np.zeros((N + 1, C), np.int8)
    m[N] = cells.never
    plans = cell_game.all_plan_steps(cells, lookahead, lo, hi, tuple(key["holds"]), key["span_cap"])
    for k in range(N - 1, -1, -1):
        m[k], action[k], hold[k] = cell_game.backward_step(cells, plans, m_all, k, N, C)
    return m, action, hold
