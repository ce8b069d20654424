"""A model writes its motion bound once (issue 37 item 5, issue 38 item 2): the compiled ``held_box_kernel`` of
the cart of docs/models.md, the page's own code, bounds every motion exactly and rounds every end outwards (checked
in exact rational arithmetic), and the base class derives the filter's four enclosure methods from it, checking
their arguments, while a model without a kernel keeps what it writes itself."""

from __future__ import annotations

from fractions import Fraction

import numba as nb
import numpy as np
import pytest

from cart_motion import CartMotion, doc_cart

from softreach.reach import Model
from softreach.reach.dynamics import ControlAndDisturbanceAffine
from softreach.reach.proof.enclosure_check import EnclosureCheck, check_enclosure, missing_extras
from softreach.reach.proof.model_kernels import held_boxes

Cart = doc_cart().Cart


def _exact_box(x_lo, x_hi, u, push, s0, s1):
    """The tightest box of every cart state at some ``s`` in ``[s0, s1]`` from the box of starts, in exact rationals:
    ``v`` between the lines ``v + (u -+ push) s``, ``p`` between the parabolas ``p + v s + (u -+ push) s^2 / 2``
    (each reached by a constant extreme push), the extremes at ``s0``, ``s1`` or a vertex in between."""
    F = Fraction
    u, push, s0, s1 = F(u), F(push), F(s0), F(s1)

    def parabola(p, v, acc):
        ss = [s0, s1] + ([-v / acc] if acc != 0 and s0 < -v / acc < s1 else [])
        return [p + v * s + acc * s * s / 2 for s in ss]

    lo_acc, hi_acc = u - push, u + push
    p_lo, v_lo, p_hi, v_hi = F(x_lo[0]), F(x_lo[1]), F(x_hi[0]), F(x_hi[1])
    return ((min(parabola(p_lo, v_lo, lo_acc)), min(v_lo + lo_acc * s0, v_lo + lo_acc * s1)),
            (max(parabola(p_hi, v_hi, hi_acc)), max(v_hi + hi_acc * s0, v_hi + hi_acc * s1)))


