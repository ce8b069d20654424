"""Table files: round trip, integrity checks, resume after interruption, and the query API's contracts."""

from __future__ import annotations

import numpy as np
import pytest

from softreach.reach import SolveConfig, SolverSettings, TableError, get_model, load_table, solve_table
from softreach.reach.numerics.compute import validate
from softreach.reach.tables.table import MAGIC

MODEL = get_model("pointmass")
SETTINGS = SolverSettings.from_accuracy("low", dtype="float32", compile=False)


def _cfg(**kw):
    base = dict(shape=(21, 21), budget_points=23, snapshots=5, settings=SETTINGS)
    base.update(kw)
    return SolveConfig(**base)


def test_metadata_round_trip(pointmass_table):
    t = pointmass_table
    assert t.fields == ["V", "W_eps"]
    assert t.model_metadata["name"] == "pointmass" and t.eps == 1e-3
    assert t.header["softreach_version"] and t.header["complete"]
    assert t.grid("W_eps").shape[:2] == t.grid("V").shape
    assert t.budget_scale == MODEL.budget_scale
    assert t.model.metadata() == MODEL.metadata()
    assert t.values("W_eps").shape == (11,) + t.grid("W_eps").shape


def test_snapshots_are_the_solver_output(pointmass_table):
    # the terminal snapshot is max(c, l) exactly, the earliest one differs from it
    W = pointmass_table.values("W_eps")
    g = pointmass_table.grid("W_eps")
    x = g.coordinates()
    from softreach.reach import soft_problem

    sp = soft_problem(MODEL, pointmass_table.eps, pointmass_table.budget_scale)
    terminal = np.maximum(np.maximum(sp.constraint_function(1.0, x), sp.floor_function(1.0, x)), sp.target_function(1.0, x))
    np.testing.assert_allclose(W[-1], terminal + 0 * W[-1], atol=1e-5)
    assert np.abs(W[0] - W[-1]).max() > 1.0


@pytest.fixture
def small_table(tmp_path):
    path = tmp_path / "t.srt"
    solve_table(MODEL, _cfg(), path, progress=False)
    return path


def test_corrupted_data_is_refused(small_table):
    data = bytearray(small_table.read_bytes())
    data[-100] ^= 0xFF
    small_table.write_bytes(bytes(data))
    with pytest.raises(TableError, match="checksum mismatch in field"):
        load_table(small_table)


def test_truncated_file_is_refused(small_table):
    data = small_table.read_bytes()
    small_table.write_bytes(data[: len(data) - 4096])
    with pytest.raises(TableError, match="truncated"):
        load_table(small_table)


def test_not_a_table_and_bad_header_are_refused(small_table, tmp_path):
    other = tmp_path / "x.srt"
    other.write_bytes(b"hello world" * 10)
    with pytest.raises(TableError, match="bad magic"):
        load_table(other)
    data = bytearray(small_table.read_bytes())
    data[len(MAGIC) + 8] = ord("#")  # the opening brace of the JSON header
    small_table.write_bytes(bytes(data))
    with pytest.raises(TableError, match="header is corrupted"):
        load_table(small_table)


def _solve_killed_then_resumed(cfg, field, tmp_path, monkeypatch):
    """``(reference table, resumed table)``: ``cfg`` solved once unbroken, and once killed after ``V``'s 5 snapshots
    and 3 of ``field``, checked to be unloadable, then resumed by the same command."""
    ref = tmp_path / "ref.srt"
    solve_table(MODEL, cfg, ref, progress=False)
    out = tmp_path / "run.srt"
    from softreach.reach.tables import table as table_mod

    original = table_mod.TableWriter.write_snapshot
    calls = {"n": 0}

    def crash_after_three(self, name, k, value):
        calls["n"] += 1
        if name == field and calls["n"] > 8:
            raise KeyboardInterrupt("simulated kill")
        return original(self, name, k, value)

    monkeypatch.setattr(table_mod.TableWriter, "write_snapshot", crash_after_three)
    with pytest.raises(KeyboardInterrupt):
        solve_table(MODEL, cfg, out, progress=False)
    partial = out.with_name(out.name + ".partial")
    assert partial.exists() and not out.exists()
    with pytest.raises(TableError, match="incomplete"):
        load_table(partial)
    monkeypatch.setattr(table_mod.TableWriter, "write_snapshot", original)
    solve_table(MODEL, cfg, out, progress=False)
    return load_table(ref), load_table(out)


def test_interrupted_solve_resumes_to_the_same_table(tmp_path, monkeypatch):
    a, b = _solve_killed_then_resumed(_cfg(), "W_eps", tmp_path, monkeypatch)
    for f in ("V", "W_eps"):
        np.testing.assert_allclose(np.asarray(a.values(f)), np.asarray(b.values(f)), atol=1e-6)


