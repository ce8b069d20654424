"""``softreach evaluate``: run a policy (trained, table-optimal or random) with or without the safety filter and
measure landings, hard violations, budget use and interventions, per episode and in aggregate.

Statistics (95 %, :mod:`softreach.agents.statistics`): rates (landing, hard violation, over budget) carry
Wilson score intervals; means (budget used, intervention rate, return, ...) carry Student-t intervals. All
policies evaluated with the same ``seed``, start distribution and budget see the same starts and, under
``wind="random"``, the same gusts (each episode ``i`` resets the environment with seed ``seed + i``):
comparisons are paired.
"""

from __future__ import annotations

import math
from dataclasses import asdict, dataclass, field
from pathlib import Path
from typing import Any

import numpy as np

from softreach.reach.registry import model_class

from .policies import check_fits
from .envs import RULES, WINDS, check_budget, check_choice, make_env, normalized_action, unwrap_filter
# re-exported: the statistics are imported from this module too
from .statistics import Z95, aggregate, mean_ci, wilson
from .tables import (TableOracle, as_table, in_set, paper_starts, sample_certified, sample_inside, sample_uniform,
                     sink_rate, start_value)

STARTS = ("certified", "inside", "paper", "uniform", "env")
POLICIES = ("optimal", "random")
#: an episode is "over budget" when it used more than ``Q + BUDGET_TOL`` seconds (the paper's proxy for the
#: sets: one millisecond of budget; the environment integrates the budget to about a microsecond)
BUDGET_TOL = 1e-3


# --------------------------------------------------------------------------------------------- policies

class OptimalPolicy:
    """The table's feedback ``a*(t, x, z)`` (normalised), the controller of the paper's guarantee."""

    name = "optimal"

    def __init__(self, oracle: TableOracle):
        self.oracle = oracle

    def act(self, env, obs: np.ndarray) -> np.ndarray:
        base = env.unwrapped
        return normalized_action(base, self.oracle.optimal_control(base.time, base.state, base.budget))


class RandomPolicy:
    """Uniform random actions (seeded)."""

    name = "random"

    def __init__(self, seed: int):
        self.rng = np.random.default_rng(seed)

    def act(self, env, obs: np.ndarray) -> np.ndarray:
        space = env.action_space
        return self.rng.uniform(space.low, space.high).astype(np.float32)


class SB3Policy:
    """A saved Stable-Baselines3 policy, deterministic."""

    def __init__(self, model: Any, name: str):
        self.model = model
        self.name = name

    def act(self, env, obs: np.ndarray) -> np.ndarray:
        action, _ = self.model.predict(obs, deterministic=True)
        return np.asarray(action, dtype=np.float32)


# --------------------------------------------------------------------------------------------- spec & result

@dataclass
class EvalSpec:
    """What ``softreach evaluate`` was asked to do.

    :param model: a registered short name (``"pointmass"``, ``"glider"``, ``"dubins"``) or ``"module:Class"``
    :param policy: a saved policy (path), ``"optimal"`` (the table's ``a*``) or ``"random"``
    :param filter: the safety filter's table; ``None``: no filter
    :param rule: the filter's rule
    :param budget: ``Q`` of every episode; ``None``: drawn per episode from the environment's default range
        (``paper`` starts use their own budgets, or only the start of this ``Q`` when it is given)
    :param wind: ``"none"``, ``"random"`` or ``"adversarial"``
    :param table: the table for ``optimal``, the adversarial wind and the ``inside``/``paper`` starts
        (default: the filter's)
    :param episodes: number of episodes
    :param starts: ``"certified"`` (sampled from ``RA~_Q`` and kept where the filter certifies the start: the
        starts of the filter's guarantee; needs a ``--held`` table), ``"inside"`` (sampled from ``RA~_Q``),
        ``"paper"`` (the representative points, cycled) or
        ``"uniform"`` (uniform over the hard-constraint box, to show what happens outside the guarantee) or
        ``"env"`` (the environment's own reset distribution, the one training uses)
    :param seed: seed of the starts, the budgets, the gusts and the random policy
    :param margin: the filter's margin (``None``: computed)
    :param keep_traces: keep the per-step traces of this many episodes (for the plots)
    """

    model: str = "pointmass"
    policy: str = "optimal"
    filter: str | None = None
    rule: str = "switch"
    budget: float | None = None
    wind: str = "none"
    table: str | None = None
    episodes: int = 100
    starts: str = "inside"
    seed: int = 0
    margin: float | None = None
    keep_traces: int = 1000


