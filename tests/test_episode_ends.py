"""One end-of-episode rule (``reach.sim.integrator.episode_ends``) for the envs' sub-steps and the rollouts: a model's
scalar fast path, its vectorised methods on one state and on a batch give the same answer at every state."""

from __future__ import annotations

import numpy as np
import pytest

from softreach.reach import get_model
from softreach.reach.sim.integrator import episode_ends, scalar_model


@pytest.mark.parametrize("name", ["pointmass", "glider", "dubins"])
def test_scalar_single_and_batched_ends_agree(name):
    model = get_model(name)
    lo, hi = (np.asarray(v, dtype=np.float64) for v in model.domain)
    rng = np.random.default_rng(0)
    X = rng.uniform(lo - 0.1 * (hi - lo), hi + 0.1 * (hi - lo), size=(400, len(lo)))
    box = model.target_box
    if box is not None:  # many states in the target, where the rate decides
        X[:100] = rng.uniform(np.maximum(box[0], lo), np.minimum(box[1], hi), size=(100, len(lo)))
    rate = np.where(rng.uniform(size=len(X)) < 0.5, 0.0, rng.uniform(0.0, 1.0, len(X)))
    batch = episode_ends(model, 0.5, [X[:, i] for i in range(X.shape[1])], rate)
    assert batch.shape == (len(X),) and batch.any() and not batch.all()
    hard = np.asarray(model.hard_constraint(0.5, [X[:, i] for i in range(X.shape[1])])) > 0
    landed = (rate == 0) & (np.asarray(model.target(0.5, [X[:, i] for i in range(X.shape[1])])) <= 0)
    np.testing.assert_array_equal(batch, hard | landed)
    fast = scalar_model(model)
    for i in range(len(X)):
        one = episode_ends(model, 0.5, [np.float64(v) for v in X[i]], float(rate[i]))
        assert bool(one) == batch[i]
        if fast is not None:
            got = episode_ends(fast, 0.5, X[i].tolist(), float(rate[i]))
            assert type(got) is bool and got == batch[i]
