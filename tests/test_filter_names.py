"""The filter's numbers and arguments by name (issue 37): the reason codes and the rank offsets have one home
(:mod:`softreach.filters.reasons`), where the ranks' order leaves room for every tie, the
compiled code reads its arguments by name, and a control box that an environment or the filter normalises by
has a width on every axis."""

from __future__ import annotations

import math
import re
from pathlib import Path

import pytest

from softreach.filters import reasons

ROOT = Path(__file__).resolve().parents[1]
#: the filter's sources: the filters package and the one-period test's parameters
SOURCES = sorted((ROOT / "filters").glob("*.py")) + [ROOT / "reach" / "proof" / "lookahead.py"]
#: a kept budget's tie lies in (-0.5, 0.5): atan(next) / pi (filters/reasons.py)
TIE = 0.5


def test_ranks_leave_room_for_every_tie():
    """The badness of a failing action is its rank plus its tie; the filter's choices rely on the ranks' order
    surviving any tie of a budget-kept action (an overspend's tie of at most a period's budget, ``1e3 dt``, too)."""
    r = reasons
    # each kind of failing action, in the order the filter prefers them
    order = [r.RANK_KEPT, r.RANK_OVERSPENT, r.RANK_LEAVES_C1]
    for lower, upper in zip(order, order[1:]):
        assert upper - lower >= 1e6 > 2 * TIE + r.TIE_OVERSPEND * 10.0, (lower, upper)
    assert order[0] > 2 * TIE
    assert math.atan(r.TIE_INF) / math.pi < TIE


def test_reason_codes_are_distinct_and_named():
    codes = [reasons.PASS, reasons.BLEND, reasons.OPTIMAL, reasons.OUTSIDE, reasons.AFTER_HORIZON, reasons.FALLBACK,
             reasons.UNCERTIFIED]
    assert len(set(codes)) == len(codes) and set(reasons.REASONS) == set(codes)


def _code(path: Path) -> str:
    """The file's code without comments and docstrings' prose lines (which may cite numbers)."""
    return "\n".join(line.split("#")[0] for line in path.read_text().splitlines())


def test_no_source_writes_a_rank_offset_or_a_reason_code_of_its_own():
    offsets = re.compile(r"(?<![\w.])(1e6|3e6|5e6|1e3|1e12)(?![\w.])")
    defines = re.compile(r"^\s*_?(PASS|BLEND|OPTIMAL|OUTSIDE|AFTER_HORIZON|FALLBACK|UNCERTIFIED|PLAN_LAND|PLAN_SAFE)"
                         r"(\s*,\s*_?\w+)*\s*=", re.M)
    for path in SOURCES:
        code = _code(path)
        if path.name != "reasons.py":  # their home
            assert not offsets.findall(code), (path.name, offsets.findall(code))
        homes = {"reasons.py": {"PASS", "BLEND", "OPTIMAL", "OUTSIDE", "AFTER_HORIZON", "FALLBACK", "UNCERTIFIED"},
                 "plans.py": {"PLAN_LAND", "PLAN_SAFE"}}
        found = {m.group(1) for m in defines.finditer(code)}
        assert found <= homes.get(path.name, set()), (path.name, found)


def test_compiled_code_reads_its_arguments_by_name():
    positional = re.compile(r"\b(M|C|T|space|work|work_box|action)\[\d")
    for name in ("compiled.py", "compiled_starts.py", "judge.py"):
        code = _code(ROOT / "filters" / name)
        assert not positional.findall(code), (name, positional.findall(code))


# ----------------------------------------------------------------------------------- a control axis of no width

def _cart_with_a_fixed_input():
    """The cart of docs/models.md with a second control, a push held at 0.5 m/s^2 (a box of zero width there)."""
    from cart_motion import CartMotion

    from softreach.reach import Model
    from softreach.reach.dynamics import ControlAndDisturbanceAffine

    class FixedPushCart(CartMotion, Model, ControlAndDisturbanceAffine):
        default_shape = (11, 11)
        default_budget_points = 5
        control_period = 0.05
        start_box = ((-1.5, -0.5), (1.5, 0.5))
        start_budget = (0.0, 1.0)
        control_bounds = ((-6.0, 0.5), (2.0, 0.5))
        disturbance_bounds = ((-0.5,), (0.5,))

        def control_matrix(self, t, x):
            return [[0, 0], [1.0, 1.0]]

    return FixedPushCart()


def test_a_control_axis_of_no_width_is_refused_where_actions_are_normalised():
    """A solve may hold an input fixed (the model's own check allows it), but an environment's action space and
    the filter's map divide by the half-width: both refuse the box at once, naming the axis and its bounds, instead
    of a division by zero at the first step."""
    from softreach.reach.proof.lookahead import action_map
    from softreach.reach.registry import make_env

    model = _cart_with_a_fixed_input()  # accepted as a model
    words = r"'cart'.*control_bounds.*axis 1 has zero width \[0\.5, 0\.5\].*half-width"
    with pytest.raises(ValueError, match=words) as info:
        make_env(model)
    assert "\n" not in str(info.value)
    with pytest.raises(ValueError, match=words):
        action_map(model)