@dataclass
class Trace:
    """One episode step by step: ``t (S+1,)``, ``x (S+1, n)``, ``z (S+1,)``, ``policy_action``/``applied_action``
    ``(S, m)`` (normalised), ``wind (S, k)``, ``filter_active (S,)``."""

    t: np.ndarray
    x: np.ndarray
    z: np.ndarray
    policy_action: np.ndarray
    applied_action: np.ndarray
    wind: np.ndarray
    filter_active: np.ndarray
    budget: float
    landed: bool
    hard_violation: bool


@dataclass
class EvaluationResult:
    """Per-episode rows, aggregates and (optionally) traces of one evaluation."""

    config: dict[str, Any]
    episodes: list[dict[str, Any]]
    aggregates: dict[str, Any]
    traces: list[Trace] = field(default_factory=list)


# --------------------------------------------------------------------------------------------- evaluation

def resolve_policy(spec: EvalSpec, oracle: TableOracle | None, policy_obj: Any = None):
    """The policy object for ``spec.policy`` (or ``policy_obj`` if given: an SB3 model or an object with ``act``)."""
    if policy_obj is not None:
        if hasattr(policy_obj, "act"):
            return policy_obj
        return SB3Policy(policy_obj, str(spec.policy))
    if spec.policy == "optimal":
        if oracle is None:
            raise ValueError("--policy optimal needs a table (its a*): give --filter TABLE or --table TABLE")
        return OptimalPolicy(oracle)
    if spec.policy == "random":
        return RandomPolicy(spec.seed + 7919)
    from .safe_train import load_method_policy  # a Saute policy appends its safety state itself

    return SB3Policy(load_method_policy(spec.policy), str(spec.policy))


def _finite_or_none(v: float) -> float | None:
    """``v``, or ``None`` for a model without that quantity (``nan``: the Dubins vehicle has no sink rate)."""
    return v if math.isfinite(v) else None


def check_spec(spec: EvalSpec, policy_given: bool = False) -> None:
    """Check ``spec`` (ValueError / FileNotFoundError naming the bad value); ``policy_given``: the policy object
    is passed in, ``spec.policy`` is only its name."""
    model_class(spec.model)  # raises, naming an unknown model
    # the policy first: a mistyped path must not be reported as a missing table
    if not policy_given and spec.policy not in POLICIES and not Path(spec.policy).exists():
        raise FileNotFoundError(f"policy file {spec.policy} does not exist (give a saved policy: a model.zip or its "
                                f"run directory, or 'optimal' or 'random')")
    check_choice("rule", spec.rule, RULES)
    check_choice("wind", spec.wind, WINDS)
    check_choice("start distribution", spec.starts, STARTS)
    if isinstance(spec.episodes, bool) or not isinstance(spec.episodes, (int, np.integer)) or spec.episodes < 1:
        raise ValueError(f"episodes must be a positive integer, got {spec.episodes!r}")
    from softreach.reach.models import get_model

    check_budget(spec.budget, get_model(spec.model).horizon)
    if isinstance(spec.budget, (tuple, list)):
        raise ValueError(f"evaluate takes one budget Q (or none for the environment's range), got {spec.budget!r}")
    table = spec.table or spec.filter
    needs = [what for what, cond in (("--policy optimal", spec.policy == "optimal"),
                                     ("--wind adversarial", spec.wind == "adversarial"),
                                     (f"--starts {spec.starts}",
                                      spec.starts in ("certified", "inside", "paper"))) if cond]
    if needs and table is None:
        raise ValueError(f"{', '.join(needs)} need(s) a W_eps table: give --filter TABLE or --table TABLE")
    for path in (spec.filter, spec.table):
        if path is not None and not Path(path).is_file():
            raise FileNotFoundError(f"table {path} does not exist (solve one with `softreach solve {spec.model}`)")


