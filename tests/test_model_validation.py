"""A model's declared boxes are checked where they are set (issue 39): a control or disturbance box with
``lower > upper`` is refused by name, with its values, by the model class, by ``softreach solve`` and on the way
into an environment, before any work; the other declared boxes and ranges likewise."""

from __future__ import annotations

import math
import sys
import textwrap

import numpy as np
import pytest

from softreach.reach.boxes import check_box
from softreach.reach.dynamics import ControlAndDisturbanceAffine
from softreach.reach.problem import Model
from softreach.reach.registry import get_model, make_env

# a cart (docs/models.md) whose boxes come from the constructor; the box was (2, -6) m/s^2
CART = '''
from cart_motion import CartMotion

from softreach.reach import Model
from softreach.reach.dynamics import ControlAndDisturbanceAffine


class Cart(CartMotion, Model, ControlAndDisturbanceAffine):
    default_shape = (11, 11)
    default_budget_points = 5
    control_period = 0.05
    start_box = ((-1.5, -0.5), (1.5, 0.5))
    start_budget = (0.0, 1.0)

    def __init__(self, accel=(-6.0, 2.0), push=(-0.5, 0.5)):
        self.accel, self.push = tuple(accel), tuple(push)
        self.control_bounds = ((accel[0],), (accel[1],))
        self.disturbance_bounds = ((push[0],), (push[1],))

    def parameters(self):
        return {"accel": list(self.accel), "push": list(self.push)}


class SwappedControl(Cart):
    def __init__(self):
        super().__init__(accel=(2.0, -6.0))


class SwappedDisturbance(Cart):
    def __init__(self):
        super().__init__(push=(0.5, -0.5))
'''

SWAPPED = {"SwappedControl": ("control_bounds", "2.0", "-6.0"), "SwappedDisturbance": ("disturbance_bounds", "0.5", "-0.5")}


@pytest.fixture
def cart_module(tmp_path, monkeypatch):
    """``cartmod`` importable from a temporary folder: the valid ``Cart`` and its two swapped variants."""
    (tmp_path / "cartmod.py").write_text(CART)
    monkeypatch.syspath_prepend(str(tmp_path))
    monkeypatch.chdir(tmp_path)
    yield __import__("cartmod")
    sys.modules.pop("cartmod", None)


def _names_the_box(message: str, cls: str) -> None:
    field, lo, hi = SWAPPED[cls]
    assert "'cart'" in message and field in message and lo in message and hi in message, message
    assert "\n" not in message.strip(), message


# ----------------------------------------------------------------------------------------------- the model itself

@pytest.mark.parametrize("cls", sorted(SWAPPED))
def test_the_model_refuses_a_swapped_box_when_built(cart_module, cls):
    with pytest.raises(ValueError) as info:
        getattr(cart_module, cls)()
    _names_the_box(str(info.value), cls)
    assert "lower <= upper" in str(info.value)


def test_a_swapped_box_in_the_class_body_is_refused_when_the_class_is_defined():
    with pytest.raises(ValueError, match=r"'bad'.*control_bounds.*lower 2\.0 > upper -6\.0"):
        class Bad(Model, ControlAndDisturbanceAffine):  # noqa: F841
            name = "bad"
            control_bounds = ((2.0,), (-6.0,))
    with pytest.raises(ValueError, match=r"'bad'.*disturbance_bounds.*axis 1 has lower 1\.0 > upper -1\.0"):
        class Bad2(Model, ControlAndDisturbanceAffine):  # noqa: F841
            name = "bad"
            disturbance_bounds = ((-1.0, 1.0), (1.0, -1.0))


def test_a_box_swapped_after_construction_is_refused_and_the_model_keeps_its_box():
    model = get_model("pointmass")
    good = model.control_bounds
    with pytest.raises(ValueError, match=r"'pointmass'.*control_bounds.*lower 60\.0 > upper -60\.0"):
        model.control_bounds = ((60.0,), (-60.0,))
    assert model.control_bounds == good
    with pytest.raises(ValueError, match=r"'pointmass'.*disturbance_bounds.*lower 10\.0 > upper -10\.0"):
        model.disturbance_bounds = ((10.0,), (-10.0,))


