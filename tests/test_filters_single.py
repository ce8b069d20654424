"""One plain row (:mod:`softreach.filters.single`, the call a ``SafetyFilter.step`` makes) is decided as the batched
path decides it: the same actions and ``info``, bit for bit and of the same types, in closed loop with the plans,
in both action conventions, for both rules; and inputs it does not take still reach the batched path's checks."""

import numpy as np
import pytest

from softreach.filters import AFTER_HORIZON, BLEND, OPTIMAL, OUTSIDE, PASS, UNCERTIFIED, ValueFilter
from softreach.filters.single import filter_one


def _draws(n, seed):
    """States across and beyond ``C1`` and the grid, budgets negative to above the table's, times up to past ``T``; normalised
    actions inside and beyond ``[-1, 1]``, some float32 (what a policy gives)."""
    rng = np.random.default_rng(seed)
    x = np.c_[rng.uniform(-17, 17, n), rng.uniform(-1, 20, n)]
    x[::13, 1] = rng.uniform(20.5, 24, len(x[::13]))  # above the grid
    z = rng.uniform(-0.05, 0.7, n)
    t = np.round(rng.uniform(0, 1.0, n), 2)
    t[::7] = rng.uniform(0, 1.01, len(t[::7]))
    a = rng.uniform(-1.2, 1.2, (n, 1))
    a[::3] = rng.choice([-1.0, 1.0, 0.0, 0.1635], (len(a[::3]), 1))
    return t, x, z, a


def _batched(vf, t, x, z, a, **kw):
    """The batched path's answer for one row (its inputs as lists, which the one-row path leaves to it)."""
    return vf.filter(float(t), x.tolist(), float(z), a.tolist(), **kw)


def _identical(got, expect):
    """Equal to the bit, with the same type, shape and dtype."""
    assert type(got) is type(expect)
    if isinstance(got, tuple):
        assert len(got) == len(expect)
        for g, e in zip(got, expect):
            _identical(g, e)
        return
    if isinstance(got, dict):
        assert list(got) == list(expect)
        for key in got:
            _identical(got[key], expect[key])
        return
    g, e = np.asarray(got), np.asarray(expect)
    assert g.shape == e.shape and g.dtype == e.dtype
    # the bytes: NaN is NaN, and -0.0 is not 0.0
    assert g.tobytes() == e.tobytes()


@pytest.mark.parametrize("rule", ["switch", "smooth"])
def test_one_plain_row_is_the_batched_decision(pointmass_held_table, rule):
    vf = ValueFilter(pointmass_held_table, 0.01, rule=rule)
    assert vf.compiled is not None
    t, x, z, a = _draws(400 if rule == "switch" else 120, 3)
    t[5::17] = vf.lookahead.horizon
    # a certified fall near the soft speed limit, the policy pushing down: the filter replaces the action
    t[1], x[1], z[1], a[1] = 0.0, (-9.9, 8.0), 0.0, -1.0
    reasons = set()
    for i in range(len(x)):
        action = a[i].astype(np.float32) if i % 2 else a[i]
        for normalized in (True, False):
            act = action if normalized else (action * 60.0).astype(action.dtype)
            for diagnostics in (True, False):
                got = filter_one(vf, t[i], x[i], z[i], act, normalized, None, diagnostics)
                assert got is not None, i
                expect = _batched(vf, t[i], x[i], z[i], act, normalized=normalized, diagnostics=diagnostics)
                _identical(got, expect)
                # and through the public call, which takes the one-row path for these inputs
                _identical(vf.filter(t[i], x[i], z[i], act, normalized=normalized, diagnostics=diagnostics), expect)
                reasons.add(int(got[1]["reason"]))
    # rows that pass, that are replaced, uncertified, off the table and after the horizon were all compared
    assert {PASS, OPTIMAL if rule == "switch" else BLEND, OUTSIDE, AFTER_HORIZON, UNCERTIFIED} <= reasons, reasons
    # one compiled code serves one row and a batch (a second would be a second compilation of about 40 s)
    from softreach.filters.compiled import decide_rows

    compiled = len(decide_rows.signatures)
    vf.filter(t, x, z, a, normalized=True, plan=np.zeros((len(x), 3), np.int64))
    assert len(decide_rows.signatures) == compiled


