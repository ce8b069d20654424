"""The GPU's time loop checked on the CPU: no host synchronisation inside a step, one graph per step, and the same
steps as the host loop (reach/numerics/device_loop.py)."""

from __future__ import annotations

import numpy as np
import pytest

from softreach.reach import Grid, SolverSettings, budget_axis, get_model, soft_problem
from softreach.reach.numerics import solver as S
from softreach.reach.numerics.device_loop import march_on_device, whole_step

import torch

#: every Tensor method that makes the host wait for the device's result
SYNCING = ("item", "tolist", "cpu", "numpy", "__bool__", "__float__", "__int__", "__index__", "nonzero")


def _op(n: int = 13, nz: int = 11, accuracy: str = "medium"):
    model = get_model("pointmass")
    z_lo, z_hi, k = budget_axis(model.horizon, nz)
    grid = Grid(model.domain[0] + (z_lo,), model.domain[1] + (z_hi,), (n, n, k))
    st = SolverSettings.from_accuracy(accuracy, dtype="float32", compile=False)
    return S.HamiltonianOperator(soft_problem(model, 1e-3, model.budget_scale), grid, st), st


@pytest.fixture
def syncs(monkeypatch):
    """Counts of the synchronising calls, by name, made while ``syncs["inside"]`` is set."""
    seen = {"inside": False, "calls": []}
    for name in SYNCING:
        original = getattr(torch.Tensor, name)

        def counted(self, *a, _orig=original, _name=name, **k):
            if seen["inside"]:
                seen["calls"].append(_name)
            return _orig(self, *a, **k)

        monkeypatch.setattr(torch.Tensor, name, counted)
    return seen


def test_a_step_never_waits_for_the_device_and_the_loop_waits_once_per_batch(syncs):
    op, st = _op()
    steps = []

    def step(*args):
        syncs["inside"] = True
        try:
            out = whole_step(op, st.time_order, st.cfl, *args)
        finally:
            syncs["inside"] = False
        steps.append(1)
        return out

    u = march_on_device(step, st.cfl, 1.0, op.terminal(1.0), 0.8)
    assert syncs["calls"] == []  # nothing inside a step
    assert len(steps) >= 8
    syncs["inside"] = True
    float(op.terminal(1.0).max())  # the counter sees what a host loop does at every step
    syncs["inside"] = False
    assert syncs["calls"] == ["__float__"]
    syncs["calls"].clear()
    # outside the steps: each batch ends with reading t and the failure flag; the first batch is one step, the
    # second covers the rest when the speed does not change, a third when it grew
    syncs["inside"] = True
    march_on_device(lambda *a: whole_step(op, st.time_order, st.cfl, *a), st.cfl, 1.0, op.terminal(1.0), 0.8)
    syncs["inside"] = False
    assert len(syncs["calls"]) <= 2 * 3, syncs["calls"]
    assert torch.isfinite(u).all()


def test_device_loop_takes_the_host_loops_steps():
    """The step's length on the device is the host rule's, in float64: the same values at the end."""
    op, st = _op(accuracy="high")
    stepper = S.Stepper(op, st, engine="eager")
    host = S.march(stepper, 1.0, op.terminal(1.0), 0.85)
    device = march_on_device(lambda *a: whole_step(op, st.time_order, st.cfl, *a), st.cfl, 1.0, op.terminal(1.0), 0.85)
    np.testing.assert_allclose(device.numpy(), host.numpy(), rtol=0, atol=2e-5 * float(host.abs().max()))


def test_a_nan_is_reported_at_the_batch_end():
    op, st = _op()
    u = op.terminal(1.0).clone()
    u[3, 4, 5] = float("nan")
    with pytest.raises(FloatingPointError, match="not finite"):
        march_on_device(lambda *a: whole_step(op, st.time_order, st.cfl, *a), st.cfl, 1.0, u, 0.9)


@pytest.mark.parametrize("accuracy", ["medium", "very_high"])
def test_the_whole_step_is_one_graph(accuracy):
    """``torch.compile`` sees the step with its CFL length as one graph: no break (which would run Python and
    synchronise between the pieces), and every operation a pointwise or reduction kernel candidate."""
    op, st = _op(accuracy=accuracy)
    f64 = dict(dtype=torch.float64)
    args = (op.terminal(1.0), torch.tensor(1.0, **f64), torch.tensor(0.9, **f64), torch.tensor(1e-12, **f64),
            torch.zeros((), dtype=torch.bool))
    explain = torch._dynamo.explain(lambda *a: whole_step(op, st.time_order, st.cfl, *a))(*args)
    assert explain.graph_count == 1 and explain.graph_break_count == 0, explain.break_reasons
    ops = [n for g in explain.graphs for n in g.graph.nodes if n.op == "call_function"]
    # nothing in the step moves data to the host or launches per-element Python
    names = {getattr(n.target, "__name__", str(n.target)) for n in ops}
    assert not names & {"item", "cpu", "tolist", "nonzero", "_local_scalar_dense"}, names
