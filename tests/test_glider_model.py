"""The fixed-wing glider model (paper §VI-B, spec §3): dynamics, exact Hamiltonian, inputs, bounds, sets, units."""

from __future__ import annotations

import math

import numpy as np
import pytest

from softreach.reach.models import get_model
from softreach.reach.models.glider import Glider, GliderParams, degrees_to_radians, radians_to_degrees

import torch

DEG = math.pi / 180.0
M, G, QS, CL0, CLA, CD0, CDK, WIND = 60000.0, 9.8, 68.6, 1.25, 4.2, 2.7, 3.08, 10000.0


@pytest.fixture(scope="module")
def model() -> Glider:
    return Glider()


def random_states(rng: np.random.Generator, n: int) -> list[np.ndarray]:
    """States over the default grid box."""
    return [rng.uniform(-5, 45, n), rng.uniform(58, 86, n), rng.uniform(-4 * DEG, 1 * DEG, n)]


def random_costates(rng: np.random.Generator, n: int) -> list[np.ndarray]:
    """Co-states covering both signs of p_V and p_gamma, and ratios p_gamma / |p_V| that put the vertex of the
    convex case inside the C_L interval (ratio about 8 to 14 at these speeds) as well as outside it."""
    p_h = rng.normal(size=n)
    p_V = rng.normal(size=n)
    ratio = rng.uniform(-30, 30, n)
    p_g = np.where(rng.random(n) < 0.5, ratio * np.abs(p_V), 60 * rng.normal(size=n))
    return [p_h, p_V, p_g]


def brute_force_hamiltonian(model: Glider, x, p, n_alpha: int = 20001) -> tuple[np.ndarray, np.ndarray]:
    """``min`` over a fine sampling of alpha of ``max`` over the wind's ends of ``p . f``; also the sampled argmin."""
    alphas = np.linspace(model.control_bounds[0][0], model.control_bounds[1][0], n_alpha)[None, :]
    X = [c[:, None] for c in x]
    P = [c[:, None] for c in p]
    best = None
    for wind in (-WIND, WIND):
        f = model.f(0.0, X, [alphas], [wind])
        val = sum(pi * fi for pi, fi in zip(P, f))
        best = val if best is None else np.maximum(best, val)
    return best.min(axis=1), alphas[0, best.argmin(axis=1)]


def hand_f(h, V, gamma, alpha, wind):
    """The spec's equations written out independently of the module."""
    cl = CL0 + CLA * alpha
    lift = QS * cl * V**2
    drag = (CD0 + CDK * cl**2) * V**2
    return np.array([V * math.sin(gamma), (-drag - M * G * math.sin(gamma) + wind) / M,
                     lift / (M * V) - G * math.cos(gamma) / V])


# ------------------------------------------------------------------------------------------------ dynamics
def test_f_array_matches_hand_computed_dynamics(model):
    x = np.array([20.0, 70.0, -2 * DEG])
    a, b = np.array([5 * DEG]), np.array([3000.0])
    got = model.f_array(0.0, x, a, b)
    want = hand_f(20.0, 70.0, -2 * DEG, 5 * DEG, 3000.0)
    np.testing.assert_allclose(got, want, rtol=1e-13, atol=1e-15)
    # worked by hand: C_L = 1.61652, D = 52667 N, V' = -0.87779 + 0.34202 + 0.05, gamma' = 0.12937 - 0.13992
    np.testing.assert_allclose(got, [-2.442965, -0.485775, -0.010539], atol=2e-6)


def test_defaults_are_the_papers(model):
    p = model.params
    assert (p.mass, p.gravity, p.half_rho_s) == (M, G, QS)
    assert math.isclose(1.225 * 112 / 2, p.half_rho_s)
    assert model.control_bounds == ((0.0,), (13 * DEG,))
    assert model.disturbance_bounds == ((-WIND,), (WIND,))
    assert model.horizon == 10.0
    assert model.state_units == ("m", "m/s", "rad")
    lo, hi = model.domain
    assert lo[0] < 0 and hi[0] > 40 and lo[1] < 61 and hi[1] > 83 and lo[2] < -3 * DEG and hi[2] > 0