def test_the_check_names_shapes_and_values():
    ok = dict(field="control_bounds")
    check_box("m", ((-1.0, 0), (1.0, 0)), **ok)  # a zero-width input axis: a fixed input, allowed
    check_box("m", (np.array([-1.0]), np.array([1.0])), **ok)
    bad = [
        ((-1.0,), "a pair"),
        (((-1.0,), (1.0,), (2.0,)), "a pair"),
        ("ab", "a pair"),
        (((-1.0, 0.0), (1.0,)), "lower has 2 entries and upper 1"),
        (((-1.0,), ("1",)), "'1', not a real number"),
        (((True,), (2.0,)), "True, not a real number"),
        (((math.nan,), (1.0,)), "must be finite"),
        (((-math.inf,), (1.0,)), "must be finite"),
        (((0.0, 3.0), (1.0, 2.0)), "axis 1 has lower 3.0 > upper 2.0"),
    ]
    for box, words in bad:
        with pytest.raises(ValueError, match="m: control_bounds") as info:
            check_box("m", box, **ok)
        assert words in str(info.value), (box, str(info.value))
    # a grid's box needs width; an unbounded box takes -inf below and +inf above only
    with pytest.raises(ValueError, match="axis 'y' has zero width"):
        check_box("m", ((0.0, 1.0), (1.0, 1.0)), field="domain", strict=True, axis_names=("x", "y"))
    check_box("m", ((-math.inf, 0.0), (math.inf, 1.0)), field="target_box", unbounded=True)
    with pytest.raises(ValueError, match="-inf below and \\+inf above"):
        check_box("m", ((math.inf,), (math.inf,)), field="target_box", unbounded=True)


def test_the_other_declared_boxes_and_ranges_are_checked_by_name():
    model = get_model("dubins")
    with pytest.raises(ValueError, match=r"'dubins'.*domain.*axis 'y' has lower 4\.0 > upper -4\.0"):
        model.domain = ((-4.0, 4.0, -math.pi), (4.0, -4.0, math.pi))
    with pytest.raises(ValueError, match=r"'dubins'.*hard_box.*axis 'x' has zero width"):
        model.hard_box = ((1.0, -3.0, -math.pi), (1.0, 3.0, math.pi))
    with pytest.raises(ValueError, match=r"'dubins'.*start_box.*must be finite.*axis 'theta'"):
        model.start_box = ((-2.5, -1.0, math.nan), (-1.5, 1.0, 0.5))
    with pytest.raises(ValueError, match=r"'dubins'.*start_budget.*\(2\.0, 1\.0\)"):
        model.start_budget = (2.0, 1.0)
    with pytest.raises(ValueError, match=r"'dubins'.*horizon.*-1\.0"):
        model.horizon = -1.0
    model.start_box = None  # not declared: allowed (the env then asks for a start box)
    model.start_budget = 0.5


# ------------------------------------------------------------------------------------------------ softreach solve

@pytest.mark.parametrize("cls", sorted(SWAPPED))
def test_softreach_solve_refuses_a_swapped_box_before_any_work(cart_module, cls, capsys, tmp_path):
    from softreach.cli import main

    out = tmp_path / "cart.srt"
    assert main(["solve", f"cartmod:{cls}", "--accuracy", "low", "--quiet", "--out", str(out)]) == 2
    err = capsys.readouterr().err
    assert err.startswith("softreach: error: ") and err.count("\n") == 1, err
    _names_the_box(err, cls)
    assert not out.exists() and not list(tmp_path.glob("cart.srt*"))


def test_softreach_solve_refuses_a_class_defined_with_a_swapped_box(tmp_path, monkeypatch, capsys):
    from softreach.cli import main

    (tmp_path / "badcart.py").write_text(CART.replace("    start_box =", "    control_bounds = ((2.0,), (-6.0,))\n"
                                                      "    start_box ="))
    monkeypatch.syspath_prepend(str(tmp_path))
    monkeypatch.chdir(tmp_path)
    try:
        with pytest.raises(SystemExit) as info:  # argparse refuses the model argument
            main(["solve", "badcart:Cart", "--out", str(tmp_path / "c.srt")])
        assert info.value.code == 2
    finally:
        sys.modules.pop("badcart", None)
    err = capsys.readouterr().err
    assert "'cart'" in err and "control_bounds" in err and "lower 2.0 > upper -6.0" in err, err
    assert not (tmp_path / "c.srt").exists()


# -------------------------------------------------------------------------------------------------- environments

@pytest.mark.parametrize("cls", sorted(SWAPPED))
def test_the_environment_refuses_a_swapped_box(cart_module, cls):
    with pytest.raises(ValueError) as info:
        make_env(f"cartmod:{cls}")
    _names_the_box(str(info.value), cls)
    with pytest.raises(ValueError, match="PointMassParams.u_max must be positive"):
        make_env("pointmass", model_params={"u_max": -60.0})


def test_the_environment_maps_plus_one_to_the_upper_end_of_the_box(cart_module):
    """The valid cart's box is (-6, 2) m/s^2: +1 applies 2, -1 applies -6, 0 the centre (not the reverse)."""
    env = make_env("cartmod:Cart").unwrapped
    assert env.physical_action(np.array([1.0, -1.0, 0.0])[:, None]).ravel().tolist() == [2.0, -6.0, -2.0]
    env.reset(seed=0)
    before = env.state[1]
    env.step(np.array([1.0], dtype=np.float32))
    # one 0.05 s period at +2 m/s^2 with a push of at most 0.5 m/s^2 either way
    assert 0.05 * 1.5 - 1e-9 <= env.state[1] - before <= 0.05 * 2.5 + 1e-9