def test_resume_with_other_settings_is_refused(tmp_path, monkeypatch):
    out = tmp_path / "run.srt"
    from softreach.reach.tables import table as table_mod

    def crash(self, field, k, value):
        raise KeyboardInterrupt

    original = table_mod.TableWriter.write_snapshot
    monkeypatch.setattr(table_mod.TableWriter, "write_snapshot", crash)
    with pytest.raises(KeyboardInterrupt):
        solve_table(MODEL, _cfg(), out, progress=False)
    monkeypatch.setattr(table_mod.TableWriter, "write_snapshot", original)
    with pytest.raises(TableError, match="other settings.*shape"):
        solve_table(MODEL, _cfg(shape=(25, 25)), out, progress=False)


def test_queries_outside_are_unsafe_never_nan(pointmass_table):
    t = pointmass_table
    x = np.array([[0.0, 5.0], [100.0, 5.0], [0.0, -50.0], [0.0, 5.0]])
    v = t.value(0.0, x, np.array([0.3, 0.3, 0.3, -0.5]))
    assert np.isfinite(v[0]) and np.isposinf(v[1:]).all()
    assert np.isposinf(t.value(2.0, x[:1], 0.3)).all()  # after the horizon
    assert np.isfinite(t.value(0.0, x[:1], 5.0)).all()  # more budget than the horizon: as much as the horizon
    np.testing.assert_allclose(t.value(0.0, x[:1], 5.0), t.value(0.0, x[:1], 1.0))
    # a gradient off the table is an error that names the query, or, asked for, the nearest grid point's
    with pytest.raises(ValueError, match=r"point \[100.0, 5.0, 0.3\] lies outside table"):
        t.gradient(0.0, x, np.full(4, 0.3))
    with pytest.raises(ValueError, match="outside table"):
        t.optimal_control(0.0, x[2:3], [0.3])
    near = t.gradient(0.0, x, np.full(4, 0.3), outside="nearest")
    assert np.isfinite(near).all()
    np.testing.assert_array_equal(near[1], t.gradient(0.0, [[t.grid().hi[0], 5.0]], [0.3])[0])
    assert np.isfinite(t.worst_disturbance(0.0, x, np.full(4, 0.3), outside="nearest")).all()


def test_bad_queries_name_the_bad_value(pointmass_table):
    t = pointmass_table
    with pytest.raises(ValueError, match=r"x must be finite, got \[nan, 1.0\]"):
        t.value(0.0, [[np.nan, 1.0]], 0.3)
    with pytest.raises(ValueError, match=r"shape \(N, 2\)"):
        t.value(0.0, [[1.0, 2.0, 3.0]], 0.3)
    with pytest.raises(ValueError, match="z must be finite"):
        t.value(0.0, [[1.0, 2.0]], np.inf)
    # the one check of batched inputs (softreach.reach.inputs): the first bad entry of a column and where it is
    with pytest.raises(ValueError, match=r"t must be finite, got nan at index 1"):
        t.value([0.0, np.nan, 0.1], [[1.0, 2.0]] * 3, 0.3)
    with pytest.raises(ValueError, match=r"x must have shape \(N, 2\) or \(2,\) \(v, y\), got \(3,\)"):
        t.value(0.0, [1.0, 2.0, 3.0], 0.3)


def test_queries_take_torch_tensors(pointmass_table):
    """A table answers tensors as the filter does (``softreach.reach.inputs``): the same values as for numpy."""
    torch = pytest.importorskip("torch")
    x = np.array([[0.0, 5.0], [-3.0, 10.0], [2.0, 1.0]])
    t, z = torch.tensor(0.2, dtype=torch.float64), torch.tensor([0.1, 0.3, 0.6], dtype=torch.float64)
    got = pointmass_table.value(t, torch.tensor(x, requires_grad=True), z)
    np.testing.assert_array_equal(got, pointmass_table.value(0.2, x, [0.1, 0.3, 0.6]))


def test_classical_only_table_wants_no_budget(tmp_path):
    path = tmp_path / "v.srt"
    solve_table(MODEL, _cfg(classical_only=True), path, progress=False)
    t = load_table(path)
    assert t.fields == ["V"] and np.isfinite(t.value(0.0, [[0.0, 2.0]]))[0]
    with pytest.raises(ValueError, match="holds only the classical V"):
        t.value(0.0, [[0.0, 2.0]], 0.3)


def test_model_mismatch_is_an_error(pointmass_table):
    from softreach.reach.models.pointmass import PointMass

    pointmass_table.check_compatible(MODEL)
    with pytest.raises(TableError, match="u_max"):
        pointmass_table.check_compatible(PointMass(u_max=55.0))
    with pytest.raises(TableError, match="model 'pointmass', not 'glider'"):
        pointmass_table.check_compatible(get_model("glider"))