def test_trimmed_glide_at_72_mps_is_within_the_alpha_range(model):
    """Computed from the coefficients: holding gamma = -3 deg at 72 m/s needs C_L = 1.651, alpha = 5.47 deg;
    at full alpha the path curves up (gamma' = +0.045 rad/s). At the 61 m/s stall speed no alpha holds it."""
    alpha_trim = model.trim_alpha(72.0, -3 * DEG)
    assert math.isclose(radians_to_degrees(alpha_trim), 5.47, abs_tol=0.01)
    assert 0 <= alpha_trim <= 13 * DEG
    x = [30.0, 72.0, -3 * DEG]
    assert abs(model.f(0.0, x, [alpha_trim], [0.0])[2]) < 1e-12
    assert math.isclose(model.f(0.0, x, [13 * DEG], [0.0])[2], 0.0454, abs_tol=1e-4)
    assert model.f(0.0, x, [0.0], [0.0])[2] < 0
    # without thrust the trimmed glide still loses speed, even with full tailwind (-0.446 + 0.167 m/s^2)
    assert model.f(0.0, x, [alpha_trim], [WIND])[1] < 0
    assert model.trim_alpha(61.0, -3 * DEG) > 13 * DEG
    assert model.f(0.0, [30.0, 61.0, -3 * DEG], [13 * DEG], [0.0])[2] < 0


# ------------------------------------------------------------------------------------------------ game
def test_hamiltonian_equals_brute_force_min_max(model):
    rng = np.random.default_rng(1)
    x, p = random_states(rng, 300), random_costates(rng, 300)
    h = model.hamiltonian(0.0, x, p)
    h_brute, _ = brute_force_hamiltonian(model, x, p)
    # the sampled minimum can only be above the exact one, and by no more than the sampling error
    assert np.all(h <= h_brute + 1e-12)
    np.testing.assert_allclose(h, h_brute, rtol=0, atol=1e-8)
    # the test covers all the cases: convex/concave q, vertex inside and outside the C_L interval
    a2 = -p[1] * CDK * x[1] ** 2 / M
    a1 = p[2] * QS * x[1] / M
    vertex = -a1 / (2 * a2)
    lo, hi = model._cl_bounds
    inside = (a2 > 0) & (vertex > lo) & (vertex < hi)
    assert inside.sum() >= 10 and (a2 < 0).sum() >= 50 and ((a2 > 0) & ~inside).sum() >= 50


def test_optimal_inputs_attain_the_hamiltonian(model):
    rng = np.random.default_rng(2)
    x, p = random_states(rng, 400), random_costates(rng, 400)
    (alpha,) = model.optimal_control(0.0, x, p)
    (wind,) = model.worst_disturbance(0.0, x, p)
    assert np.all(alpha >= 0) and np.all(alpha <= 13 * DEG + 1e-15)
    np.testing.assert_array_equal(wind, np.where(p[1] > 0, WIND, -WIND))
    value = sum(pi * fi for pi, fi in zip(p, model.f(0.0, x, [alpha], [wind])))
    np.testing.assert_allclose(value, model.hamiltonian(0.0, x, p), rtol=0, atol=1e-12)
    # alpha* agrees with the sampled argmin where the minimum is well separated
    _, alpha_brute = brute_force_hamiltonian(model, x, p)
    assert np.median(np.abs(alpha - alpha_brute)) < 1e-4


def test_ties(model):
    x = [np.array([10.0, 10.0]), np.array([70.0, 70.0]), np.array([-DEG, -DEG])]
    p = [np.array([1.0, 1.0]), np.array([0.0, 0.0]), np.array([0.0, 0.0])]
    (alpha,) = model.optimal_control(0.0, x, p)
    (wind,) = model.worst_disturbance(0.0, x, p)
    np.testing.assert_allclose(alpha, 6.5 * DEG)  # every angle is optimal: the midpoint
    np.testing.assert_array_equal(wind, [0.0, 0.0])
    np.testing.assert_allclose(model.hamiltonian(0.0, x, p), x[1] * np.sin(x[2]))


def test_dissipation_bounds_the_vector_field(model):
    rng = np.random.default_rng(3)
    n = 5000
    x = random_states(rng, n)
    a = [rng.uniform(0, 13 * DEG, n)]
    a[0][:50], a[0][50:100] = 0.0, 13 * DEG
    b = [rng.choice([-WIND, WIND], n) * rng.uniform(0.0, 1.0, n) ** 0.2]
    f = model.f(0.0, x, a, b)
    bound = model.dissipation(0.0, x, None, None)
    for fi, bi in zip(f, bound):
        assert np.all(np.abs(fi) <= bi + 1e-12)
    # the bound is the max over the boxes, attained at their corners: not loose
    corners = [model.f(0.0, x, [al], [w]) for al in (0.0, 13 * DEG) for w in (-WIND, WIND)]
    for i in range(3):
        np.testing.assert_allclose(bound[i], np.max([np.abs(c[i]) for c in corners], axis=0), rtol=1e-12)


