"""The Dubins vehicle's cell certificates (``softreach.reach.proof.cell_certificate`` on its held-turn enclosure,
``Dubins.cell_shape``): sound against facts of the vehicle the cells are not built from (how fast it can approach
the goal, where the obstacle is), kept by their own plans under winds that switch inside the 0.1 s period, read
modulo the heading's period across its seam ``theta = +-pi``, and kept by the filter from certified starts (some
bisected onto the certified edge) against adversarial policies and winds. The cells are the package's own
(``reach/proof/cells/``), the ones a user's filter reads."""

from __future__ import annotations

import copy
import math

import gymnasium as gym
import numpy as np
import pytest

import softreach.envs  # noqa: F401  (registers the environments)

from softreach.filters import SafetyFilter, ValueFilter
from softreach.agents.audit import Row, _policy, _wind, run_episode
from softreach.reach import get_model
from softreach.reach.proof.cell_certificate import CellCertificate
from softreach.reach.proof.kernels import step_index

from cell_plans import (assert_landing_cells_nested, cell_boxes, fly_plan_from_a_good_cell, recheck,
                        run_certified_episode)

DT = 0.1


@pytest.fixture(scope="module")
def vf(dubins_held_table):
    # what SafetyFilter asks: landing checked at the environment's sub-step ends
    out = ValueFilter(dubins_held_table, DT, target_checks=dubins_held_table.model.substeps)
    assert out.landing_cells is not None and out.safe_cells is None
    assert out.landing_cells.shape == tuple(out.model.cell_shape)
    return out


def _box_distance(lo, hi, point):
    """The distance from ``point`` (x, y) to each box ``[lo, hi]`` (rows) in the plane."""
    nearest = np.clip(np.asarray(point, float), lo[:, :2], hi[:, :2])
    return np.hypot(*(nearest - np.asarray(point, float)).T)


@pytest.mark.parametrize("t", [0.0, 3.5, 6.5, 6.9])
def test_no_landing_cell_is_farther_from_the_goal_than_the_vehicle_can_fly_by_T(vf, t):
    # the vehicle's ground speed is at most v + sqrt(2) w_max: a cell farther from the goal disc cannot land by T
    p = vf.model.params
    cells = vf.landing_cells
    k = step_index(t, cells.dt, cells.steps)
    lo, hi, m = cell_boxes(cells, k)
    good = m < cells.never
    reach = (p.speed + math.sqrt(2.0) * p.wind_max) * (vf.model.horizon - k * DT)
    assert good.any()
    assert (_box_distance(lo[good], hi[good], p.goal) <= p.goal_radius + reach + 1e-9).all()


def test_no_good_cell_lies_inside_the_obstacle_or_the_cells_change_with_the_heading_period(vf):
    cells = vf.landing_cells
    p = vf.model.params
    lo, hi, m = cell_boxes(cells, 0)
    # a cell whose farthest corner from the obstacle's centre is inside the obstacle violates C1 everywhere
    far = np.hypot(np.maximum(np.abs(lo[:, 0] - p.obstacle[0]), np.abs(hi[:, 0] - p.obstacle[0])),
                   np.maximum(np.abs(lo[:, 1] - p.obstacle[1]), np.abs(hi[:, 1] - p.obstacle[1])))
    inside = far < p.obstacle_radius
    assert inside.sum() > 10 and (m[inside] == cells.never).all()
    # the cells tile the heading's period exactly once: [-pi, pi], read modulo it beyond
    assert cells.lo[2] == -math.pi and cells.hi[2] == math.pi


def test_landing_cells_grow_with_the_budget(vf):
    assert_landing_cells_nested(vf, (0.0, 1.0, 2.0), least=501)


def _touched(cells, lo, hi):
    """Per axis the cells whose closed box meets ``[lo, hi]``, the heading's cells also one period on either side:
    each cell asked in turn."""
    period = cells.hi[2] - cells.lo[2]
    out = []
    for a in range(3):
        shifts = (-period, 0.0, period) if a == 2 else (0.0,)
        out.append([c for c in range(cells.shape[a])
                    if any(cells.lo[a] + c * cells.width[a] + s <= hi[a] and lo[a] <= cells.lo[a] + (c + 1) *
                           cells.width[a] + s for s in shifts)])
    return out


