"""The environments' integrator lives in :mod:`softreach.reach.integrator` (one integrator for the envs, the
rollouts and the plots); this module keeps its old import path working, private names included (the fast-path
tests and scripts written against it import them from here)."""

from softreach.reach.budget_quadrature import hermite as _hermite  # noqa: F401
from softreach.reach.budget_quadrature import hermite_basis as _hermite_basis  # noqa: F401
from softreach.reach.budget_quadrature import kink_grid as _kink_grid  # noqa: F401
from softreach.reach.integrator import (BatchPeriod, ScalarModel, _integrate_period_scalar, _rates,  # noqa: F401
                                        episode_ends, integrate_batch, integrate_period, rk4_stages, rk4_step,
                                        scalar_model, stage_rates)

__all__ = ["BatchPeriod", "ScalarModel", "episode_ends", "integrate_batch", "integrate_period", "rk4_stages",
           "rk4_step", "scalar_model", "stage_rates"]
