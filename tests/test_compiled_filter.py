"""What the filter's compiled decision (:mod:`softreach.filters.compiled`) relies on holds: the declared set boxes
are the model's set functions, the compiled set maxima over boxes are the largest values at the corners, and the
compiled certificate is the table's interpolant; it decides the same with and without diagnostics, in threads and
for tables made in this process. The decision itself is tested against the reference of ``docs/filters.md`` in
``tests/test_filter_reference.py``."""

import itertools

import numpy as np
import pytest

from softreach.filters import PASS, PLAN_LAND, ValueFilter
from softreach.reach import get_model, sets
from softreach.reach.proof.model_kernels import SET_INDEX, set_max_address, set_max_rows
from softreach.reach.registry import model_names

SETS = ("target", "hard_constraint", "soft_constraint")


@pytest.mark.parametrize("name", model_names())
def test_declared_set_boxes_are_the_set_functions(name):
    model = get_model(name)
    if not model.set_boxes:
        pytest.skip(f"{name} declares no set boxes")
    lo, hi = (np.asarray(b, dtype=float) for b in model.domain)
    rng = np.random.default_rng(0)
    x = rng.uniform(lo - 0.2 * (hi - lo), hi + 0.2 * (hi - lo), (2000, len(lo)))
    for which in SETS:
        box = model.set_boxes[which]
        cols = [x[:, i] for i in range(len(lo))]
        np.testing.assert_array_equal(getattr(model, which)(0.0, cols), sets.box(cols, *box), err_msg=which)


@pytest.mark.parametrize("name", model_names())
def test_set_kernels_are_the_largest_values_at_the_corners(name):
    """Boxes across and beyond the domain, wide and narrow, some of no width: the compiled maximum of each set
    equals the largest value of the model's own set function at the box's corners, to the bit, where the corners
    bound it (a set whose maximum the model bounds itself, ``set_box_max``, as Dubins's obstacle and zone, is checked
    against sampled values by the model's tests)."""
    model = get_model(name)
    if model.set_max_kernel is None:
        pytest.skip(f"{name} gives no compiled set maxima")
    d_lo, d_hi = (np.asarray(b, dtype=float) for b in model.domain)
    n = len(d_lo)
    rng = np.random.default_rng(1)
    lo = rng.uniform(d_lo - 0.2 * (d_hi - d_lo), d_hi + 0.2 * (d_hi - d_lo), (3000, n))
    hi = lo + (d_hi - d_lo) * rng.exponential(0.05, (3000, n))
    hi[::10] = lo[::10]
    lo[5::50, -1] = np.nan  # a failed enclosure: NaN, as at the corners
    address, params = set_max_address(model), model.set_max_params
    for which, index in SET_INDEX.items():
        if model.set_box_max(which, 0.0, lo[:1], hi[:1]) is not None:
            continue
        expect = np.max([getattr(model, which)(0.0, [np.where(c[i], hi[:, i], lo[:, i]) for i in range(n)])
                         for c in itertools.product((False, True), repeat=n)], axis=0)
        got = np.empty(len(lo))
        set_max_rows(address, params, index, lo, hi, got)
        np.testing.assert_array_equal(got, expect, err_msg=f"{name} {which}")


def _draws(n, seed):
    """States across and beyond ``C1``, budgets from negative to above the table's, times up to past ``T``, actions
    random and at the candidates (the policies an audit runs)."""
    rng = np.random.default_rng(seed)
    x = np.c_[rng.uniform(-17, 17, n), rng.uniform(-1, 20, n)]
    z = rng.uniform(-0.05, 0.7, n)
    t = np.round(rng.uniform(0, 1.0, n), 2)
    t[::7] = rng.uniform(0, 1.01, len(t[::7]))
    a = rng.uniform(-60, 60, (n, 1))
    a[::3] = rng.choice([-60.0, 60.0, 9.81, 0.0], (len(a[::3]), 1))
    return t, x, z, a


def _same(info_a, info_b):
    for key in info_a:
        u, v = np.asarray(info_a[key]), np.asarray(info_b[key])
        assert u.shape == v.shape and np.array_equal(u, v, equal_nan=u.dtype.kind == "f"), key


def _rows(vf, t, x, z, a):
    """``vf.filter`` without diagnostics one row at a time (the one-row path), stacked as a batch's answer."""
    out = [vf.filter(t[i], x[i], z[i], a[i], diagnostics=False) for i in range(len(x))]
    return np.stack([o[0] for o in out]), {k: np.stack([o[1][k] for o in out]) for k in out[0][1]}


