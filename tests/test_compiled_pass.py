"""The filter's compiled test (:mod:`softreach.reach.compiled_pass`) decides as the numpy test does, and what it
relies on holds: the declared set boxes are the model's set functions, their box maxima are the corner maxima,
and the compiled certificate is the table's interpolant."""

import numpy as np
import pytest

from softreach.filters import ValueFilter
from softreach.reach import get_model, sets
from softreach.reach.compiled_pass import box_excess
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


def test_box_excess_is_the_largest_value_at_the_corners():
    model = get_model("pointmass")
    rng = np.random.default_rng(1)
    lo = np.c_[rng.uniform(-20, 20, 500), rng.uniform(-5, 20, 500)]
    hi = lo + rng.exponential(1.0, (500, 2))
    corners = [np.where(np.array(c, bool), hi, lo) for c in ((0, 0), (0, 1), (1, 0), (1, 1))]
    for which in ("hard_constraint", "soft_constraint"):
        expect = np.max([getattr(model, which)(0.0, [c[:, 0], c[:, 1]]) for c in corners], axis=0)
        b_lo, b_hi = (np.asarray(b, dtype=float) for b in model.set_boxes[which])
        got = np.array([box_excess(b_lo, b_hi, lo[i], hi[i]) for i in range(len(lo))])
        np.testing.assert_array_equal(got, expect)


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


def test_compiled_filter_decides_as_the_numpy_filter(pointmass_held_table):
    fast = ValueFilter(pointmass_held_table, 0.01)
    slow = ValueFilter(pointmass_held_table, 0.01)
    slow.compiled = None
    assert fast.compiled is not None
    t, x, z, a = _draws(2000, 5)
    applied, info = fast.filter(t, x, z, a)
    expect, expect_info = slow.filter(t, x, z, a)
    np.testing.assert_array_equal(applied, expect)
    _same(info, expect_info)
    # both kinds of rows occur, so both paths were compared
    assert 0.05 < (info["reason"] == 0).mean() < 0.95
    for i in range(0, 2000, 40):  # one row at a time: the call a SafetyFilter.step makes
        one, one_info = fast.filter(t[i], x[i], z[i], a[i])
        np.testing.assert_array_equal(one, applied[i])
        _same(one_info, {k: v[i] for k, v in info.items()})


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


def test_models_without_a_compiled_enclosure_keep_the_numpy_test(glider_held_table):
    assert get_model("glider").held_box_kernel is None
    assert ValueFilter(glider_held_table, 0.1, safe_cells=None, landing_cells=None).compiled is None
