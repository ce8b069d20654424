"""Glider.held_enclosure: validated boxes for one control period with the angle of attack held.

The boxes are checked against fine RK4 trajectories of the true dynamics under extreme wind signals (constant,
random switching, bang-bang); a box that is too small fails the containment tests, a uselessly wide one the
tightness tests.
"""

from __future__ import annotations

import math

import numpy as np
import pytest

from softreach.reach.models.glider import Glider

DEG = math.pi / 180.0
SUBSTEPS = 200
REL_TOL = 1e-9


@pytest.fixture(scope="module")
def model() -> Glider:
    return Glider()


def random_inputs(model: Glider, rng: np.random.Generator, n: int) -> tuple[np.ndarray, np.ndarray]:
    """States in the hard-constraint box of the default domain and angles of attack in the control box."""
    x = np.stack([rng.uniform(0.0, 40.0, n), rng.uniform(61.0, 83.0, n), rng.uniform(-3 * DEG, 0.0, n)], axis=1)
    (a_lo,), (a_hi,) = model.control_bounds
    a = rng.uniform(a_lo, a_hi, (n, 1))
    a[:3, 0] = (a_lo, a_hi, a_hi)  # the ends of the control box too
    return x, a


def rk4_path(model: Glider, x0: np.ndarray, a: np.ndarray, winds: np.ndarray, dt: float) -> np.ndarray:
    """States at every substep, shape (SUBSTEPS + 1, N, 3), of x' = f(x, a, wind) with the wind of substep k
    ``winds[:, k]`` held over that substep (so RK4 never steps across a switch)."""
    h = dt / SUBSTEPS

    def f(x: np.ndarray, w: np.ndarray) -> np.ndarray:
        return np.stack(model.f(0.0, [x[:, 0], x[:, 1], x[:, 2]], [a[:, 0]], [w]), axis=1)

    path = [x0]
    x = x0
    for k in range(SUBSTEPS):
        w = winds[:, k]
        k1 = f(x, w)
        k2 = f(x + 0.5 * h * k1, w)
        k3 = f(x + 0.5 * h * k2, w)
        k4 = f(x + h * k3, w)
        x = x + (h / 6.0) * (k1 + 2 * k2 + 2 * k3 + k4)
        path.append(x)
    return np.stack(path)