@pytest.mark.parametrize("rule", ["switch", "smooth"])
def test_without_diagnostics_the_same_decisions(pointmass_held_table, rule):
    """``diagnostics=False`` leaves out the certificate at the state and the passing policy action's next one, in a
    batch and one row at a time: every action, reason, plan and the replaced rows' ``lookahead`` are those of the
    full decision."""
    vf = ValueFilter(pointmass_held_table, 0.01, rule=rule)
    t, x, z, a = _draws(1500 if rule == "switch" else 300, 9)
    applied, info = vf.filter(t, x, z, a)
    passed = info["reason"] == PASS
    assert 0.05 < passed.mean() < 0.95
    for one_row in (False, True):
        lean, lean_info = (vf.filter(t, x, z, a, diagnostics=False) if not one_row else
                           _rows(vf, t, x, z, a))
        np.testing.assert_array_equal(lean, applied)
        assert np.isnan(lean_info["value"]).all() and np.isnan(lean_info["lookahead"][passed]).all()
        np.testing.assert_array_equal(lean_info["lookahead"][~passed], info["lookahead"][~passed])
        _same({k: v for k, v in lean_info.items() if k not in ("value", "lookahead")},
              {k: v for k, v in info.items() if k not in ("value", "lookahead")})
    with pytest.raises(TypeError, match="diagnostics must be True or False, got 'no'"):
        vf.filter(t, x, z, a, diagnostics="no")


def _reference_key(bad):
    """A compiled badness as the reference's key ``(class, tie)`` (``tests/reference_decision.py``,
    ``ReferenceDecision._bad_key``): the rank offsets of :mod:`softreach.filters.reasons` named by class."""
    from softreach.filters.reasons import RANK_KEPT, RANK_LEAVES_C1, RANK_OVERSPENT

    if bad == np.inf:
        return 3, 0.0
    if bad >= RANK_LEAVES_C1:
        return 2, bad - RANK_LEAVES_C1
    ranks = {RANK_KEPT: 0, RANK_OVERSPENT: 1}
    rank = min(ranks, key=lambda r: abs(bad - r))
    return ranks[rank], bad - rank


def _same_key(a, b):
    return a[0] == b[0] and (a[1] == b[1] or abs(a[1] - b[1]) <= 1e-9 * max(1.0, abs(a[1]), abs(b[1])))


def test_badness_is_the_references(pointmass_held_table):
    """The compiled badness of candidates where none passes (:func:`softreach.filters.judge.badness`) against the
    reference's order of failing actions (``tests/reference_decision.py``: the budget kept, the next value and the
    overspend, then how far ``C1`` may be left), candidate by candidate, on rows where few states pass."""
    from reference_decision import ReferenceDecision
    from softreach.filters.compiled import decision_space
    from softreach.filters.judge import badness, judge

    vf = ValueFilter(pointmass_held_table, 0.01)
    ref = ReferenceDecision(vf)
    fast, la = vf.compiled, vf.lookahead
    J = len(fast.cands)
    work = decision_space(la.n, fast.cands.shape[1], J)[0].work
    t, x, z, _ = _draws(150, 3)
    classes = set()
    for r in range(len(x)):
        judged = [ref.judge(float(t[r]), x[r], x[r], float(z[r]), c) for c in fast.cands]
        end_lo, end_hi = np.empty((J, la.n)), np.empty((J, la.n))
        in_c1, bounded, kept = (np.empty(J, bool) for _ in range(3))
        c1, z_end = np.empty(J), np.empty(J)
        for j in range(J):
            v = judge(fast.enclose, fast.M, fast.C, t[r], x[r], x[r], z[r], fast.cands[j], end_lo[j], end_hi[j],
                      work)
            bounded[j], in_c1[j], kept[j], c1[j], z_end[j] = v.bounded, v.in_c1, v.kept or v.lands, v.c1, v.z_end
        got = np.full(J, np.nan)
        badness(fast.T, min(t[r] + 0.01, la.horizon), end_lo, end_hi, work, in_c1, bounded, kept, c1, z_end, got)
        for k in range(J):
            if judged[k].passes:
                continue
            want = ref._bad_key(judged[k])
            assert _same_key(_reference_key(got[k]), want), (r, k, got[k], want)
            classes.add(want[0])
    assert {0, 2} <= classes  # the budget kept, leaving C1: each with next values that move the tie


