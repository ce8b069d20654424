"""The model's held-period enclosure compared with simulated runs before a proof is built
(:mod:`softreach.reach.proof.enclosure_check`): the built-in models pass, wrong enclosures are refuted with the run that
leaves them (reproduced here by an independent integrator), and a model without the filter's extras is refused
before any solve."""

from __future__ import annotations

import types

import numba as nb
import numpy as np
import pytest
from scipy.integrate import solve_ivp

from cart_motion import CartMotion

from softreach.reach import Model, SolveConfig, SolverSettings
from softreach.reach.numerics import compute
from softreach.reach.proof import cell_certificate, cell_game
from softreach.reach.proof.cell_certificate import CellCertificate
from softreach.reach.dynamics import ControlAndDisturbanceAffine
from softreach.reach.proof.enclosure_check import (EnclosureCheck, EnclosureError, check_enclosure,
                                             check_model_for_filter, missing_extras)
from softreach.reach.models import get_model
from softreach.reach.models.pointmass import PointMass

FEW = EnclosureCheck(samples=512)


def _check(model, settings=EnclosureCheck()):
    return check_enclosure(model, model.control_period, pieces=4, checks=model.substeps, settings=settings)


# ------------------------------------------------------------------------------------------ the built-in models
@pytest.mark.parametrize("name", ["pointmass", "dubins", "glider"])
def test_the_built_in_enclosures_hold_every_simulated_run(name):
    model = get_model(name)
    report = _check(model)
    assert report["runs"] == 2048 and report["tightest"] <= 0
    # every claim of the filter's: the kernel's tube, end and four pieces from boxes and from points, over the period
    # and each landing check
    assert report["claims"] == model.substeps * 6 * 2


def test_the_runs_reach_the_bounds_of_an_exact_enclosure():
    """The point mass's boxes are reached by constant extreme winds (its docstring): the runs come within rounding
    of them, so a box a little smaller would be refuted (next tests)."""
    assert _check(PointMass())["tightest"] > -1e-9


def test_the_check_is_deterministic():
    a, b = _check(get_model("dubins"), FEW), _check(get_model("dubins"), FEW)
    assert a["tightest"] == b["tightest"] and a["claims"] == b["claims"]


def test_settings_are_checked():
    with pytest.raises(ValueError, match="samples must be a positive integer, got 0"):
        EnclosureCheck(samples=0)
    with pytest.raises(ValueError, match="face_share must lie in"):
        EnclosureCheck(face_share=1.5)


# ------------------------------------------------------------------------------------------ wrong enclosures
class WindShrunk(PointMass):
    """The point mass whose enclosure assumes a wind bound ``fraction`` smaller than the wind's: its numpy boxes
    and its kernel both read ``held_box_params``, so all are wrong by that much."""

    def __init__(self, fraction: float):
        super().__init__()
        self.held_box_params = np.array([self.params.gravity, self.params.d_max * (1.0 - fraction)])


@nb.njit(cache=False)
def _ends_only_kernel(params, x_lo, x_hi, a, s0, s1, lo, hi):
    """The point mass's box at the instants ``s0`` and ``s1`` only: it misses the altitude's turning point inside
    ``[s0, s1]`` where the speed changes sign."""
    acc_lo, acc_hi = a[0] - params[0] - params[1], a[0] - params[0] + params[1]
    lo[0] = min(x_lo[0] + acc_lo * s0, x_lo[0] + acc_lo * s1)
    hi[0] = max(x_hi[0] + acc_hi * s0, x_hi[0] + acc_hi * s1)
    lo[1] = min(x_lo[1] + x_lo[0] * s0 + 0.5 * acc_lo * s0 * s0, x_lo[1] + x_lo[0] * s1 + 0.5 * acc_lo * s1 * s1)
    hi[1] = max(x_hi[1] + x_hi[0] * s0 + 0.5 * acc_hi * s0 * s0, x_hi[1] + x_hi[0] * s1 + 0.5 * acc_hi * s1 * s1)


