"""The Dubins vehicle's cell certificates (``softreach.reach.proof.cell_certificate`` on its held-turn enclosure,
``Dubins.cell_shape``): sound against facts of the vehicle the cells are not built from (how fast it can approach
the goal, where the obstacle is), kept by their own plans under winds that switch inside the 0.1 s period, looked
up consistently at the heading's seam ``theta = -pi``, and kept by the filter from certified starts (some bisected
onto the certified edge) against adversarial policies and winds. The cells are the package's own
(``reach/proof/cells/``), the ones a user's filter reads."""

from __future__ import annotations

import math

import gymnasium as gym
import numpy as np
import pytest

import softreach.envs  # noqa: F401  (registers the environments)

from softreach.filters import SafetyFilter, ValueFilter
from softreach.agents.audit import Row, _policy, _wind, run_episode
from softreach.reach import get_model

from cell_plans import assert_landing_cells_nested, cell_boxes, fly_plan_from_a_good_cell, run_certified_episode

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
    k = cells.step_index(np.array([t]))[0]
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
    # the cells tile the heading's period exactly once: [-pi, pi], no cell beyond it
    assert cells.lo[2] == -math.pi and cells.hi[2] == math.pi


def test_landing_cells_grow_with_the_budget(vf):
    assert_landing_cells_nested(vf, (0.0, 1.0, 2.0), least=501)


def test_the_heading_seam_is_looked_up_on_the_grid_and_nothing_off_it_is_certified(vf):
    """The environment wraps the heading into ``[-pi, pi)``: ``theta = -pi`` is the first heading cell (closed,
    proven for its lower face too), ``pi`` the last; a heading beyond the period is off the grid, so neither in a
    cell nor planned; and an end box that crosses the seam touches no cell, so no period is admitted by it."""
    env = gym.make("softreach/SoftReach-v0", model=get_model("dubins"), wind="none")
    _, info = env.reset(options={"state": [-2.0, 0.0, math.pi], "budget": 1.0})
    assert env.unwrapped.state[2] == -math.pi  # pi is wrapped onto the seam's lower side
    cells = vf.landing_cells
    n = cells.shape[2]
    rng = np.random.default_rng(5)
    lo, hi = (np.asarray(b, float) for b in vf.model.hard_box)
    x = rng.uniform(lo, hi, (4000, 3))
    for theta, column in ((-math.pi, 0), (math.pi, n - 1)):
        at = x.copy()
        at[:, 2] = theta
        # the plan and the membership are those of the cell column that holds the seam
        inner = at.copy()
        inner[:, 2] = theta + (0.5 if column == 0 else -0.5) * cells.width[2]
        np.testing.assert_array_equal(cells.plan(0.0, at)[0], cells.plan(0.0, inner)[0])
        np.testing.assert_array_equal(cells.contains(0.0, at, 1.0), cells.contains(0.0, inner, 1.0))
    assert cells.contains(0.0, x[:200] * [1, 1, 0] + [0, 0, -math.pi], 2.0).any()
    for theta in (np.nextafter(-math.pi, -4.0), np.nextafter(math.pi, 4.0), 3.5, -7.0):
        off = x.copy()
        off[:, 2] = theta
        assert not cells.contains(0.0, off, 2.0).any()
        assert (cells.plan(0.0, off)[0] == -1).all()
    # an end box across the seam, however good the cells at both of its ends
    box_lo, box_hi = x[:200].copy(), x[:200].copy()
    box_lo[:, 2], box_hi[:, 2] = math.pi - 0.01, math.pi + 0.01
    assert not cells.covered(DT, box_lo, box_hi, 2.0).any()
    box_lo[:, 2], box_hi[:, 2] = -math.pi - 0.01, -math.pi + 0.01
    assert not cells.covered(DT, box_lo, box_hi, 2.0).any()


def test_no_admitted_period_crosses_the_heading_seam(vf):
    """The environment wraps the heading at ``+-pi``; the filter's proofs are stated in one period's coordinates.
    A policy's turn that would carry the heading across the seam is not admitted, not even through a candidate
    that would certify the next state from the whole end box (it would be certified in the other coordinates,
    where the next step does not look): the regression of a run that went ``"uncertified"`` after such a pass,
    from ``(2.76, 3.56, pi)`` at ``Q = 0`` under the env's random wind. The applied action's period stays in the
    period, and ``c1``'s box maximum is positive for any box that leaves it."""
    from softreach.filters.core import PASS

    model = vf.model
    start = np.array([2.7605945669964234, 3.5595853691598363, -math.pi])
    for theta, turn in ((-math.pi, -0.0223), (-math.pi + 0.01, -0.5), (math.pi - 0.01, 0.5)):
        x = start.copy()
        x[2] = theta
        applied, info = vf.filter(0.0, x, 0.0, np.array([turn]))
        assert int(info["reason"]) != PASS
        end = theta + float(np.asarray(applied).reshape(-1)[0]) * DT
        assert -math.pi <= end <= math.pi, (theta, turn, applied)
    # a box well inside C1 (west of the obstacle, inside the arena), its heading across the seam or not
    lo = np.array([[-3.0, 2.0, math.pi - 0.1], [-3.0, 2.0, -math.pi - 1e-9], [-3.0, 2.0, -math.pi]])
    hi = np.array([[-2.9, 2.1, math.pi + 1e-9], [-2.9, 2.1, -math.pi + 0.1], [-2.9, 2.1, math.pi]])
    c1 = model.set_box_max("hard_constraint", 0.0, lo, hi)
    assert (c1[:2] > 0).all() and c1[2] < 0


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
    env = SafetyFilter(gym.make("softreach/SoftReach-v0", model=get_model("dubins"), wind="random"),
                       dubins_held_table)
    env.action_space.seed(0)
    vf = env.value_filter
    rng = np.random.default_rng(7)
    lo, hi = (np.asarray(b, float) for b in vf.model.hard_box)
    x = rng.uniform(lo, hi, (4000, 3))
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
    later samples (``cell_game.recheck``), so the file is the build's answer there for this model, its enclosure
    and its ``c1`` bound."""
    from softreach.reach.proof import cell_game

    cells = vf.landing_cells
    n = cells.shape[2]
    grid = np.arange(int(np.prod(cells.shape))).reshape(cells.shape)
    flat = np.r_[np.random.default_rng(1).choice(grid.size, 1500, replace=False), grid[:, :, 0].ravel(),
                 grid[:, :, n - 1].ravel()]
    m, action, hold = cell_game.recheck(cells, vf.lookahead, flat)
    steps = cells.steps + 1
    for name, got in (("m", m), ("action", action), ("hold", hold)):
        np.testing.assert_array_equal(got, np.asarray(getattr(cells, name)).reshape(steps, -1)[:, flat],
                                      err_msg=name)
    assert 0.05 < (m[0] < cells.never).mean() < 0.95