def test_blocks_cover_every_row_once_and_raise_a_blocks_error():
    from softreach.reach.proof.blocks import PARALLEL_MIN_ROWS, run_in_blocks

    for rows, threads, blocks in ((10, 4, 1), (2 * PARALLEL_MIN_ROWS - 1, 4, 1), (5 * PARALLEL_MIN_ROWS, 3, 3)):
        seen = []
        run_in_blocks(lambda lo, hi: seen.append((lo, hi)), rows, threads)
        seen.sort()
        assert len(seen) == blocks and seen[0][0] == 0 and seen[-1][1] == rows
        assert all(a[1] == b[0] and a[0] < a[1] for a, b in zip(seen, seen[1:]))

    def fail_late(lo, hi):
        if lo > 0:
            raise RuntimeError(f"block {lo}")

    with pytest.raises(RuntimeError, match="block"):
        run_in_blocks(fail_late, 4 * PARALLEL_MIN_ROWS, 2)
    for bad in (0, -1, 1.5, "2", True):
        with pytest.raises(ValueError, match=f"threads .* got {bad!r}"):
            run_in_blocks(lambda lo, hi: None, 10, bad)


def test_threads_decide_as_one_thread(pointmass_held_table):
    """A batch cut into blocks for several threads (uneven block sizes, plans fed back, with and without the
    diagnostics) gives every row exactly what one thread gives it."""
    from softreach.reach.proof.blocks import PARALLEL_MIN_ROWS

    one, many = ValueFilter(pointmass_held_table, 0.01), ValueFilter(pointmass_held_table, 0.01)
    one.threads, many.threads = 1, 3
    t, x, z, a = _draws(3 * PARALLEL_MIN_ROWS + 17, 12)
    plan = None
    for diagnostics in (True, False):
        applied, info = one.filter(t, x, z, a, plan=plan, diagnostics=diagnostics)
        got, got_info = many.filter(t, x, z, a, plan=plan, diagnostics=diagnostics)
        np.testing.assert_array_equal(got, applied)
        _same(got_info, info)
        # the second round follows plans: each row's own, else candidate 0 for two more periods
        plan = np.where(info["plan"][:, :1] >= 0, info["plan"], np.array([0, 2, PLAN_LAND]))
    assert (info["plan"][:, 0] >= 0).any()  # rows where no candidate passes followed the plans fed back


def test_compiled_certificate_is_the_tables_interpolant(pointmass_held_table):
    """The compiled certificate against :meth:`Table.value` (the interpolation engine): ``min(V, W_eps)``."""
    table = pointmass_held_table
    la = ValueFilter(table, 0.01).lookahead
    t, x, z, _ = _draws(3000, 7)
    z = np.abs(z)
    got = la.certificate(t, x, z)
    expect = np.minimum(table.value(t, x, z), table.value(t, x))
    finite = np.isfinite(expect)
    np.testing.assert_array_equal(np.isfinite(got), finite)
    np.testing.assert_allclose(got[finite], expect[finite], rtol=0, atol=1e-12)


def _glider_draws(model, n, seed):
    """Glider states across and beyond the table's domain, budgets from negative to above the table's, times up to
    past ``T``, angles of attack random and at the ends of their box."""
    rng = np.random.default_rng(seed)
    lo, hi = (np.asarray(b, dtype=float) for b in model.domain)
    x = rng.uniform(lo - 0.05 * (hi - lo), hi + 0.05 * (hi - lo), (n, 3))
    z = rng.uniform(-0.5, 11.0, n)
    t = np.round(rng.uniform(0, 1.01 * model.horizon, n), 1)
    (a_lo,), (a_hi,) = model.control_bounds
    a = rng.uniform(a_lo, a_hi, (n, 1))
    a[::3] = rng.choice([a_lo, a_hi], (len(a[::3]), 1))
    return t, x, z, a


def test_a_model_without_an_enclosure_is_refused_first(dubins_held_table, monkeypatch):
    """A model without the compiled enclosure is refused at the filter's construction, with one line naming what
    to add, before any cell is built."""
    from softreach.filters import core

    model = get_model("dubins")
    model.held_box_kernel = None  # an instance without the compiled enclosure

    def no_cells(*args, **kwargs):
        raise AssertionError("cells built for a model the filter refuses")

    monkeypatch.setattr(core, "resolve_cells", no_cells)
    with pytest.raises(ValueError, match=r"model 'dubins': add to Dubins: held_box_kernel\(params") as err:
        ValueFilter(dubins_held_table, 0.1, model=model)
    assert "\n" not in str(err.value) and "docs/models.md" in str(err.value)