def certifier(table, env) -> Any:
    """The ``ValueFilter`` whose :meth:`~softreach.filters.ValueFilter.certify` says which starts carry the
    filter's guarantee in ``env`` (its control period, its model); the environment's own filter where it has one.

    :raises ValueError: the table was not solved for the sampled-data game (nothing is certified with it)
    """
    filt = unwrap_filter(env)
    # the same file: a table loaded again for each evaluation of a sweep meets the filter core shared since the first
    if filt is not None and (filt.table is table or Path(filt.table.path).resolve() == Path(table.path).resolve()):
        vf = filt.value_filter
    else:
        from softreach.filters import ValueFilter

        # the landing checks the environment's SafetyFilter asks for, so that an evaluation alone certifies the
        # same starts as one under the filter (and loads the same cells: the glider's ship for its 2 checks only)
        vf = ValueFilter(table, float(env.unwrapped.dt), model=env.unwrapped.model,
                         target_checks=int(getattr(env.unwrapped, "n_substeps", 1)))
    return vf


def _starts(spec: EvalSpec, table, env, rng: np.random.Generator, budget_range: tuple[float, float]):
    """The ``(x0, Q)`` of every episode."""
    n = spec.episodes
    model = env.unwrapped.model
    vf = certifier(table, env) if spec.starts == "certified" else None
    if spec.starts == "paper":
        budgets = [spec.budget] if spec.budget is not None else list(model.paper_budgets)
        pts = paper_starts(table, budgets)
        if not pts:
            raise ValueError(f"no paper start: RA~_Q is empty for every Q in {budgets}")
        return [(pts[i % len(pts)][0], pts[i % len(pts)][1]) for i in range(n)]
    out = []
    for _ in range(n):
        if spec.budget is not None:
            q = float(spec.budget)
        else:
            lo, hi = budget_range
            q = lo if lo == hi else float(rng.uniform(lo, hi))
        if spec.starts == "env":
            out.append((None, q))  # the environment draws the state at reset
        elif spec.starts == "inside":
            out.append((np.asarray(sample_inside(table, q, rng), dtype=np.float64), q))
        elif spec.starts == "certified":
            out.append((sample_certified(table, vf, q, rng), q))
        else:
            out.append((np.asarray(sample_uniform(model, rng), dtype=np.float64), q))
    return out


def run_episode(env, policy, x0: np.ndarray | None, q: float, seed: int, table=None, keep_trace: bool = True):
    """One episode from ``x0`` (``None``: the environment's reset draws it) with budget ``q``; returns
    ``(row, trace)``."""
    base = env.unwrapped
    model = base.model
    options = {"budget": float(q)}
    if x0 is not None:
        options["state"] = [float(v) for v in x0]
    obs, info = env.reset(seed=seed, options=options)
    x0 = base.state.copy()
    filt = unwrap_filter(env)
    ts, xs, zs = [base.time], [base.state.copy()], [base.budget]
    pol, app, winds, active = [], [], [], []
    ret, steps, effort, outside_steps, outside_time, interventions = 0.0, 0, 0.0, 0, 0.0, 0
    min_value = math.inf
    terminated = truncated = False
    t_prev = base.time
    while not (terminated or truncated):
        action = policy.act(env, obs)
        obs, reward, terminated, truncated, info = env.step(action)
        steps += 1
        ret += float(reward)
        h = base.time - t_prev
        t_prev = base.time
        applied = np.asarray(info.get("applied_action", np.clip(action, -1, 1)), dtype=np.float64).reshape(-1)
        effort += float(np.mean(applied ** 2)) * h
        if info.get("soft_violation"):
            outside_steps += 1
            outside_time += h
        is_active = bool(info.get("filter_active", False))
        interventions += int(is_active)
        if "value" in info:
            min_value = min(min_value, float(info["value"]))
        if keep_trace:
            ts.append(base.time)
            xs.append(base.state.copy())
            zs.append(base.budget)
            pol.append(np.asarray(action, dtype=np.float64).reshape(-1))
            app.append(applied)
            winds.append(np.asarray(info.get("wind", [np.nan]), dtype=np.float64).reshape(-1))
            active.append(is_active)
    landed = bool(info.get("landed", False))
    hard = bool(info.get("hard_violation", False))
    used = float(info.get("budget_used", q - base.budget))
    horizon = base.horizon
    row: dict[str, Any] = {
        "start_state": [float(v) for v in x0],
        "budget": float(q),
        "start_value": None,
        "start_inside": None,
        "landed": landed,
        "hard_violation": hard,
        "over_budget": used > q + BUDGET_TOL,
        "budget_used": used,
        "budget_left": float(base.budget),
        "time_outside_c2": outside_time,
        "touchdown_sink_rate": _finite_or_none(sink_rate(model, base.state)) if landed else None,
        "control_effort": effort / horizon,
        "interventions": interventions if filt is not None else None,
        "intervention_rate": interventions / steps if (filt is not None and steps) else None,
        "min_value": min_value if (filt is not None and math.isfinite(min_value)) else None,
        "steps": steps,
        "duration": float(base.time - ts[0]),
        "return": ret,
        "outcome": "landed" if landed else ("hard_violation" if hard else "timeout"),
        "final_state": [float(v) for v in base.state],
    }
    if table is not None:
        v = start_value(table, x0, q)
        row["start_value"] = v if math.isfinite(v) else None
        row["start_inside"] = bool(in_set(table, x0, q))
    trace = None
    if keep_trace:
        m = base.action_space.shape[0]
        trace = Trace(t=np.array(ts), x=np.array(xs), z=np.array(zs),
                      policy_action=np.array(pol).reshape(-1, m), applied_action=np.array(app).reshape(-1, m),
                      wind=np.array(winds), filter_active=np.array(active, dtype=bool), budget=float(q),
                      landed=landed, hard_violation=hard)
    return row, trace