def test_the_heading_seam_is_looked_up_periodically_on_the_grid(vf):
    """The environment wraps the heading into ``[-pi, pi)``; the cells tile that period once and read a heading
    modulo it: a state one period off is in the same cell, with the same plan, and a box across the seam is covered
    exactly where every cell it meets at either end of the period is good (each cell asked in the test)."""
    env = gym.make("softreach/SoftReach-v0", model=get_model("dubins"), wind="none")
    env.reset(options={"state": [-2.0, 0.0, math.pi], "budget": 1.0})
    assert env.unwrapped.state[2] == -math.pi  # pi is wrapped onto the seam's lower side
    cells = vf.landing_cells
    n, period = cells.shape[2], cells.hi[2] - cells.lo[2]
    rng = np.random.default_rng(5)
    lo, hi = (np.asarray(b, float) for b in vf.model.hard_box)
    x = rng.uniform(lo, hi, (4000, 3))
    # headings in the middle third of a cell, well inside it however they are rounded
    x[:, 2] = cells.lo[2] + (rng.integers(0, n, 4000) + rng.uniform(1 / 3, 2 / 3, 4000)) * cells.width[2]
    inside = cells.contains(0.0, x, 2.0)
    assert 100 < inside.sum() < 3900
    for turns in (-1, 1):
        shifted = x + [0.0, 0.0, turns * period]
        np.testing.assert_array_equal(cells.contains(0.0, shifted, 2.0), inside)
        np.testing.assert_array_equal(cells.plan(0.0, shifted)[0], cells.plan(0.0, x)[0])
    # two periods off, beyond where the wrap's allowance is derived: off the grid
    far = x + [0.0, 0.0, 2 * period]
    assert not cells.contains(0.0, far, 2.0).any() and (cells.plan(0.0, far)[0] == -1).all()
    # boxes across the seam around good cells next to it, at sample 1 with 2 s of budget (inside its budget cell)
    k, z = 1, 2.0 + 0.5 * cells.dz
    m = np.asarray(cells.m[k])
    j = int(np.floor(z / cells.dz))
    seam = np.argwhere(np.r_["-1", m[:, :, :1], m[:, :, -1:]] <= j)
    assert len(seam) > 100
    got, want = [], []
    for ix, iy, _ in seam[rng.permutation(len(seam))[:300]]:
        b_lo = np.maximum(cells.lo[:2] + (np.array([ix, iy]) + rng.uniform(-0.2, 0.5, 2)) * cells.width[:2],
                          cells.lo[:2])
        b_hi = np.minimum(b_lo + rng.uniform(0.0, 0.6, 2) * cells.width[:2], cells.hi[:2])
        left, right = rng.uniform(0.0, 4.0, 2) * cells.width[2]
        centre = float(rng.choice([-math.pi, math.pi]))
        box_lo, box_hi = np.r_[b_lo, centre - left], np.r_[b_hi, centre + right]
        got.append(bool(cells.covered(k * DT, box_lo[None], box_hi[None], z)[0]))
        want.append(bool((m[np.ix_(*_touched(cells, box_lo, box_hi))] <= j).all()))
    assert got == want
    assert 30 <= sum(want) <= len(want) - 30
    # a box longer than the period meets every heading cell once
    box_lo, box_hi = np.r_[b_lo, -4.0], np.r_[b_hi, 3.5]
    assert len(_touched(cells, box_lo, box_hi)[2]) == n
    assert cells.covered(k * DT, box_lo[None], box_hi[None], z)[0] == (m[np.ix_(*_touched(cells, box_lo, box_hi))]
                                                                      <= j).all()


def test_a_heading_the_environment_wraps_lies_in_a_cell_its_box_touches(vf):
    """The environment's wrap rounds: a heading a period off, within a few ulps of a cell's edge, can come back on
    the edge's other side. A box reaching such a heading is covered only where the cell holding the wrapped heading
    is good too (the look-up's allowance, ``WRAP_ULPS``)."""
    cells, model = vf.landing_cells, vf.model
    n, period = cells.shape[2], cells.hi[2] - cells.lo[2]

    def column(h):  # the heading's cell as the look-up computes it, modulo the period
        return math.floor((h - cells.lo[2]) / cells.width[2]) % n

    jumps = []
    for edge in cells.lo[2] + np.arange(n) * cells.width[2]:
        for shifted in (edge - period, edge + period):
            for heading in shifted + np.spacing(period) * np.arange(-8, 8):
                wrapped = model.wrap_state([0.0, 0.0, heading])[2]
                if column(heading) != column(wrapped):
                    jumps.append((heading, column(heading), column(wrapped)))
    assert len(jumps) >= 5
    k, z = 1, 2.0 + 0.5 * cells.dz
    m = np.asarray(cells.m[k])
    j = int(np.floor(z / cells.dz))
    refused = 0
    for heading, own, wrapped_column in jumps:
        rows = np.argwhere(m[:, :, own] <= j)
        centres = cells.lo[:2] + (rows + 0.5) * cells.width[:2]
        box_lo = np.c_[centres, np.full(len(rows), heading - 1e-3)]
        box_hi = np.c_[centres, np.full(len(rows), heading)]
        covered = cells.covered(k * DT, box_lo, box_hi, z)
        good = m[rows[:, 0], rows[:, 1], wrapped_column] <= j
        assert not (covered & ~good).any(), heading
        refused += int((~good).sum())
    assert refused > 0


