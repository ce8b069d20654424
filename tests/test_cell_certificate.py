"""The certificates solved on cells (``softreach.reach.proof.cell_certificate``): sound against facts of the point mass
the cells are not built from (the exact continuous-time sets, the stopping distance), kept by their own plans under
winds that switch inside the period, and kept by the filter against adversarial policies and winds."""

from __future__ import annotations

import numpy as np
import pytest

from softreach.filters import ValueFilter
from softreach.agents.audit import Row, _policy, _wind, run_episode
from softreach.reach import get_model
from softreach.reach.proof.cell_certificate import CellCertificate
from softreach.reach.proof.kernels import step_index
from softreach.reach.proof.lookahead import Lookahead
from softreach.reach.numerics.exact_pointmass import exact_member

from cell_plans import cell_boxes, fly_plan_from_a_good_cell
from judged import candidate_verdicts

DT = 0.01
SHAPE = (60, 360)
HOLDS = (1, 2, 4)


@pytest.fixture(scope="module")
def vf(pointmass_held_table):
    model = get_model("pointmass")
    la = Lookahead.from_table(pointmass_held_table, model, DT, pointmass_held_table.eps, target_checks=model.substeps)
    land = CellCertificate.build(la, SHAPE, holds=HOLDS)
    return ValueFilter(pointmass_held_table, DT, target_checks=model.substeps, landing_cells=land)


def test_no_landing_cell_holds_a_state_that_must_hit_the_ground(vf):
    # descending at v < 0, the best the vehicle can do against the worst wind is u_max - g - d_max upwards: below
    # the stopping altitude v^2 / (2 a) it reaches y < 0 within |v| / a < T, whatever the budget
    p = vf.model.params
    a = p.u_max - p.gravity - p.d_max
    lo, hi, m = cell_boxes(vf.landing_cells, 0)
    good = m < vf.landing_cells.never
    doomed = (lo[:, 0] < 0) & (lo[:, 1] < lo[:, 0] ** 2 / (2 * a))
    assert not (good & doomed).any()
    # and the cells are not empty of such starts by accident: near the ground slow cells are good
    assert (good & (hi[:, 1] < 1.0) & (np.abs(lo[:, 0]) < 2)).any()


def test_outside_the_soft_band_needs_budget(vf):
    # outside C2 (|v| > 10) the budget drains at once: no such cell is good with none, and some are with some
    lo, hi, m = cell_boxes(vf.landing_cells, 0)
    band = (lo[:, 0] >= vf.model.params.soft_speed[1]) | (hi[:, 0] <= vf.model.params.soft_speed[0])
    assert band.any() and (m[band] > 0).all()
    assert (m[band] < vf.landing_cells.never).any()


@pytest.mark.parametrize("t", [0.0, 0.4, 0.8, 0.95])
def test_landing_cells_lie_inside_the_exact_sets_and_grow_with_the_budget(vf, t):
    # the exact continuous-time sets (closed form, reach/numerics/exact_pointmass.py) hold every state any controller can
    # land from; holding actions can only do less, so a landing cell outside them would be unsound
    rng = np.random.default_rng(1)
    x = rng.uniform([-15, 0], [15, 18], (20000, 2))
    before = None
    for q in (0.0, 0.06, 0.3, 0.6):
        inside = vf.landing_cells.contains(t, x, q)
        exact = np.asarray(exact_member(x[:, 0], x[:, 1], q, 1.0 - t), bool)
        assert not (inside & ~exact).any(), (t, q, x[inside & ~exact][:3])
        assert inside.sum() > 0.3 * exact.sum(), (t, q, inside.sum(), exact.sum())  # coarse test cells
        if before is not None:
            assert not (before & ~inside).any()
        before = inside


def test_a_cells_plan_keeps_its_promise_under_switching_winds(vf):
    rng = np.random.default_rng(0)
    for _ in range(300):
        fly_plan_from_a_good_cell(vf.landing_cells, vf.model, vf.eps, rng)