def test_dissipation_with_a_costate_box(model):
    rng = np.random.default_rng(4)
    n = 2000
    x = random_states(rng, n)
    centre = random_costates(rng, n)
    width = [np.abs(rng.normal(size=n)) * 0.3 for _ in range(3)]
    p_lo = [c - w for c, w in zip(centre, width)]
    p_hi = [c + w for c, w in zip(centre, width)]
    local = model.dissipation(0.0, x, p_lo, p_hi)
    glob = model.dissipation(0.0, x, None, None)
    for li, gi in zip(local, glob):
        assert np.all(li <= gi + 1e-15)
    # drag makes V' mostly negative, so a tailwind-only box (p_V > 0 throughout) shrinks the largest |V'|
    tailwind = p_lo[1] > 0
    assert tailwind.sum() > 100 and np.all(local[1][tailwind] < glob[1][tailwind])
    np.testing.assert_array_equal(local[0], glob[0])
    np.testing.assert_array_equal(local[2], glob[2])
    # |dH/dp_i| = |f_i(alpha*, F*)| for co-states in the box stays below the local bound
    for _ in range(5):
        u = [lo + rng.random(n) * (hi - lo) for lo, hi in zip(p_lo, p_hi)]
        f = model.f(0.0, x, model.optimal_control(0.0, x, u), model.worst_disturbance(0.0, x, u))
        for fi, li in zip(f, local):
            assert np.all(np.abs(fi) <= li + 1e-12)
    # and so do finite differences of H along each co-state axis
    u = [lo + 0.5 * (hi - lo) for lo, hi in zip(p_lo, p_hi)]
    for i in range(3):
        step = 1e-6
        up = list(u)
        up[i] = u[i] + step
        slope = (model.hamiltonian(0.0, x, up) - model.hamiltonian(0.0, x, u)) / step
        assert np.all(np.abs(slope) <= local[i] + 1e-5)


def test_grid_broadcasting(model):
    rng = np.random.default_rng(5)
    h = np.linspace(-5, 45, 4).reshape(4, 1, 1)
    V = np.linspace(58, 86, 5).reshape(1, 5, 1)
    gamma = np.linspace(-4 * DEG, DEG, 6).reshape(1, 1, 6)
    p = [rng.normal(size=(4, 5, 6)) for _ in range(3)]
    x = [h, V, gamma]
    assert model.hamiltonian(0.0, x, p).shape == (4, 5, 6)
    assert model.optimal_control(0.0, x, p)[0].shape == (4, 5, 6)
    assert model.worst_disturbance(0.0, x, p)[0].shape == (4, 5, 6)
    for d in model.dissipation(0.0, x, None, None) + model.dissipation(0.0, x, p, p):
        assert np.broadcast_shapes(np.shape(d), (4, 5, 6)) == (4, 5, 6)
    for fn in (model.target, model.hard_constraint, model.soft_constraint):
        assert np.broadcast_shapes(np.shape(fn(0.0, x)), (4, 5, 6)) == (4, 5, 6)
    flat = [np.broadcast_to(c, (4, 5, 6)).ravel() for c in x]
    np.testing.assert_allclose(model.hamiltonian(0.0, x, p).ravel(),
                               model.hamiltonian(0.0, flat, [c.ravel() for c in p]), rtol=1e-14)