def _env_and_starts(table, seed, n):
    """``SafetyFilter`` on the Dubins env under its random wind, its filter, a generator seeded ``seed`` and ``n``
    states it drew uniformly over ``C1``'s box."""
    env = SafetyFilter(gym.make("softreach/SoftReach-v0", model=get_model("dubins"), wind="random"), table)
    env.action_space.seed(0)
    vf = env.value_filter
    rng = np.random.default_rng(seed)
    lo, hi = (np.asarray(b, float) for b in vf.model.hard_box)
    return env, vf, rng, rng.uniform(lo, hi, (n, 3))


def test_periods_across_the_heading_seam_are_admitted_and_the_chain_holds(dubins_held_table):
    """The environment wraps the heading at ``+-pi``, where the cells read it modulo the period: the policy's turn
    across the seam is applied where it keeps the next state certified. Starts the filter certifies within 0.15 rad
    of the seam, a policy turning across it first (then random), the env's random wind, ``SafetyFilter`` on the
    environment: every step certified, every run lands with no hard violation and no overspend, and the policy's
    own turn carries the heading across the seam at some steps. ``c1``'s box maximum does not depend on the
    heading, across the seam or not."""
    env, vf, rng, x = _env_and_starts(dubins_held_table, 11, 6000)
    side = rng.choice([-1.0, 1.0], 6000)
    x[:, 2] = side * (math.pi - rng.uniform(0.0, 0.15, 6000))
    episodes = crossings = 0
    for q in (0.0, 2.0):
        for i in np.nonzero(vf.certify(0.0, x, q)[0])[0][:6]:
            _, info = env.reset(seed=int(i), options={"state": x[i].tolist(), "budget": q})
            assert info["certified"]
            done, steps = False, 0
            while not done:
                # turn towards the seam for the first second: +1 from near pi, -1 from near -pi
                action = np.array([side[i]]) if steps < 10 else env.action_space.sample()
                before = env.unwrapped.state[2]
                _, _, terminated, truncated, info = env.step(action)
                assert info["certified"], info["filter_reason"]
                crossings += int(abs(env.unwrapped.state[2] - before) > math.pi and info["filter_reason"] == "pass")
                done, steps = terminated or truncated, steps + 1
            assert info["landed"] and not info["hard_violation"] and info["budget_used"] <= q + 1e-9
            episodes += 1
    assert episodes == 12 and crossings >= 6
    box_lo = np.array([[-3.0, 2.0, math.pi - 0.1], [-3.0, 2.0, -math.pi - 0.1], [-3.0, 2.0, -0.1]])
    box_hi = np.array([[-2.9, 2.1, math.pi + 0.1], [-2.9, 2.1, -math.pi + 0.1], [-2.9, 2.1, 0.1]])
    c1 = vf.model.set_box_max("hard_constraint", 0.0, box_lo, box_hi)
    assert c1[0] == c1[1] == c1[2] < 0


def test_cells_refuse_a_periodic_axis_not_tiled_over_its_period(vf):
    la = copy.copy(vf.lookahead)
    la.model = model = get_model("dubins")
    model.hard_box = (model.hard_box[0][:2] + (-3.0,), model.hard_box[1][:2] + (3.0,))
    with pytest.raises(ValueError, match="periodic axis theta"):
        CellCertificate.build(la, (2, 2, 4))


def test_a_cells_plan_keeps_its_promise_under_switching_winds(vf):
    cells = vf.landing_cells
    rng = np.random.default_rng(0)
    flown = sum(fly_plan_from_a_good_cell(cells, vf.model, vf.eps, rng, faces=True) for _ in range(150))
    assert flown >= 100


def _bisect_onto_edge(vf, x_in, q, axis, step):
    """A start certified at ``t = 0`` within 1e-12 of the certificate's edge along ``axis``: bisected between
    ``x_in`` (certified) and ``x_in`` moved by ``step`` (not); ``None`` if that is certified too."""
    def certified(x):
        return bool(np.atleast_1d(vf.certify(0.0, x, q)[0])[0])

    out = x_in.copy()
    out[axis] += step
    if certified(out):
        return None
    a, b = x_in[axis], out[axis]
    while abs(b - a) > 1e-12:
        mid = x_in.copy()
        mid[axis] = 0.5 * (a + b)
        if certified(mid):
            a = mid[axis]
        else:
            b = mid[axis]
    edge = x_in.copy()
    edge[axis] = a
    return edge