@pytest.mark.parametrize("policy", ["always_min", "always_max", "random", "anti_optimal"])
def test_filter_lands_every_run_from_landing_cells(vf, policy):
    # every policy, adversarial winds: certified starts land by T, never leave C1 nor overspend
    rng = np.random.default_rng(11)
    x = rng.uniform([-15, 0], [15, 18], (4000, 2))
    for q in (0.0, 0.3):
        starts = x[vf.landing_cells.contains(0.0, x, q)][:2]
        assert len(starts) == 2
        for x0 in starts:
            for wind in ("worst_case", "switch_inside", "switch_on_filter", "helps_policy"):
                row = Row(policy, wind, "certified", True)
                out = run_episode(vf, vf, x0, q, _policy(policy, vf, rng), _wind(wind, vf, rng, 4), 4,
                                  vf.model.substeps, row, False)
                assert out["landed"] and not out["hard"] and out["budget_used"] <= q + 1e-9, (x0, q, wind, out)
                assert row.uncertified_steps == 0, (x0, q, wind)


def test_files_and_arguments_are_checked(vf, tmp_path):
    sc = vf.landing_cells
    path = tmp_path / "cells.npz"
    sc.save(path)
    back = CellCertificate.load(path, sc.key)
    assert np.array_equal(back.m, sc.m) and np.array_equal(back.hold, sc.hold) and back.key["game"] == "land"
    other = dict(sc.key, dt=0.1)
    with pytest.raises(ValueError, match="built for"):
        CellCertificate.load(path, other)
    bad = tmp_path / "bad.npz"
    bad.write_bytes(b"not a numpy file")
    with pytest.raises(ValueError, match="bad.npz"):
        CellCertificate.load(bad)
    # the cache's form: a folder of arrays, read back memory-mapped; a truncated array is refused by its folder
    folder = tmp_path / "cells"
    sc.save(folder, compressed=False)
    mapped = CellCertificate.load(folder, sc.key)
    assert isinstance(mapped.m.base, np.memmap) and np.array_equal(mapped.m, sc.m)
    assert np.array_equal(mapped.plan(0.3, [[1.0, 5.0]])[0], sc.plan(0.3, [[1.0, 5.0]])[0])
    (folder / "hold.npy").write_bytes((folder / "hold.npy").read_bytes()[:200])
    with pytest.raises(ValueError, match="cells is not a readable"):
        CellCertificate.load(folder)
    with pytest.raises(ValueError, match="safe_cells must be 'auto' or None"):
        ValueFilter(vf.table, DT, safe_cells=sc, landing_cells=sc)
    with pytest.raises(TypeError, match="landing_cells must be 'auto' or a CellCertificate"):
        ValueFilter(vf.table, DT, landing_cells="yes")
    with pytest.raises(ValueError, match="not for this filter"):
        ValueFilter(vf.table, DT, landing_cells=CellCertificate(
            sc.lo, sc.hi, sc.m, sc.action, sc.hold, sc.candidates, DT, sc.dz, sc.horizon, other))
    with pytest.raises(ValueError, match="plan"):
        vf.filter(0.0, [0.0, 5.0], 0.3, [0.0], plan=[1.5, 2.0])


def test_multi_period_plans_are_followed_to_their_end(vf, monkeypatch):
    # the runs above do meet states where no single period ends in landing cells: the filter then holds its
    # cell's plan for several periods, and the run still lands
    from softreach.filters import PLAN_LAND

    seen = {"started": 0, "followed": 0}
    decide = vf.filter

    def counting(*args, **kwargs):
        applied, info = decide(*args, **kwargs)
        before, now = kwargs.get("plan"), np.atleast_2d(info["plan"])
        seen["started"] += int(((now[:, 2] == PLAN_LAND) & (now[:, 1] > 0)).sum())
        if before is not None:
            # followed: the same candidate, one period less (a passing action may also end a plan early)
            before = np.atleast_2d(before)
            seen["followed"] += int(((before[:, 2] == PLAN_LAND) & (before[:, 1] > 0) & (now[:, 2] == PLAN_LAND)
                                     & (now[:, 0] == before[:, 0]) & (now[:, 1] == before[:, 1] - 1)).sum())
        return applied, info

    monkeypatch.setattr(vf, "filter", counting)
    rng = np.random.default_rng(5)
    x = rng.uniform([-15, 0], [15, 18], (4000, 2))
    for policy in ("always_max", "anti_optimal", "random"):
        for x0 in x[vf.landing_cells.contains(0.0, x, 0.3)][:4]:
            row = Row(policy, "worst_case", "certified", True)
            out = run_episode(vf, vf, x0, 0.3, _policy(policy, vf, rng), _wind("worst_case", vf, rng, 4), 4,
                              vf.model.substeps, row, False)
            assert out["landed"] and not out["hard"] and out["budget_used"] <= 0.3 + 1e-9
    assert seen["started"] > 0 and seen["followed"] > 0, seen