class EndsOnly(PointMass):
    def __init__(self):
        super().__init__()
        self.held_box_kernel = _ends_only_kernel


def _simulated(model, run) -> float:
    """The refuted coordinate at the refuted instant, by scipy's DOP853 at tight tolerances, the wind piece by
    piece (not the check's RK4)."""
    x = np.asarray(run["start"], dtype=np.float64)
    a, t = np.asarray(run["action"])[None, :], 0.0
    for w, until in zip(run["wind"], run["until"]):
        end = min(until, run["s"])
        if end > t:
            def rhs(_, y, w=w):
                out = model.f(0.0, [np.array([v]) for v in y], [a[:, 0]], [np.array([v]) for v in w])
                return [float(np.ravel(o)[0]) for o in out]

            x = solve_ivp(rhs, (t, end), x, method="DOP853", rtol=1e-13, atol=1e-15).y[:, -1]
            t = end
    return float(x[run["axis"]])


@pytest.mark.parametrize("fraction", [0.01, 1e-6])
def test_an_enclosure_that_underestimates_the_wind_is_refuted_with_the_run(fraction):
    """A wind bound 1 % or one millionth too small: the run that leaves the box is named, and an independent
    integrator confirms that it leaves it, while the true box (the point mass's own) holds it."""
    wrong = WindShrunk(fraction)
    with pytest.raises(EnclosureError) as err:
        _check(wrong)
    msg, run = str(err.value), err.value.run
    assert "state (v, y) = (" in msg or "start box (" in msg
    assert "action (" in msg and "wind [m/s^2] (" in msg and " s: at s = " in msg
    assert f"simulated {('v', 'y')[run['axis']]} = " in msg and "docs/models.md" in msg
    value = _simulated(wrong, run)
    assert value == pytest.approx(run["value"], rel=1e-12, abs=1e-12)
    outside = value - run["side"] if value > run["side"] else run["side"] - value
    assert outside > 1e-12  # beyond both integrators' errors
    true = PointMass()
    lo, hi = true.held_tube_pieces_box(0.0, run["box_lo"][None], run["box_hi"][None], run["action"][None],
                                       run["period"], 1)
    assert lo[0, 0, run["axis"]] - 1e-12 <= value <= hi[0, 0, run["axis"]] + 1e-12


def test_an_enclosure_that_ignores_the_wind_is_refuted():
    with pytest.raises(EnclosureError, match=r"wind \[m/s\^2\] \((-10|10)\)"):
        _check(WindShrunk(1.0), FEW)


def test_a_tube_that_misses_the_motion_between_its_instants_is_refuted():
    """Boxes right at every instant ``s0``, ``s1`` they are asked for, wrong between them: only runs checked inside
    the pieces find it."""
    with pytest.raises(EnclosureError, match=r"simulated y = .* is (above|below)") as err:
        _check(EndsOnly())
    assert err.value.run["s"] not in (0.0, err.value.run["period"])


# ------------------------------------------------------------------------------------------ before any long work
class Cart(CartMotion, Model, ControlAndDisturbanceAffine):
    """The cart of docs/models.md: no enclosure."""

    default_shape = (31, 31)
    control_period = 0.05
    substeps = 2
    control_bounds = ((-2.0,), (2.0,))
    disturbance_bounds = ((-0.5,), (0.5,))


def _no_solve(*args, **kwargs):
    raise AssertionError("a solve started before the model was refused")