@pytest.mark.parametrize("policy", ["random", "always_max", "anti_optimal"])
def test_filter_keeps_the_promise_from_certified_and_edge_starts(vf, policy):
    """From starts the cells certify (uniform, and bisected onto the certified edge along x, y or the heading),
    under the worst-case wind of the table, winds switching at random inside each period, and a wind that flips
    whenever the filter starts or stops acting: every run lands, never leaves ``C1``, never overspends, and every
    step is certified."""
    rng = np.random.default_rng({"random": 3, "always_max": 4, "anti_optimal": 5}[policy])
    lo, hi = (np.asarray(b, float) for b in vf.model.hard_box)
    x = rng.uniform(lo, hi, (4000, 3))
    runs = 0
    for q in (0.0, 1.0):
        ok = vf.certify(0.0, x, q)[0]
        starts = list(x[ok][:2])
        for x0, axis in zip(x[ok][2:30], [0, 1, 2] * 10):
            sign = float(rng.choice([-1.0, 1.0]))
            for length in (0.5, 2.0):  # a longer step where the shorter one stays certified
                step = sign * length
                if not lo[axis] <= x0[axis] + step <= hi[axis]:
                    step = -step  # the edge inside C1 and the heading's period, where the environment's states lie
                edge = _bisect_onto_edge(vf, x0, q, axis, step) if lo[axis] <= x0[axis] + step <= hi[axis] else None
                if edge is not None:
                    break
            if edge is not None:
                starts.append(edge)
            if len(starts) == 4:
                break
        assert len(starts) == 4
        for x0, wind in zip(starts, ["worst_case", "switch_inside", "switch_on_filter", "switch_inside"]):
            row = Row(policy, wind, "certified", True)
            out = run_episode(vf, vf, x0, q, _policy(policy, vf, rng), _wind(wind, vf, rng, 4), 4,
                              vf.model.substeps, row, False)
            assert out["landed"] and not out["hard"] and out["budget_used"] <= q + 1e-9, (x0, q, wind, out)
            assert row.uncertified_steps == 0, (x0, q, wind)
            runs += 1
    assert runs == 8


def test_safety_filter_on_the_env_keeps_its_promise_at_the_seam(dubins_held_table):
    """The wrapped environment: starts the filter certifies, headings on the seam (``pi``, which the environment
    wraps to ``-pi``) among them, a random policy and the env's random wind: every run lands, no hard violation,
    no overspend, every step certified."""
    env, vf, rng, x = _env_and_starts(dubins_held_table, 7, 4000)
    x[:2000, 2] = math.pi
    seam = 0
    for q in (0.0, 2.0):
        wrapped = x.copy()
        wrapped[:2000, 2] = -math.pi
        ok = vf.certify(0.0, wrapped, q)[0]
        for i in [*np.nonzero(ok[:2000])[0][:2], *np.nonzero(ok[2000:])[0][:1] + 2000]:
            _, info = env.reset(seed=int(i), options={"state": x[i].tolist(), "budget": q})
            assert info["certified"]
            seam += int(i < 2000)
            run_certified_episode(env, q)
    assert seam == 4


def test_the_packaged_cells_are_what_the_recursion_gives(vf):
    """The package's files at 1,500 random cells and the 2 x 60 x 60 cells on the heading's seam, at every sample:
    the least good budget index and the plan are those one step of the game's recursion gives from the file's own
    later samples (``cell_plans.recheck``), so the file is the build's answer there for this model, its enclosure
    and its ``c1`` bound."""
    cells = vf.landing_cells
    n = cells.shape[2]
    grid = np.arange(int(np.prod(cells.shape))).reshape(cells.shape)
    flat = np.r_[np.random.default_rng(1).choice(grid.size, 1500, replace=False), grid[:, :, 0].ravel(),
                 grid[:, :, n - 1].ravel()]
    m, action, hold = recheck(cells, vf.lookahead, flat)
    steps = cells.steps + 1
    for name, got in (("m", m), ("action", action), ("hold", hold)):
        np.testing.assert_array_equal(got, np.asarray(getattr(cells, name)).reshape(steps, -1)[:, flat],
                                      err_msg=name)
    assert 0.05 < (m[0] < cells.never).mean() < 0.95