def evaluate(spec: EvalSpec, policy_obj: Any = None, progress: bool = False) -> EvaluationResult:
    """Run ``spec.episodes`` episodes and measure them (see the module docstring).

    :param policy_obj: use this policy instead of loading ``spec.policy`` (an SB3 model or an object with
        ``act(env, obs)``); ``spec.policy`` is then only its name in the report
    :param progress: show a progress bar
    """
    check_spec(spec, policy_given=policy_obj is not None)
    table_path = spec.table or spec.filter
    table = as_table(table_path) if table_path is not None else None
    oracle = TableOracle(table) if table is not None and table.has_budget else None
    if table is not None:
        from softreach.reach.models import get_model

        table.check_compatible(get_model(spec.model))
    policy = resolve_policy(spec, oracle, policy_obj)
    env = make_env(spec.model, wind=spec.wind, wind_table=oracle, filter_table=table if spec.filter and
                   spec.filter == table_path else spec.filter, rule=spec.rule, margin=spec.margin)
    if isinstance(policy, SB3Policy):
        check_fits(policy.model, env, spec.model, spec.policy if policy_obj is None else None)
    base = env.unwrapped
    rng = np.random.default_rng(spec.seed)
    starts = _starts(spec, table, env, rng, base.budget_range)
    rows, traces = [], []
    it = range(len(starts))
    if progress:
        from tqdm.auto import tqdm

        it = tqdm(it, desc=f"evaluate {policy.name}{' +filter' if spec.filter else ''} ({spec.wind} wind)", unit="ep")
    for i in it:
        x0, q = starts[i]
        row, trace = run_episode(env, policy, x0, q, spec.seed + i, table=table, keep_trace=i < spec.keep_traces)
        rows.append({"episode": i, "seed": spec.seed + i, **row})
        if trace is not None:
            traces.append(trace)
    env.close()
    config = {**asdict(spec), "policy_name": policy.name, "filtered": spec.filter is not None,
              "table_used": str(table_path) if table_path else None, "budget_tol": BUDGET_TOL,
              "horizon": base.horizon, "dt": base.dt, "state_names": list(base.model.state_names)}
    return EvaluationResult(config=config, episodes=rows, aggregates=aggregate(rows, spec.filter is not None),
                            traces=traces)


__all__ = ["BUDGET_TOL", "EvalSpec", "EvaluationResult", "OptimalPolicy", "POLICIES", "RandomPolicy", "SB3Policy",
           "STARTS", "Trace", "Z95", "aggregate", "check_spec", "evaluate", "mean_ci", "run_episode", "wilson"]