def _random_boxes(rng, n):
    """Start boxes over ``C1`` (a quarter of them points), actions in the control box and at its corners, and
    sub-intervals of a period, some of one instant, some from 0."""
    lo = rng.uniform(-2.0, 2.0, (n, 2))
    width = rng.uniform(0.0, 0.1, (n, 2)) * (rng.random((n, 1)) > 0.25)
    a = rng.uniform(-2.0, 2.0, n)
    a[: n // 8] = rng.choice([-2.0, 2.0], n // 8)
    s = np.sort(rng.uniform(0.0, 0.05, (n, 2)), axis=1)
    s[: n // 4, 0] = 0.0
    s[n // 4: n // 2, 0] = s[n // 4: n // 2, 1]
    return lo, lo + width, a, s


def _kernel_box(model, x_lo, x_hi, a, s0, s1):
    lo, hi = np.empty(2), np.empty(2)
    model.held_box_kernel(model.held_box_params, x_lo, x_hi, np.array([a]), s0, s1, lo, hi)
    return lo, hi


def test_the_docs_cart_bound_is_the_exact_box_rounded_outwards():
    """Against exact rationals: every end lies outside the tightest box (a float rounded inwards would fail about
    half the rows) and within a few ulps of the magnitudes involved of it (the bound is exact, not merely sound)."""
    model = Cart()
    rng = np.random.default_rng(7)
    x_lo, x_hi, a, s = _random_boxes(rng, 400)
    for i in range(len(a)):
        lo, hi = _kernel_box(model, x_lo[i], x_hi[i], a[i], s[i, 0], s[i, 1])
        (e_p_lo, e_v_lo), (e_p_hi, e_v_hi) = _exact_box(x_lo[i], x_hi[i], a[i], 0.5, s[i, 0], s[i, 1])
        for got, exact, below in ((lo[0], e_p_lo, True), (lo[1], e_v_lo, True), (hi[0], e_p_hi, False),
                                  (hi[1], e_v_hi, False)):
            assert (Fraction(got) <= exact) if below else (Fraction(got) >= exact), (i, got, float(exact))
            # tight: each bound is at most 6 roundings deep (intervals.down / up), each moving its value by at
            # most 4 eps of it plus the smallest normal, and every value on the way is below 2.5 in magnitude
            assert abs(float(Fraction(got) - exact)) <= 6 * (4 * np.finfo(float).eps * 2.5 + 1e-300), (i, got)


@nb.njit(cache=False)
def _rounded_to_nearest(params, x_lo, x_hi, a, s0, s1, lo, hi):
    """The cart's bound without outward rounding: right on the reals, a rounding inside the box in floats."""
    acc_lo, acc_hi = a[0] - params[0], a[0] + params[0]
    lo[1] = min(x_lo[1] + acc_lo * s0, x_lo[1] + acc_lo * s1)
    hi[1] = max(x_hi[1] + acc_hi * s0, x_hi[1] + acc_hi * s1)
    lo[0] = min(x_lo[0] + x_lo[1] * s0 + 0.5 * acc_lo * s0 * s0, x_lo[0] + x_lo[1] * s1 + 0.5 * acc_lo * s1 * s1)
    hi[0] = max(x_hi[0] + x_hi[1] * s0 + 0.5 * acc_hi * s0 * s0, x_hi[0] + x_hi[1] * s1 + 0.5 * acc_hi * s1 * s1)


def test_the_exact_comparison_catches_a_bound_rounded_to_nearest():
    """The rational check above has teeth: the same bound in round-to-nearest floats lies inside the exact box
    for some of the same rows (end instants only, where it is right on the reals)."""
    model = Cart()
    model.held_box_kernel = _rounded_to_nearest
    rng = np.random.default_rng(7)
    x_lo, x_hi, a, s = _random_boxes(rng, 400)
    inside = 0
    for i in range(len(a)):
        s0 = s1 = s[i, 1]
        lo, hi = _kernel_box(model, x_lo[i], x_hi[i], a[i], s0, s1)
        (e_p_lo, e_v_lo), (e_p_hi, e_v_hi) = _exact_box(x_lo[i], x_hi[i], a[i], 0.5, s0, s1)
        inside += (Fraction(lo[0]) > e_p_lo) + (Fraction(lo[1]) > e_v_lo) + (Fraction(hi[0]) < e_p_hi) + (
            Fraction(hi[1]) < e_v_hi)
    assert inside > 50


def test_the_docs_cart_bound_holds_every_simulated_run_and_is_reached():
    """The enclosure check (switching pushes, box starts, the derived methods and the kernel): no run leaves a box,
    and constant extreme pushes reach the bounds within rounding."""
    model = Cart()
    assert missing_extras(model, cells=True) == []
    report = check_enclosure(model, model.control_period, pieces=4, checks=model.substeps,
                             settings=EnclosureCheck(samples=512))
    # per check instant: the tube, the end and four pieces, each from the start boxes and from the points
    assert report["claims"] == model.substeps * 6 * 2
    assert -1e-9 < report["tightest"] <= 0


# ------------------------------------------------------------------------------------------ the derived methods
def test_the_four_methods_are_the_kernel_over_the_period_and_its_pieces():
    model = Cart()
    rng = np.random.default_rng(3)
    x = rng.uniform(-2.0, 2.0, (50, 2))
    x_hi = x + rng.uniform(0.0, 0.1, (50, 2))
    a = rng.uniform(-2.0, 2.0, (50, 1))
    dt = model.control_period
    tube_lo, tube_hi, end_lo, end_hi = model.held_enclosure_box(0.0, x, x_hi, a, dt)
    for got, want in zip((tube_lo, tube_hi, end_lo, end_hi),
                         held_boxes(model, x, x_hi, a, 0.0, dt) + held_boxes(model, x, x_hi, a, dt, dt)):
        np.testing.assert_array_equal(got, want)
    point = model.held_enclosure(0.0, x, a, dt)
    for got, want in zip(point, model.held_enclosure_box(0.0, x, x, a, dt)):
        np.testing.assert_array_equal(got, want)
    p_lo, p_hi = model.held_tube_pieces_box(0.0, x, x_hi, a[:, 0], dt, 4)  # one control: (N,) is accepted
    assert p_lo.shape == (4, 50, 2)
    edges = np.linspace(0.0, dt, 5)
    for j in range(4):
        lo, hi = held_boxes(model, x, x_hi, a, edges[j], edges[j + 1])
        np.testing.assert_array_equal(p_lo[j], lo)
        np.testing.assert_array_equal(p_hi[j], hi)
    # the pieces lie in the tube and together reach its ends
    assert (p_lo >= tube_lo).all() and (p_hi <= tube_hi).all()
    np.testing.assert_array_equal(p_lo.min(axis=0), tube_lo)
    np.testing.assert_array_equal(p_hi.max(axis=0), tube_hi)
    pieces = model.held_tube_pieces(0.0, x, a, dt, 4)
    for got, want in zip(pieces, model.held_tube_pieces_box(0.0, x, x, a, dt, 4)):
        np.testing.assert_array_equal(got, want)


def test_the_derived_methods_refuse_bad_arguments_naming_them():
    model = Cart()
    x, a = np.zeros((2, 2)), np.zeros((2, 1))
    with pytest.raises(ValueError, match=r"cart: start box 1 has an upper corner below its lower one: \[0.0, 0.0\]"):
        model.held_enclosure_box(0.0, x, np.array([[0.0, 0.0], [0.1, -0.1]]), a, 0.05)
    with pytest.raises(ValueError, match=r"cart: dt must be a finite positive period \[s\], got 0.0"):
        model.held_enclosure(0.0, x, a, 0.0)
    with pytest.raises(ValueError, match=r"cart: states must have shape \(N, 2\) \(p, v\), got \(2,\)"):
        model.held_enclosure(0.0, x[0], a, 0.05)
    with pytest.raises(ValueError, match=r"cart: controls must have shape \(2, 1\), one row per state, got \(3, 1\)"):
        model.held_tube_pieces(0.0, x, np.zeros((3, 1)), 0.05, 2)


@nb.njit(cache=False)
def _no_box_below_zero(params, x_lo, x_hi, a, s0, s1, lo, hi):
    """A bound that finds no box for starts with ``p < 0`` (NaN), and the start box elsewhere."""
    for i in range(2):
        lo[i], hi[i] = (np.nan, np.nan) if x_lo[0] < 0 else (x_lo[i], x_hi[i])


def test_a_row_without_a_box_is_nan_from_boxes_and_refused_from_points():
    """NaN is the kernel's "no box": the box methods pass it on (the filter reads it as not admissible), the point
    method refuses it with the row, the state and the action, which the look-ahead catches row by row."""
    model = Cart()
    model.held_box_kernel = _no_box_below_zero
    x, a = np.array([[0.5, 0.0], [-0.5, 1.0]]), np.array([[1.0], [-2.0]])
    tube_lo = model.held_enclosure_box(0.0, x, x, a, 0.05)[0]
    assert np.isfinite(tube_lo[0]).all() and np.isnan(tube_lo[1]).all()
    with pytest.raises(ValueError, match=r"cart: no enclosure for row 1: state \(p, v\) = \(-0.5, 1.0\), action "
                                         r"\(-2.0\), dt = 0.05 s \(1 rows failed\)"):
        model.held_enclosure(0.0, x, a, 0.05)


# ------------------------------------------------------------------------------------------ models without a kernel
class NoBound(CartMotion, Model, ControlAndDisturbanceAffine):
    """The cart's motion and sets with no motion bound."""

    control_bounds = ((-2.0,), (2.0,))
    disturbance_bounds = ((-0.5,), (0.5,))


class OwnPoints(NoBound):
    """A bound from points only, written by hand as a method: the filter reads the compiled kernel, not this."""

    def held_enclosure(self, t, x, a, dt):
        lo = np.stack([x[:, 0] - 2.5 * dt - 2.5 * dt * dt, x[:, 1] - 2.5 * dt], 1)
        hi = np.stack([x[:, 0] + 2.5 * dt + 2.5 * dt * dt, x[:, 1] + 2.5 * dt], 1)
        return lo, hi, lo, hi


def test_what_a_model_gives_is_what_is_derived_and_reported():
    assert missing_extras(Cart(), cells=True) == []
    for model in (NoBound(), OwnPoints()):
        # no motion bound, and no sets' box maxima either
        assert [m.split("(")[0].strip() for m in missing_extras(model, cells=False)] == ["held_box_kernel", "set_boxes"]
        with pytest.raises(NotImplementedError, match="cart gives no held_box_kernel, from which held_tube_pieces_box"):
            model.held_tube_pieces(0.0, np.zeros((1, 2)), np.zeros((1, 1)), 0.05, 3)
    with pytest.raises(NotImplementedError, match="cart gives no held_box_kernel, from which held_enclosure_box"):
        NoBound().held_enclosure(0.0, np.zeros((1, 2)), np.zeros((1, 1)), 0.05)