def test_plans_are_followed_as_in_a_batch(pointmass_held_table):
    """Closed loop, each step's plan fed to the next, from starts in the landing cells and starts that only a plan
    of their own certifies (followed from the first step), the policy random, the wind switching at random: the
    one-row path and the batched path give the same steps all along."""
    from softreach.agents.audit import sample_starts

    vf = ValueFilter(pointmass_held_table, 0.01)
    p = vf.model.params
    rng = np.random.default_rng(11)
    x = np.c_[rng.uniform(-14, 14, 3000), rng.uniform(0, 17, 3000)]
    z = rng.uniform(0, 0.6, 3000)
    keep = np.nonzero(vf.landing_cells.contains(0.0, x, z))[0][:30]
    starts = [(x[i], z[i]) for i in keep] + [(s, 0.3) for s in sample_starts(vf, 0.3, "planned", 30, rng)]
    followed = 0
    for x, z in starts:
        t, x = 0.0, x.copy()
        plan = np.asarray(vf.certify_start(t, x, z)[3], np.int64).reshape(-1, 3)[0]
        for _ in range(40):
            action = rng.uniform(-1, 1, 1)
            got = filter_one(vf, t, x, z, action, True, plan, True)
            _identical(got, _batched(vf, t, x, z, action, normalized=True, plan=plan))
            followed += int(got[1]["plan"][0] >= 0)
            plan = got[1]["plan"]
            # one period of the exact motion under a wind at either bound
            acc = vf.physical(got[0])[0] - p.gravity + rng.choice([-1.0, 1.0]) * p.d_max
            x = np.array([x[0] + acc * 0.01, x[1] + x[0] * 0.01 + 0.5 * acc * 0.01 ** 2])
            z = z - 0.01 * float(np.clip(vf.model.soft_constraint(0.0, [x[:1], x[1:]])[0] / vf.eps, 0, 1))
            t += 0.01
    assert len(starts) > 40 and followed > 30, (len(starts), followed)


def test_other_inputs_take_the_batched_path_with_its_checks(pointmass_held_table):
    vf = ValueFilter(pointmass_held_table, 0.01)
    x, a = np.array([1.0, 5.0]), np.array([0.3])
    assert filter_one(vf, 0.3, x, 0.3, a, True, None, True) is not None
    for args in ((0.3, x.tolist(), 0.3, a), (0.3, x[None], 0.3, a[None]), (np.array([0.3]), x, 0.3, a),
                 (0.3, x.astype(int), 0.3, a), (0.3, x, 0.3, a, [-1, 0, 0])):
        assert filter_one(vf, *args[:4], True, args[4] if len(args) > 4 else None, True) is None
    for bad, name in (((np.nan, x, 0.3, a), "t"), ((0.3, np.array([1.0, np.inf]), 0.3, a), "x"),
                      ((0.3, x, np.nan, a), "z"), ((0.3, x, 0.3, np.array([np.nan])), "action")):
        assert filter_one(vf, *bad, True, None, True) is None
        with pytest.raises(ValueError, match=f"{name} must be finite"):
            vf.filter(*bad, normalized=True)
    with pytest.raises(ValueError, match="action must have shape"):
        vf.filter(0.3, x, 0.3, np.array([0.3, 0.1]), normalized=True)
    with pytest.raises(ValueError, match="plan must be"):
        vf.filter(0.3, x, 0.3, a, plan=np.array([1.5, 0.0, 0.0]))
    vf.threads = 0
    with pytest.raises(ValueError, match="threads"):
        vf.filter(0.3, x, 0.3, a)