def test_torch_and_numpy_agree(model):
    rng = np.random.default_rng(6)
    x, p = random_states(rng, 500), random_costates(rng, 500)
    width = [np.abs(rng.normal(size=500)) * 0.3 for _ in range(3)]
    p_lo = [c - w for c, w in zip(p, width)]
    p_hi = [c + w for c, w in zip(p, width)]
    t = lambda cs: [torch.as_tensor(c, dtype=torch.float64) for c in cs]  # noqa: E731
    pairs = [
        (model.hamiltonian(0.0, x, p), model.hamiltonian(0.0, t(x), t(p))),
        (model.optimal_control(0.0, x, p)[0], model.optimal_control(0.0, t(x), t(p))[0]),
        (model.worst_disturbance(0.0, x, p)[0], model.worst_disturbance(0.0, t(x), t(p))[0]),
        (model.target(0.0, x), model.target(0.0, t(x))),
        (model.hard_constraint(0.0, x), model.hard_constraint(0.0, t(x))),
        (model.soft_constraint(0.0, x), model.soft_constraint(0.0, t(x))),
        (model.violation_rate(0.0, x, 1e-3), model.violation_rate(0.0, t(x), 1e-3)),
    ]
    pairs += list(zip(model.f(0.0, x, [np.full(500, 0.1)], [np.full(500, 5e3)]),
                      model.f(0.0, t(x), [torch.full((500,), 0.1, dtype=torch.float64)],
                              [torch.full((500,), 5e3, dtype=torch.float64)])))
    pairs += list(zip(model.dissipation(0.0, x, None, None), model.dissipation(0.0, t(x), None, None)))
    pairs += list(zip(model.dissipation(0.0, x, p_lo, p_hi), model.dissipation(0.0, t(x), t(p_lo), t(p_hi))))
    for ref, got in pairs:
        assert isinstance(got, torch.Tensor)
        np.testing.assert_allclose(got.numpy(), ref, rtol=1e-12, atol=1e-14)
    # float32 on a broadcast grid runs too
    grid = [torch.linspace(0, 40, 3).reshape(3, 1, 1), torch.linspace(60, 80, 4).reshape(1, 4, 1),
            torch.linspace(-0.05, 0, 5).reshape(1, 1, 5)]
    pg = [torch.randn(3, 4, 5) for _ in range(3)]
    assert model.hamiltonian(0.0, grid, pg).dtype == torch.float32
    assert model.optimal_control(0.0, grid, pg)[0].shape == (3, 4, 5)


# ------------------------------------------------------------------------------------------------ sets
def test_sets_signs_and_scaling(model):
    def at(fn, h, V, gamma_deg):
        return float(fn(0.0, [np.array(h), np.array(V), np.array(gamma_deg * DEG)]))

    # target: in the touchdown band with a gentle sink rate (72 sin 0.5 deg = 0.63 m/s)
    assert at(model.target, 0.2, 72, -0.5) < 0
    assert at(model.target, 0.0, 72, -0.5) < 0
    assert at(model.target, 0.2, 72, -1.0) > 0  # sink 1.26 m/s
    assert at(model.target, 2.0, 72, -0.5) > 0  # too high
    # 0.91 m/s at 72 m/s is gamma = -0.724 deg: the boundary of the sink-rate term
    assert abs(at(model.target, 0.0, 72, -math.degrees(math.asin(0.91 / 72)))) < 1e-12
    assert math.isclose(at(model.target, 0.0, 72, -0.5), 0.91 * (72 * math.sin(0.5 * DEG) / 0.91 - 1))
    assert math.isclose(at(model.target, 0.3, 72, 0.0), -0.2)  # the band decides: 0.2 m from its edge
    # hard constraint: scaled distances in m, m/s and degrees
    assert math.isclose(at(model.hard_constraint, 10, 72, -1.5), -1.5)  # 1.5 deg from both gamma edges
    assert math.isclose(at(model.hard_constraint, 10, 82, -1.5), -1.0)  # 1 m/s below 83
    # the ground bound is the bottom of the touchdown band, h >= -0.5 m (Glider docstring, "Touchdown")
    assert math.isclose(at(model.hard_constraint, 0.5, 72, -1.5), -1.0)  # 1 m above the bound
    assert math.isclose(at(model.hard_constraint, 0.0, 72, -1.5), -0.5)  # ground level: inside C1 and the band
    assert at(model.hard_constraint, 0.0, 72, -1.5) < 0 and at(model.target, 0.0, 72, -0.5) < 0
    assert math.isclose(at(model.hard_constraint, 10, 60, -1.5), 1.0)
    assert math.isclose(at(model.hard_constraint, 10, 72, -4.0), 1.0)
    assert math.isclose(at(model.hard_constraint, 10, 72, 0.5), 0.5)
    assert math.isclose(at(model.hard_constraint, -1, 72, -1.5), 0.5)
    assert math.isclose(at(model.hard_constraint, -0.5, 72, -1.5), 0.0)
    assert at(model.hard_constraint, 1000, 72, -1.5) < 0  # no ceiling
    # soft constraint: the speed margins only
    assert math.isclose(at(model.soft_constraint, 10, 72, -1.5), -6.0)
    assert math.isclose(at(model.soft_constraint, 10, 63, -1.5), 3.0)
    assert math.isclose(at(model.soft_constraint, 10, 80, -1.5), 2.0)
    assert math.isclose(at(model.soft_constraint, -10, 72, 5.0), -6.0)
    assert float(model.violation_rate(0.0, [np.array(10.0), np.array(80.0), np.array(-DEG)], 1e-3)) == 1.0
    assert float(model.violation_rate(0.0, [np.array(10.0), np.array(70.0), np.array(-DEG)], 1e-3)) == 0.0