def test_the_decisions_order_of_candidates_is_numpys_stable_argsort():
    """The decision orders candidates by preference without allocating (``_stable_order``, an insertion sort): the
    order of ``np.argsort(kind="stable")``, ties in index order and NaN last, on keys with ties, infinities and
    NaN."""
    import numba as nb

    from softreach.filters.compiled import _stable_order

    @nb.njit
    def order(keys):
        out = np.empty(len(keys), np.int64)
        _stable_order(keys, out)
        return out

    rng = np.random.default_rng(5)
    for J in (1, 2, 6, 13):
        for _ in range(200):
            keys = rng.choice([0.0, 1.0, 2.5, -3.0, np.inf, -np.inf, np.nan], J) + (rng.random(J) < 0.3) * rng.random(J)
            assert np.array_equal(order(keys), np.argsort(keys, kind="stable")), keys


def test_tables_and_inputs_made_in_this_process_reuse_the_compiled_decision(pointmass_held_table):
    """numba compiles a loop once per argument type, and an array's type says whether it is writable: a loaded
    table is a read-only memory map, one made in this process is writable, and so may be a caller's states. The
    decision of a writable table, cells and inputs must not be a second compilation (tens of seconds) of the
    same loop."""
    from softreach.filters.compiled import decide_rows
    from softreach.reach import load_table
    from softreach.reach.proof.cell_certificate import CellCertificate

    t, x, z, a = _draws(50, 3)
    loaded = ValueFilter(pointmass_held_table, pointmass_held_table.control_period)
    expect, _ = loaded.filter(t, x, z, a)
    compiled = len(decide_rows.signatures)
    table = load_table(pointmass_held_table.path)
    for name in ("W_eps", "V"):
        table._arrays[name] = np.array(table.values(name))
        assert table.values(name).flags.writeable
    cells = loaded.landing_cells
    land = CellCertificate(cells.lo, cells.hi, np.array(cells.m), np.array(cells.action), np.array(cells.hold),
                           cells.candidates, cells.dt, cells.dz, cells.horizon, cells.key)
    made = ValueFilter(table, table.control_period, landing_cells=land)
    frozen_x = x.copy()
    frozen_x.flags.writeable = False
    applied, _ = made.filter(t, frozen_x, z, a)
    np.testing.assert_array_equal(applied, expect)
    # a flag given as an int or a numpy bool, for a batch and for one row
    q = np.clip(a / 60.0, -1.0, 1.0)
    for flag in (1, np.True_):
        np.testing.assert_array_equal(made.filter(t, x, z, q, normalized=flag)[0],
                                      loaded.filter(t, x, z, q, normalized=True)[0])
        made.filter(float(t[0]), x[0], float(z[0]), q[0], normalized=flag)
    assert len(decide_rows.signatures) == compiled


def test_softreach_compile_leaves_the_decision_in_numbas_cache(pointmass_held_table, dubins_held_table, capsys,
                                                               monkeypatch):
    """``softreach compile TABLE`` runs the compiled entry points (a decision, a state's certificate, a start-plan
    search), for a model with cells and one without, and what they run is in numba's on-disk cache, where the next
    process finds it (``load_overload`` reads the cache files, not this process's code)."""
    from softreach.cli import main
    from softreach.filters.compiled import CompiledDecision, decide_rows
    from softreach.filters.compiled_starts import start_plan_rows

    calls = []
    # _arguments: the decision of a batch and of one row alike
    for name in ("_arguments", "certify", "start_plans"):
        real = getattr(CompiledDecision, name)
        monkeypatch.setattr(CompiledDecision, name,
                            lambda self, *a, _real=real, _name=name, **k: calls.append(_name) or _real(self, *a, **k))
    assert main(["compile", str(pointmass_held_table.path), str(dubins_held_table.path)]) == 0
    assert sorted(set(calls)) == ["_arguments", "certify", "start_plans"]
    out = capsys.readouterr().out.splitlines()
    assert "pointmass's filter" in out[0] and str(decide_rows.stats.cache_path) in out[0]
    assert "dubins's filter" in out[1] and str(decide_rows.stats.cache_path) in out[1]
    for kernel in (decide_rows, start_plan_rows):
        assert kernel.signatures
        assert all(kernel._cache.load_overload(sig, kernel.targetctx) is not None for sig in kernel.signatures)