def test_a_model_without_the_extras_is_refused_before_the_held_solve(tmp_path, monkeypatch):
    monkeypatch.setattr(compute, "solve_held", _no_solve)
    monkeypatch.setattr(compute, "solve", _no_solve)
    cfg = SolveConfig(shape=(11, 11), budget_points=8, control_period=0.05,
                      settings=SolverSettings.from_accuracy("low", compile=False))
    with pytest.raises(EnclosureError) as err:
        compute.solve_table(Cart(), cfg, tmp_path / "cart.srt", progress=False)
    msg = str(err.value)
    assert "held_box_kernel(params, x_lo, x_hi, a, s0, s1, lo, hi) with held_box_params" in msg
    assert "softreach solve --held" in msg and "docs/models.md" in msg
    assert not list(tmp_path.iterdir())  # not even a partial table


def test_the_cells_ask_for_a_hard_box():
    no_box = PointMass()
    no_box.hard_box = None
    assert missing_extras(PointMass(), cells=True) == [] and missing_extras(no_box, cells=False) == []
    assert [m.split(" =")[0] for m in missing_extras(no_box, cells=True)] == ["hard_box"]


def _lookahead(model, monkeypatch):
    """What :meth:`CellCertificate.build` reads of a look-ahead before it solves (the key's parts from elsewhere in
    the look-ahead replaced by the few the build reads)."""
    monkeypatch.setattr(cell_certificate, "cell_key", lambda la, shape, dz=None, holds=(1,), span_cap=32:
                        {"shape": list(shape), "holds": sorted(holds),
                         "dz": cell_certificate.default_dz(la.dt, la.horizon)})
    return types.SimpleNamespace(model=model, dt=model.control_period, horizon=model.horizon, pieces=4,
                                 target_checks=model.substeps)


def test_a_wrong_enclosure_is_refused_before_the_cells_are_solved(monkeypatch):
    monkeypatch.setattr(cell_game, "solve", _no_solve)
    with pytest.raises(EnclosureError, match="held enclosure does not hold its own motion"):
        CellCertificate.build(_lookahead(WindShrunk(0.01), monkeypatch), (30, 40), holds=(1, 2))
    with pytest.raises(EnclosureError, match="lacks what the safety filter needs for building the filter's cells"):
        CellCertificate.build(_lookahead(Cart(), monkeypatch), (30, 40))


def test_a_right_enclosure_goes_on_to_the_cells_and_is_checked_once(monkeypatch):
    calls = []
    monkeypatch.setattr(cell_game, "solve", lambda cls, la, key: calls.append(key["shape"]) or "solved")
    checks = []
    real = cell_certificate.check_model_for_filter.__globals__["check_enclosure"]
    monkeypatch.setitem(cell_certificate.check_model_for_filter.__globals__, "check_enclosure",
                        lambda *a, **k: checks.append(1) or real(*a, **k))
    model = PointMass(d_max=9.0)  # parameters no other test checks
    assert CellCertificate.build(_lookahead(model, monkeypatch), (30, 40)) == "solved"
    assert CellCertificate.build(_lookahead(model, monkeypatch), (30, 40), holds=(1, 2)) == "solved"
    assert calls == [[30, 40], [30, 40]] and checks == [1]
    check_model_for_filter(model, 0.01, "a job", checks=model.substeps, cells=True,
                           cell_width=np.array([30.0 / 30, 18.0 / 40]))
    assert checks == [1]


def test_a_model_without_set_maxima_is_refused_before_the_held_solve(tmp_path, monkeypatch):
    from cart_motion import doc_cart

    class NoSetMaxima(doc_cart().Cart):
        """The cart of docs/models.md with its motion bound, without its sets' box maxima."""

        set_boxes = None

    monkeypatch.setattr(compute, "solve_held", _no_solve)
    monkeypatch.setattr(compute, "solve", _no_solve)
    cfg = SolveConfig(shape=(11, 11), budget_points=8, control_period=0.05,
                      settings=SolverSettings.from_accuracy("low", compile=False))
    with pytest.raises(ValueError, match=r"add to the class: set_boxes \(box-distance sets\), or a set_max_kernel"):
        compute.solve_table(NoSetMaxima(), cfg, tmp_path / "cart.srt", progress=False)
    assert not list(tmp_path.iterdir())