def test_the_cover_test_is_every_touched_cell_good_at_the_budget(vf):
    """``CellCertificate.covered`` (the compiled cover test both filter paths use) against the definition written
    out cell by cell: along each axis, the cells from the last whose float box (as the builder has it) starts at or
    below the box's lower end to the first that ends at or above its upper end are all good at the step's budget
    index; off the grid, past ``T`` or at a negative budget nothing is. Boxes of one cell, of runs along either axis
    and of blocks, on and past the grid's edges and reaching its top exactly, with budgets at, below and above the
    cells' own."""
    rng = np.random.default_rng(11)
    for cells in (vf.landing_cells,):
        n = 3000
        lo = rng.uniform(cells.lo - 0.05 * (cells.hi - cells.lo), cells.hi, (n, 2))
        hi = lo + rng.uniform(0, 6, (n, 2)) * cells.width * (rng.random((n, 2)) < 0.8)
        # boxes reaching the grid's top exactly along one axis, from at most two cells below it
        top = np.arange(0, n, 10)
        axis = rng.integers(0, 2, len(top))
        hi[top, axis] = cells.hi[axis]
        lo[top, axis] = cells.hi[axis] - rng.uniform(0, 2, len(top)) * cells.width[axis]
        t = rng.choice(np.arange(cells.steps + 2) * cells.dt, n) + rng.choice([0.0, 0.3 * cells.dt], n)
        k = np.array([step_index(v, cells.dt, cells.steps) for v in t])
        z = rng.uniform(-0.01, 1.2 * cells.top * cells.dz, n)
        got = cells.covered(t, lo, hi, z)
        # the cells' float boxes along each axis, as the builder has them (cell_game.cell_boxes)
        edges = [cells.lo[a] + np.arange(cells.shape[a] + 1) * cells.width[a] for a in range(2)]
        for r in range(n):
            # from the last cell whose box starts at or below lo to the first whose box ends at or above hi
            first = [np.searchsorted(e, v, side="right") - 1 for e, v in zip(edges, lo[r])]
            last = [max(np.searchsorted(e, v, side="left") - 1, 0) for e, v in zip(edges, hi[r])]
            on = all(e[0] <= a and b <= e[-1] for e, a, b in zip(edges, lo[r], hi[r]))
            if not on or t[r] > cells.horizon + 1e-9 * cells.dt or z[r] < 0:
                assert not got[r], r
                continue
            block = cells.m[k[r]][tuple(slice(int(f), int(g) + 1) for f, g in zip(first, last))]
            index = int(np.floor(min(z[r], cells.top * cells.dz) / cells.dz + 1e-12))
            index -= index * cells.dz > z[r]
            assert got[r] == bool((block <= index).all()), r
        assert 0.05 < got.mean() < 0.95 and got[top].any()  # both answers are asked, at the top too


def test_empty_cells_certify_nothing(pointmass_held_table):
    """``CellCertificate.empty`` (what compiling ahead builds the filter with): a filter accepts it as its own cells,
    and it holds no state at any time or budget, so the filter certifies only states where a candidate surely lands
    within the period (which the enclosure proves without cells)."""
    model = get_model("pointmass")
    la = Lookahead.from_table(pointmass_held_table, model, DT, pointmass_held_table.eps, target_checks=model.substeps)
    empty = CellCertificate.empty(la)
    vf = ValueFilter(pointmass_held_table, DT, target_checks=model.substeps, landing_cells=empty)
    rng = np.random.default_rng(0)
    lo, hi = (np.asarray(b, float) for b in model.hard_box)
    x = rng.uniform(lo, hi, (500, 2))
    t, z = rng.uniform(0.0, 1.0, 500), rng.uniform(0.0, 1.0, 500)
    assert not empty.contains(t, x, z).any()
    certified = vf.certify(0.0, x, 0.6)[0]
    passes, lands = candidate_verdicts(vf, 0.0, x, 0.6)
    np.testing.assert_array_equal(passes, lands)
    np.testing.assert_array_equal(certified, lands.any(axis=1))
    assert 0 < certified.sum() < len(x)