# ------------------------------------------------------------------------------------------------ units
def test_degrees_are_refused(model):
    with pytest.raises(ValueError, match=r"radians expected.*-3.0.*looks like degrees"):
        model.validate_state([10.0, 72.0, -3.0])
    with pytest.raises(ValueError, match="looks like degrees"):
        model.validate_state(np.array([[10.0, 72.0, -0.01], [5.0, 70.0, -2.0]]))
    with pytest.raises(ValueError, match=r"radians expected.*5.0.*looks like degrees"):
        model.validate_control(5.0)
    with pytest.raises(ValueError, match="looks like degrees"):
        model.validate_control(torch.tensor([[0.1], [13.0]]))
    with pytest.raises(ValueError, match="looks like degrees"):
        model.f_array(0.0, np.array([10.0, 72.0, -0.01]), np.array([10.0]), np.array([0.0]))
    with pytest.raises(ValueError, match="looks like degrees"):
        GliderParams(alpha_bounds=(0.0, 13.0))
    with pytest.raises(ValueError, match="looks like degrees"):
        Glider(hard_gamma=(-3.0, 0.0))
    with pytest.raises(ValueError, match="positive"):
        model.validate_state([10.0, -72.0, -0.01])
    with pytest.raises(ValueError, match="finite"):
        model.validate_state([10.0, 72.0, float("nan")])
    # radians pass, and the conveniences convert
    model.validate_state(np.array([10.0, 72.0, degrees_to_radians(-3.0)]))
    model.validate_state([torch.tensor([10.0]), torch.tensor([72.0]), torch.tensor([-0.05])])
    model.validate_control(degrees_to_radians(13.0))
    assert math.isclose(degrees_to_radians(13.0), math.radians(13.0))
    assert math.isclose(radians_to_degrees(math.radians(13.0)), 13.0)
    assert torch.allclose(degrees_to_radians(torch.tensor([180.0], dtype=torch.float64)),
                          torch.tensor([math.pi], dtype=torch.float64))


@pytest.mark.parametrize("field,value", [("mass", float("nan")), ("gravity", float("inf")), ("cl_alpha", 0.0),
                                         ("soft_speed", (78.0, 66.0)), ("wind_max", -1.0), ("cd_k", -3.08),
                                         ("hard_speed", (-5.0, 83.0)), ("gamma_scale", 0.0),
                                         ("half_rho_s", float("nan"))])
def test_bad_parameters_are_refused(field, value):
    with pytest.raises(ValueError, match=field):
        GliderParams(**{field: value})


# ------------------------------------------------------------------------------------------------ registry
def test_get_model():
    m = get_model("glider")
    assert isinstance(m, Glider) and m.name == "glider"
    assert get_model("glider", horizon=5.0).horizon == 5.0
    meta = m.metadata()
    assert meta["name"] == "glider" and meta["state_names"] == ["h", "V", "gamma"]
    assert meta["parameters"]["alpha_bounds"] == [0.0, 13 * DEG]
    with pytest.raises(TypeError):
        Glider(GliderParams(), horizon=3.0)


def test_get_model_imports_the_module_lazily():
    """``get_model("glider")`` in a fresh interpreter, where nothing has imported the module yet."""
    import subprocess
    import sys

    code = ("import sys; from softreach.reach.models import get_model, MODELS; "
            "assert 'glider' not in MODELS; m = get_model('glider'); print(type(m).__name__, m.horizon)")
    out = subprocess.run([sys.executable, "-c", code], capture_output=True, text=True, timeout=120)
    assert out.returncode == 0, out.stderr
    assert out.stdout.split() == ["Glider", "10.0"]