def test_optimal_inputs_and_q_min(pointmass_table):
    t = pointmass_table
    x = np.array([[-12.0, 4.0], [8.0, 12.0]])
    a = t.optimal_control(0.0, x, [0.3, 0.3])
    b = t.worst_disturbance(0.0, x, [0.3, 0.3])
    assert a.shape == (2, 1) and b.shape == (2, 1)
    assert set(np.abs(a.ravel())) <= {60.0, 0.0} and set(np.abs(b.ravel())) <= {10.0, 0.0}
    # falling fast outside C2, 4 m up: brake (u = +60) while the wind pushes down
    assert a[0, 0] == 60.0 and b[0, 0] == -10.0
    # climbing fast at 12 m with one second to land: thrust down while the wind pushes up
    assert a[1, 0] == -60.0 and b[1, 0] == 10.0
    g = t.grid("V")
    vv, yy = np.meshgrid(*t.state_axes("V"), indexing="ij")
    pts = np.stack([vv.ravel(), yy.ravel()], 1)
    qmin = t.q_min(0.0, pts)
    for q in (0.0, 0.3, 0.6):
        # equal up to nodes where W crosses zero within round-off of q (first crossing vs. value at q)
        differ = (qmin <= q).reshape(g.shape) != t.set_mask(0.0, q, margin=0.0)
        assert differ.sum() <= 2, (q, differ.sum())
    band = t.budget_band_mask(0.0, 0.3, 0.6)
    np.testing.assert_array_equal(band, t.set_mask(0.0, 0.6) & ~t.set_mask(0.0, 0.3))
    assert band.any()


def test_bad_solve_input_fails_before_work(tmp_path):
    with pytest.raises(ValueError, match="grid size for v must be an integer >= 5, got -3"):
        validate(MODEL, _cfg(shape=(-3, 21)), tmp_path / "a.srt")
    with pytest.raises(ValueError, match="eps must be a finite number > 0, got 0.0"):
        validate(MODEL, _cfg(eps=0.0), tmp_path / "a.srt")
    with pytest.raises(ValueError, match="eps must be a finite number > 0, got nan"):
        validate(MODEL, _cfg(eps=float("nan")), tmp_path / "a.srt")
    with pytest.raises(ValueError, match="does not contain the hard-constraint"):
        validate(MODEL, _cfg(domain=((-12.0, -5.0), (20.0, 20.0))), tmp_path / "a.srt")
    with pytest.raises(ValueError, match="does not exist"):
        validate(MODEL, _cfg(), tmp_path / "missing" / "a.srt")
    with pytest.raises(ValueError, match="PointMassParams.u_max must be finite"):
        get_model("pointmass", u_max=float("inf"))


def test_contains_is_the_set_mask_rule_at_the_nodes(pointmass_table):
    """One membership rule: at the nodes, point queries agree with the drawn sets (and the agents' starts use it)."""
    from softreach.agents.tables import in_set

    t = pointmass_table
    vv, yy = np.meshgrid(*t.state_axes(), indexing="ij")
    pts = np.stack([vv.ravel(), yy.ravel()], 1)
    for q in (None, 0.0, 0.06, 0.3):
        inside = t.contains(0.5, pts, q).reshape(vv.shape)
        np.testing.assert_array_equal(inside, t.set_mask(0.5) if q is None else t.set_mask(0.5, q))
    edge = pts[t.contains(0.0, pts, 0.3) & ~t.contains(0.0, pts, 0.0)][0]
    assert in_set(t, edge, 0.3) and not in_set(t, edge, 0.0)
    assert not t.contains(0.0, [[100.0, 5.0]], 0.3)[0]  # off the table: not contained
    with pytest.raises(ValueError, match="budget must be >= 0"):
        t.contains(0.0, pts[:2], -0.1)


def test_interrupted_budget_surface_resumes_to_the_same_table(tmp_path, monkeypatch):
    """A ``Q_min`` solve killed after three snapshots resumes from the last one stored (masked by the feasible set,
    as the unbroken solve goes on from it); the ``V`` it marches in lockstep is marched again up to there."""
    cfg = SolveConfig(shape=(31, 31), budget_points=0, snapshots=5, budget_surface=True,
                      settings=SolverSettings.from_accuracy("medium", compile=False))
    a, b = _solve_killed_then_resumed(cfg, "Q_min", tmp_path, monkeypatch)
    np.testing.assert_array_equal(np.asarray(a.values("V")), np.asarray(b.values("V")))
    qa, qb = np.asarray(a.values("Q_min")), np.asarray(b.values("Q_min"))
    np.testing.assert_allclose(qa, qb, atol=1e-5)
    for q in (0.0, 0.06, 0.3, 0.6):
        np.testing.assert_array_equal(a.set_mask(0.0, q), b.set_mask(0.0, q))