def wind_signals(model: Glider, rng: np.random.Generator, n: int) -> dict[str, np.ndarray]:
    """Per-row wind per substep, (N, SUBSTEPS), each at +-wind_max."""
    w = model.params.wind_max
    ones = np.ones((n, SUBSTEPS))
    k = np.arange(SUBSTEPS)
    # 10 random switch instants per row (on the substep grid), starting sign random
    switches = np.sort(rng.integers(1, SUBSTEPS, (n, 10)), axis=1)
    parity = (k[None, None, :] >= switches[:, :, None]).sum(axis=1) % 2
    start = rng.choice([-1.0, 1.0], (n, 1))
    return {
        "const+": w * ones,
        "const-": -w * ones,
        "switching": w * start * np.where(parity == 0, 1.0, -1.0),
        "bang+-": w * np.where(k < SUBSTEPS // 2, 1.0, -1.0)[None, :] * ones,
        "bang-+": w * np.where(k < SUBSTEPS // 2, -1.0, 1.0)[None, :] * ones,
    }


def assert_inside(value: np.ndarray, lo: np.ndarray, hi: np.ndarray, what: str) -> None:
    lo, hi = np.broadcast_to(lo, value.shape), np.broadcast_to(hi, value.shape)
    tol_lo = REL_TOL * np.maximum(np.abs(lo), 1.0)
    tol_hi = REL_TOL * np.maximum(np.abs(hi), 1.0)
    below = value < lo - tol_lo
    above = value > hi + tol_hi
    if np.any(below | above):
        idx = np.argwhere(below | above)[0]
        raise AssertionError(f"{what}: value {value[tuple(idx)]!r} outside [{lo[tuple(idx)]!r}, "
                             f"{hi[tuple(idx)]!r}] at index {tuple(idx)}")


@pytest.mark.parametrize("dt", [0.1, 0.01])
def test_trajectories_stay_in_the_boxes(model: Glider, dt: float):
    rng = np.random.default_rng(20240611 + int(dt * 1000))
    n = 200
    x, a = random_inputs(model, rng, n)
    tube_lo, tube_hi, end_lo, end_hi = model.held_enclosure(0.0, x, a, dt)
    for arr in (tube_lo, tube_hi, end_lo, end_hi):
        assert arr.shape == (n, 3) and arr.dtype == np.float64 and np.all(np.isfinite(arr))
    assert np.all(tube_lo <= end_lo) and np.all(end_lo <= end_hi) and np.all(end_hi <= tube_hi)
    assert np.all(tube_lo <= x) and np.all(x <= tube_hi)
    for name, winds in wind_signals(model, rng, n).items():
        path = rk4_path(model, x, a, winds, dt)
        assert_inside(path, tube_lo[None], tube_hi[None], f"tube, wind {name}, dt {dt}")
        assert_inside(path[-1], end_lo, end_hi, f"end, wind {name}, dt {dt}")


@pytest.mark.parametrize("dt", [0.1, 0.01])
def test_tube_pieces_hold_their_part_of_every_trajectory(model: Glider, dt: float):
    """Each of the 4 pieces' boxes (what the filter charges the budget by) holds the states of its quarter of the
    period under every wind signal, lies in the whole tube, and is typically a fraction of it in altitude."""
    rng = np.random.default_rng(99 + int(dt * 1000))
    n, pieces = 200, 4
    x, a = random_inputs(model, rng, n)
    lo, hi = model.held_tube_pieces(0.0, x, a, dt, pieces)
    assert lo.shape == hi.shape == (pieces, n, 3) and np.all(np.isfinite(lo)) and np.all(lo <= hi)
    tube_lo, tube_hi, _, _ = model.held_enclosure(0.0, x, a, dt)
    assert np.all(lo >= tube_lo) and np.all(hi <= tube_hi)
    per = SUBSTEPS // pieces
    for name, winds in wind_signals(model, rng, n).items():
        path = rk4_path(model, x, a, winds, dt)
        for j in range(pieces):
            assert_inside(path[j * per:(j + 1) * per + 1], lo[j][None], hi[j][None], f"piece {j}, wind {name}")
    share = (hi - lo)[..., 0] / (tube_hi - tube_lo)[None, :, 0]
    assert np.median(share) < 0.5


def test_box_starts_hold_every_start_and_contain_the_point_boxes(model: Glider):
    rng = np.random.default_rng(7)
    n, dt = 200, 0.1
    centre, a = random_inputs(model, rng, n)
    half = np.array([0.3, 0.2, 0.05 * DEG]) * rng.uniform(0, 1, (n, 3))
    lo, hi = centre - half, centre + half
    tube_lo, tube_hi, end_lo, end_hi = model.held_enclosure_box(0.0, lo, hi, a, dt)
    assert np.all(np.isfinite(tube_lo)) and np.all(tube_lo <= lo) and np.all(hi <= tube_hi)
    # starts anywhere in the box (corners included), any of the extreme wind signals
    for corner in range(4):
        x0 = lo + rng.uniform(0, 1, (n, 3)) * (hi - lo) if corner else lo.copy()
        if corner == 3:
            x0 = hi.copy()
        for name, winds in wind_signals(model, rng, n).items():
            path = rk4_path(model, x0, a, winds, dt)
            assert_inside(path, tube_lo[None], tube_hi[None], f"box tube, wind {name}")
            assert_inside(path[-1], end_lo, end_hi, f"box end, wind {name}")
    # a point start is a degenerate box: the same boxes as held_enclosure, bit for bit
    point = model.held_enclosure(0.0, centre, a, dt)
    degenerate = model.held_enclosure_box(0.0, centre, centre, a, dt)
    for p_, d_ in zip(point, degenerate):
        assert np.array_equal(p_, d_)
    # a box far too wide for one period has no enclosure: NaN, not an exception
    wide = model.held_enclosure_box(0.0, centre[:2] - [0, 20, 0], centre[:2], a[:2], 30.0)
    assert np.isnan(wide[0]).all()
    # a reversed box is refused, naming it
    with pytest.raises(ValueError, match="start box 1 has an upper corner below"):
        model.held_enclosure_box(0.0, lo[:2], np.array([hi[0], lo[1] - [0.1, 0, 0]]), a[:2], dt)


@pytest.mark.parametrize("dt", [0.1, 0.01])
def test_boxes_are_tight(model: Glider, dt: float):
    rng = np.random.default_rng(7 + int(dt * 1000))
    n = 50
    x, a = random_inputs(model, rng, n)
    tube_lo, tube_hi, end_lo, end_hi = model.held_enclosure(0.0, x, a, dt)
    winds = wind_signals(model, rng, n)
    v_plus = rk4_path(model, x, a, winds["const+"], dt)[-1, :, 1]
    v_minus = rk4_path(model, x, a, winds["const-"], dt)[-1, :, 1]
    spread = v_plus - v_minus
    assert np.all(spread > 0)
    assert np.all(end_hi[:, 1] - end_lo[:, 1] <= 3.0 * spread)
    # h' = V sin(gamma) is at most 83 sin(3 deg) = 4.3 m/s in magnitude: the h tube is about |h'| dt wide
    assert np.all(tube_hi[:, 0] - tube_lo[:, 0] <= 1.2 * 4.35 * dt)
    if dt == 0.1:
        assert np.all(tube_hi[:, 0] - tube_lo[:, 0] < 1.0)


def test_reference_state_widths(model: Glider):
    """(20 m, 72 m/s, -2 deg), alpha = 5 deg, dt = 0.1: the widths the report quotes, within a factor 2."""
    x = np.array([[20.0, 72.0, -2 * DEG]])
    a = np.array([[5 * DEG]])
    tube_lo, tube_hi, end_lo, end_hi = model.held_enclosure(0.0, x, a, 0.1)
    tube_w, end_w = (tube_hi - tube_lo)[0], (end_hi - end_lo)[0]
    # sink 72 sin(2 deg) = 2.51 m/s; wind alone spreads V by 2 * 10000 / 60000 * 0.1 = 0.0333 m/s
    assert 0.25 <= tube_w[0] <= 0.26
    assert 0.0333 <= end_w[1] <= 0.05
    assert end_w[0] < 0.01 and end_w[2] < 1e-4 and tube_w[2] < 1e-3


def _trim_alpha(model: Glider, v: float, gamma: float) -> float:
    """The angle of attack at which the airspeed holds still in calm air (bisection: drag grows with alpha)."""
    (a_lo,), (a_hi,) = model.control_bounds
    for _ in range(60):
        mid = 0.5 * (a_lo + a_hi)
        dv = model.f(0.0, [np.array([20.0]), np.array([v]), np.array([gamma])], [np.array([mid])], [np.zeros(1)])[1]
        a_lo, a_hi = (mid, a_hi) if float(dv[0]) > 0 else (a_lo, mid)
    return 0.5 * (a_lo + a_hi)


@pytest.mark.parametrize("dt", [0.1, 0.01])
def test_a_rate_of_one_sign_keeps_the_start_exactly(model: Glider, dt: float):
    """Step 5 of the kernel: along an axis whose rate has one sign over the whole tube, the box keeps the start's
    end exactly instead of rounding past it. At the soft airspeed limit, decelerating at full alpha, the tube
    tops out at 78 m/s itself, so a budget of 0 is not charged; pitching down at gamma = 0 it stays at gamma <= 0,
    inside C1. Where the wind can push the airspeed either way (trim), both ends move off the start."""
    (a_lo,), (a_hi,) = model.control_bounds
    # (the glider can hold its airspeed in calm air only slow and steep: elsewhere drag wins at every alpha)
    trim = _trim_alpha(model, 62.0, -3 * DEG)
    assert a_lo < trim < a_hi
    x = np.array([[20.0, 78.0, -1 * DEG], [20.0, 66.0, 0.0], [20.0, 62.0, -3 * DEG]])
    a = np.array([[a_hi], [a_lo], [trim]])
    tube_lo, tube_hi, end_lo, end_hi = model.held_enclosure(0.0, x, a, dt)
    assert tube_hi[0, 1] == 78.0 and tube_hi[0, 0] == 20.0  # decelerating, and descending
    assert tube_lo[0, 2] == x[0, 2]  # full lift pitches up
    assert tube_hi[1, 2] == 0.0  # no lift to speak of: pitches down from level flight
    assert tube_lo[2, 1] < 62.0 < tube_hi[2, 1]
    # the paths bear the claims out, with no tolerance: each rate's sign holds at every substep
    trim_end = {}
    for name, winds in wind_signals(model, np.random.default_rng(3), 3).items():
        path = rk4_path(model, x, a, winds, dt)
        assert path[:, 0, 1].max() <= 78.0 and path[:, 0, 0].max() <= 20.0, name
        assert path[:, 0, 2].min() >= x[0, 2] and path[:, 1, 2].max() <= 0.0, name
        assert_inside(path, tube_lo[None], tube_hi[None], f"tube, wind {name}")
        trim_end[name] = path[-1, 2, 1]
    assert trim_end["const+"] > 62.0 > trim_end["const-"]


def test_a_large_batch_in_threads_is_the_batch_row_by_row(model: Glider, monkeypatch):
    """A batch of more than :data:`~softreach.reach.proof.model_kernels.ENCLOSE_MIN_ROWS` rows per thread is enclosed in
    blocks, one a thread (``held_boxes``): every row's box is the one a single loop over the rows gives, bit for
    bit, and a row whose enclosure fails is NaN in both."""
    from softreach.reach.proof import model_kernels

    rng = np.random.default_rng(3)
    x, a = random_inputs(model, rng, 2 * model_kernels.ENCLOSE_MIN_ROWS + 7)
    hi = x + 0.01
    x[5, 1] = 2.0  # from 2 m/s up: the period's motion reaches V <= 0, no enclosure
    real, calls = model_kernels.held_box_rows, []
    monkeypatch.setattr(model_kernels, "held_box_rows", lambda *args: calls.append(len(args[2])) or real(*args))
    monkeypatch.setattr(model_kernels, "default_threads", lambda: 2)
    threaded = model.held_enclosure_box(0.0, x, hi, a, 0.1)
    assert sorted(calls[:2]) == [len(x) // 2, len(x) - len(x) // 2]
    monkeypatch.setattr(model_kernels, "default_threads", lambda: 1)
    calls.clear()
    single = model.held_enclosure_box(0.0, x, hi, a, 0.1)
    assert calls[0] == len(x)
    for got, expect in zip(threaded, single):
        np.testing.assert_array_equal(got, expect)
    assert np.isnan(single[0][5]).all() and np.isfinite(np.delete(single[0], 5, axis=0)).all()


def test_empty_batch(model: Glider):
    out = model.held_enclosure(0.0, np.empty((0, 3)), np.empty((0, 1)), 0.1)
    assert all(o.shape == (0, 3) for o in out)


@pytest.mark.parametrize("state", [(20.0, 0.0, -0.03), (20.0, -72.0, -0.03), (20.0, 72.0, 5.0),
                                   (20.0, 72.0, -5.0), (float("nan"), 72.0, -0.03)])
def test_bad_state_raises(model: Glider, state):
    x = np.array([[20.0, 72.0, -0.03], state])
    with pytest.raises(ValueError):
        model.held_enclosure(0.0, x, np.full((2, 1), 5 * DEG), 0.1)


def test_bad_arguments_raise(model: Glider):
    x = np.array([[20.0, 72.0, -0.03]])
    a = np.array([[5 * DEG]])
    with pytest.raises(ValueError):
        model.held_enclosure(0.0, x, a, 0.0)
    with pytest.raises(ValueError):
        model.held_enclosure(0.0, x, a, -0.1)
    with pytest.raises(ValueError):
        model.held_enclosure(0.0, x, np.array([[5.0]]), 0.1)  # degrees
    with pytest.raises(ValueError):
        model.held_enclosure(0.0, x[0], a, 0.1)  # not (N, 3)
    with pytest.raises(ValueError):
        model.held_enclosure(0.0, x, np.zeros((2, 1)), 0.1)  # one control per state


def test_too_long_period_raises_naming_the_row(model: Glider):
    """Over 1000 s no box passes the Picard test (V or gamma leave the model's domain): an error, not a box."""
    x = np.array([[20.0, 72.0, -0.03], [10.0, 65.0, -0.01]])
    with pytest.raises(ValueError, match="row 0"):
        model.held_enclosure(0.0, x, np.full((2, 1), 5 * DEG), 1000.0)


def _products(a0, a1, b0, b1):
    """The range of ``a b`` over ``[a0, a1] x [b0, b1]``: its extremes lie at the corners."""
    corners = np.stack([a0 * b0, a0 * b1, a1 * b0, a1 * b1])
    return corners.min(axis=0), corners.max(axis=0)


@pytest.mark.parametrize("dt", [0.1, 0.01])
def test_the_end_box_along_V_is_the_winds_spread_and_the_curvature_of_the_rest(model: Glider, dt: float):
    """``V' = A(V, gamma) + w / m``: from a point, ``V(dt)`` lies in ``V0 + dt A(x0) + dt [-w, w] / m + dt^2 / 2 A'``
    with ``A' = -2 D V V' / m - g cos(gamma) gamma'`` over the tube. The box is no wider than that range, evaluated
    here over the enclosure's own tube with plain interval products, beyond the kernel's outward rounding: each of
    the end's two sums widened by ``4 eps |V|`` on each side (``16 eps |V|``), at most as much for the roundings of
    the terms under them (each below ``|V|``), and the reference's own rounding to nearest (a few ``eps |V|``): under
    ``40 eps |V|``. A first-order box, ``dt F_V(tube)``, is wider by ``dt`` times the drag's change over the tube."""
    p = model.params
    rng = np.random.default_rng(11 + int(dt * 1000))
    n = 200
    x, a = random_inputs(model, rng, n)
    tube_lo, tube_hi, end_lo, end_hi = model.held_enclosure(0.0, x, a, dt)
    lift = p.cl0 + p.cl_alpha * a[:, 0]
    drag = p.cd0 + p.cd_k * lift * lift
    w = p.wind_max / p.mass
    V0, V1, g0, g1 = tube_lo[:, 1], tube_hi[:, 1], tube_lo[:, 2], tube_hi[:, 2]
    # on |gamma| < pi / 2 sin increases; cos peaks at 0
    cos_lo = np.minimum(np.cos(g0), np.cos(g1))
    cos_hi = np.where((g0 <= 0.0) & (g1 >= 0.0), 1.0, np.maximum(np.cos(g0), np.cos(g1)))
    v_rate = (-drag * V1 ** 2 / p.mass - p.gravity * np.sin(g1) - w,
              -drag * V0 ** 2 / p.mass - p.gravity * np.sin(g0) + w)
    g_rate = (p.half_rho_s * lift * V0 / p.mass - p.gravity * cos_hi / V0,
              p.half_rho_s * lift * V1 / p.mass - p.gravity * cos_lo / V1)
    e0, e1 = _products(V0, V1, *v_rate)
    f0, f1 = _products(p.gravity * cos_lo, p.gravity * cos_hi, *g_rate)
    curvature = (2.0 * drag * e1 / p.mass + f1) - (2.0 * drag * e0 / p.mass + f0)
    bound = dt * 2.0 * w + 0.5 * dt * dt * curvature
    allowance = 40.0 * np.finfo(np.float64).eps * V1
    width = end_hi[:, 1] - end_lo[:, 1]
    assert np.all(width <= bound + allowance), np.max(width - bound - allowance)