def test_the_default_budget_cell_fits_long_horizons_and_a_finer_one_is_refused(pointmass_held_table, monkeypatch):
    """The default budget cell is accepted at horizons where it is set by the stored indices' bound (``horizon /
    MAX_BUDGET_CELLS``, where ``horizon / dz`` rounds either way), and a finer one is refused, naming it, before
    anything is solved."""
    from softreach.reach.proof import cell_certificate, cell_game

    monkeypatch.setattr(cell_game, "solve", lambda cls, la, key: key["dz"])
    monkeypatch.setattr(cell_certificate, "check_model_for_filter", lambda *a, **k: None)
    model = get_model("pointmass")
    la = Lookahead.from_table(pointmass_held_table, model, DT, pointmass_held_table.eps)
    for horizon in (1.0, 579.76, 589.73, 729.31, 2000.0):
        la.horizon = horizon
        dz = CellCertificate.build(la, SHAPE)
        assert dz == cell_certificate.default_dz(DT, horizon)
        assert cell_certificate.budget_top(dz, horizon) <= cell_certificate.MAX_BUDGET_CELLS
    with pytest.raises(ValueError, match=r"dz must be .* got 0\.0125"):
        CellCertificate.build(la, SHAPE, dz=0.0125)  # 2000 s in budget cells of 12.5 ms: 160,000


def test_a_state_is_read_in_the_cell_whose_float_box_holds_it():
    """``cell_span``, the cells' one look-up (the builder's end boxes, the filter's states and boxes), against the
    builder's own float boxes (``cell_game.cell_boxes``), at every edge of every packaged file's axes: a state on an
    edge or one ulp either side of it lies in the box of the first and of the last cell it is read in (along a
    periodic axis, a state the env has wrapped into the period, read unwidened), and a box whose ends lie one ulp
    outside a cell's edges is read over the cells beyond them. At hundreds of those edges ``floor((x - lo) /
    width)`` alone rounds across the edge, into a cell whose box misses ``x``."""
    from softreach.reach.proof.cell_certificate import PACKAGED
    from softreach.reach.proof.cell_game import cell_boxes
    from softreach.reach.proof.kernels import cell_span

    rounded_across = 0
    for path in sorted(PACKAGED.glob("cells-*.npz")):
        cells = CellCertificate.load(path)
        for a in range(len(cells.shape)):
            n, clo, width, periodic = int(cells.shape[a]), float(cells.lo[a]), float(cells.width[a]), cells.periodic[a]
            # the cells along axis a (the other axes' first): their boxes' ends along it, as the builder has them
            box_lo, box_hi = (b[:, a] for b in cell_boxes(cells, np.arange(n) * int(np.prod(cells.shape[a + 1:]))))
            edges = np.append(box_lo, box_hi[-1])
            assert (box_hi[:-1] == box_lo[1:]).all()
            for x in np.concatenate([np.nextafter(edges, -np.inf), edges, np.nextafter(edges, np.inf)]):
                if periodic and not edges[0] <= x < edges[-1]:
                    continue  # the env's wrap puts every heading in [lo, hi)
                first, last, on = cell_span(x, x, clo, width, n, periodic, 0.0)
                assert on == (edges[0] <= x <= edges[-1]), (path.name, a, x)
                if on:
                    assert first <= last and box_lo[first] <= x <= box_hi[first] and box_lo[last] <= x <= box_hi[last]
                    guess = min(int(np.floor((x - clo) / width)), n - 1)
                    rounded_across += not box_lo[guess] <= x <= box_hi[guess]
            for k in range(1, n - 1):
                lo, hi = np.nextafter(edges[k], -np.inf), np.nextafter(edges[k + 1], np.inf)
                first, last, on = cell_span(lo, hi, clo, width, n, periodic, 0.0)
                assert on and (first, last) == (k - 1, k + 1), (path.name, a, k, first, last)
    assert rounded_across > 100, rounded_across
