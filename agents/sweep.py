"""``softreach sweep``: the grid of a sweep, its runs and evaluations, and their stable ids.

A sweep is a grid of training runs (model x algorithm x method x filter rule x training budget x wind x variant x
seed; the methods are plain PPO/SAC and the constrained-RL baselines of :mod:`.safe_rl`, which train without
the filter, so a baseline with a filter rule is left out of the grid),
each evaluated under a list of settings (evaluation wind x budget ``Q`` x with/without the filter). This module
holds the configuration only: :class:`SweepSpec` (what the user asks for, from the command line or a JSON/TOML
sweep file), :class:`SweepRun` (one training run) and :class:`EvalSetting` (one evaluation of it). Running them
is :mod:`.sweep_exec`; the table, report and plots are :mod:`.sweep_report`.

Ids are hashes of everything that changes a result, so that rerunning a sweep into the same folder finds the
runs already done (:func:`stable_hash`): a run's id covers its training settings only, an evaluation's id its
evaluation settings, so adding an evaluation budget to a finished sweep evaluates the trained policies again
without retraining them.
"""

from __future__ import annotations

import hashlib
import json
import tomllib
from dataclasses import asdict, dataclass, field, fields
from pathlib import Path
from typing import Any

from .config import ALGOS, MODELS
from .envs import RULES, WINDS, check_budget, check_choice
from .evaluate import STARTS

SWEEP_SCHEMA = "softreach.sweep/1"
#: a run's filter rule; ``"none"`` trains without the safety filter
FILTER_RULES = ("none",) + RULES
EVAL_FILTERS = ("on", "off")
CHECKPOINTS = ("best", "final")
#: the keys of an overrides block: RunConfig fields under "run", each algorithm's config fields under its name,
#: the baselines' :class:`~softreach.agents.safe_rl.SafeRLConfig` fields under "safe"
OVERRIDE_SECTIONS = ("run",) + ALGOS + ("safe",)


def stable_hash(obj: Any, length: int = 10) -> str:
    """A short hex digest of ``obj``'s canonical JSON (sorted keys): the same settings give the same id on every
    machine and Python version, unlike :func:`hash`."""
    text = json.dumps(obj, sort_keys=True, separators=(",", ":"), default=str)
    return hashlib.sha256(text.encode()).hexdigest()[:length]


def parse_budget(value: Any) -> float | tuple[float, float] | None:
    """A training budget as a sweep file or the command line writes it: ``None`` or ``"default"`` (the
    environment's range), a number ``Q``, ``"LOW:HIGH"`` or ``[LOW, HIGH]``.

    :raises ValueError: naming the value
    """
    if value is None or value == "default":
        return None
    if isinstance(value, str):
        try:
            if ":" in value:
                lo, hi = value.split(":", 1)
                return (float(lo), float(hi))
            return float(value)
        except ValueError:
            raise ValueError(f"budget must be Q, LOW:HIGH or 'default', got {value!r}") from None
    if isinstance(value, (list, tuple)):
        if len(value) != 2:
            raise ValueError(f"budget range must be [LOW, HIGH], got {value!r}")
        return (float(value[0]), float(value[1]))
    if isinstance(value, bool) or not isinstance(value, (int, float)):
        raise ValueError(f"budget must be Q, LOW:HIGH or 'default', got {value!r}")
    return float(value)


def budget_text(budget: float | tuple[float, float] | None) -> str:
    """``"default"``, ``"0.3"`` or ``"0:0.6"``: how the table and the run ids write a training budget."""
    if budget is None:
        return "default"
    if isinstance(budget, tuple):
        return f"{budget[0]:g}:{budget[1]:g}"
    return f"{budget:g}"


@dataclass(frozen=True)
class SweepRun:
    """One training run of a sweep.

    :param model: ``"pointmass"`` or ``"glider"``
    :param algo: ``"ppo"`` or ``"sac"``
    :param rule: the safety filter's rule during training, or ``"none"`` (no filter)
    :param budget: training budget (``None``: the environment's range; ``Q``; ``(low, high)``)
    :param wind: training wind
    :param seed: training seed
    :param variant: name of the hyperparameter variant (its overrides are in ``run_overrides``/``algo_overrides``)
    :param table: the model's ``W_eps`` table, where the run needs one (filter or adversarial wind), else ``None``
    :param timesteps: environment steps (``None``: the model's default)
    :param n_envs: environments stepped together (``None``: the default)
    :param run_overrides: fields of :class:`~softreach.agents.config.RunConfig` to replace
    :param algo_overrides: fields of the algorithm's config to replace
    :param method: ``"plain"`` (the algorithm as it is), ``"lag"`` (PPO-Lagrangian) or ``"saute"`` (PPO-Saute)
    :param safe_overrides: fields of :class:`~softreach.agents.safe_rl.SafeRLConfig` to replace (baselines only)
    """

    model: str
    algo: str
    rule: str
    budget: float | tuple[float, float] | None
    wind: str
    seed: int
    variant: str = "default"
    table: str | None = None
    timesteps: int | None = None
    n_envs: int | None = None
    run_overrides: dict[str, Any] = field(default_factory=dict)
    algo_overrides: dict[str, Any] = field(default_factory=dict)
    method: str = "plain"
    safe_overrides: dict[str, Any] = field(default_factory=dict)

    @property
    def run_id(self) -> str:
        """Readable prefix plus the hash of every field (e.g. ``pointmass-ppo-switch-s0-3f2a...``,
        ``pointmass-ppo-lag-none-s0-...``); a plain run hashes without the method fields, so its id is the one
        it had before methods existed and earlier sweeps resume."""
        d = asdict(self)
        if self.method == "plain" and not self.safe_overrides:
            del d["method"], d["safe_overrides"]
        method = "" if self.method == "plain" else f"-{self.method}"
        return f"{self.model}-{self.algo}{method}-{self.rule}-s{self.seed}-{stable_hash(d)}"

    def train_spec(self, out: str | Path, progress: bool = False):
        """The :class:`~softreach.agents.train.TrainSpec` of this run, writing into ``out``."""
        from .train import TrainSpec

        return TrainSpec(model=self.model, algo=self.algo, filter=self.table if self.rule != "none" else None,
                         rule=self.rule if self.rule != "none" else "switch", budget=self.budget, wind=self.wind,
                         table=self.table, timesteps=self.timesteps, n_envs=self.n_envs, seed=self.seed,
                         out=str(out), progress=progress, run_overrides=dict(self.run_overrides),
                         algo_overrides=dict(self.algo_overrides))


@dataclass(frozen=True)
class EvalSetting:
    """One evaluation of a trained policy (see :class:`~softreach.agents.evaluate.EvalSpec`).

    :param wind: evaluation wind
    :param budget: ``Q`` of every episode (``None``: drawn from the environment's range)
    :param filter: ``"on"`` (with the safety filter: the run's rule, or ``switch`` for a run trained without
        one) or ``"off"``
    :param episodes: episodes
    :param starts: start distribution
    :param seed: evaluation seed (the same for every run: paired comparisons)
    :param checkpoint: ``"best"`` (``best_model.zip`` of the periodic evaluations, ``model.zip`` when there is
        none) or ``"final"`` (``model.zip``)
    :param table: the model's table (starts inside ``RA~_Q``, adversarial wind, filter), or ``None``
    """

    wind: str
    budget: float | None
    filter: str
    episodes: int
    starts: str
    seed: int
    checkpoint: str
    table: str | None

    @property
    def eval_id(self) -> str:
        q = "drawn" if self.budget is None else f"{self.budget:g}"
        return f"{self.wind}-q{q}-filter{self.filter}-{stable_hash(asdict(self), 6)}"


@dataclass
class SweepSpec:
    """What ``softreach sweep`` was asked to do: lists are grid axes (every combination is one run).

    :param models: models
    :param algos: algorithms
    :param methods: training methods (:data:`~softreach.agents.safe_rl.METHODS`; the baselines only with rule
        ``"none"``: other combinations are left out of the grid)
    :param rules: filter rules during training (``"none"``, ``"switch"``, ``"smooth"``)
    :param budgets: training budgets (``None``, ``Q`` or ``(low, high)``; see :func:`parse_budget`)
    :param winds: training winds
    :param seeds: training seeds
    :param variants: named overrides blocks ``{"run": {...}, "ppo": {...}, "sac": {...}}`` (a grid axis)
    :param tables: the ``W_eps`` table of each model (``{"pointmass": "runs/pointmass.srt"}``)
    :param timesteps: environment steps per run (``None``: each model's default)
    :param n_envs: environments stepped together (``None``: the default)
    :param overrides: an overrides block for every run (a variant's own block wins)
    :param eval_winds: evaluation winds (``None``: adversarial with a table, else random)
    :param eval_budgets: evaluation budgets (``None``: each model's ``paper_budgets``)
    :param eval_filters: ``"on"``/``"off"`` (``None``: both with a table, else off)
    :param episodes: episodes per evaluation
    :param starts: start distribution (``None``: inside ``RA~_Q`` with a table, else the environment's)
    :param eval_seed: evaluation seed
    :param checkpoint: ``"best"`` or ``"final"``
    :param eval_own_budget: a run trained at one budget ``Q`` is evaluated only at that ``Q`` (it must be one of
        the evaluation budgets); runs trained with the budget drawn per episode are evaluated at every one. This
        compares policies trained at each ``Q`` with one policy for every budget at the cost of one grid.
    """

    models: tuple[str, ...] = ("pointmass",)
    algos: tuple[str, ...] = ("ppo",)
    methods: tuple[str, ...] = ("plain",)
    rules: tuple[str, ...] = ("switch",)
    budgets: tuple[Any, ...] = (None,)
    winds: tuple[str, ...] = ("random",)
    seeds: tuple[int, ...] = (0, 1, 2)
    variants: dict[str, dict[str, Any]] = field(default_factory=lambda: {"default": {}})
    tables: dict[str, str] = field(default_factory=dict)
    timesteps: int | None = None
    n_envs: int | None = None
    overrides: dict[str, Any] = field(default_factory=dict)
    eval_winds: tuple[str, ...] | None = None
    eval_budgets: tuple[float, ...] | None = None
    eval_filters: tuple[str, ...] | None = None
    episodes: int = 30
    starts: str | None = None
    eval_seed: int = 0
    checkpoint: str = "best"
    eval_own_budget: bool = False

    # ------------------------------------------------------------------------------------------ the grid

    def runs(self) -> list[SweepRun]:
        """Every training run of the grid, in a fixed order (models outermost, seeds innermost); a baseline
        method (not ``"plain"``) only with rule ``"none"``."""
        out = []
        for model in self.models:
            for algo in self.algos:
                for method in self.methods:
                    for rule in self.rules:
                        if method != "plain" and rule != "none":
                            continue
                        for budget in self.budgets:
                            for wind in self.winds:
                                for name, block in self.variants.items():
                                    for seed in self.seeds:
                                        out.append(self._run(model, algo, rule, parse_budget(budget), wind, name,
                                                             block, int(seed), method))
        return out

    def _run(self, model: str, algo: str, rule: str, budget: Any, wind: str, variant: str,
             block: dict[str, Any], seed: int, method: str = "plain") -> SweepRun:
        needs_table = rule != "none" or wind == "adversarial"
        safe = {**self.overrides.get("safe", {}), **block.get("safe", {})} if method != "plain" else {}
        return SweepRun(model=model, algo=algo, rule=rule, budget=budget, wind=wind, seed=seed, variant=variant,
                        table=self.tables.get(model) if needs_table else None, timesteps=self.timesteps,
                        n_envs=self.n_envs,
                        run_overrides={**self.overrides.get("run", {}), **block.get("run", {})},
                        algo_overrides={**self.overrides.get(algo, {}), **block.get(algo, {})},
                        method=method, safe_overrides=safe)

    def evaluations(self, model: str) -> list[EvalSetting]:
        """The evaluations of every run of ``model``."""
        from softreach.reach.models import get_model

        table = self.tables.get(model)
        winds = self.eval_winds or (("adversarial",) if table else ("random",))
        budgets = self.eval_budgets if self.eval_budgets is not None else get_model(model).paper_budgets
        filters = self.eval_filters or (("on", "off") if table else ("off",))
        starts = self.starts or ("inside" if table else "env")
        return [EvalSetting(wind=w, budget=None if q is None else float(q), filter=f, episodes=self.episodes,
                            starts=starts, seed=self.eval_seed, checkpoint=self.checkpoint, table=table)
                for w in winds for q in budgets for f in filters]

    def run_evaluations(self, run: SweepRun) -> list[EvalSetting]:
        """The evaluations of ``run``: its model's, or with :attr:`eval_own_budget` and a run trained at one
        ``Q``, those at that ``Q``."""
        evals = self.evaluations(run.model)
        if self.eval_own_budget and isinstance(run.budget, float):
            evals = [ev for ev in evals if ev.budget is not None and abs(ev.budget - run.budget) <= 1e-12]
        return evals

    # ------------------------------------------------------------------------------------------ checks

    def check(self) -> None:
        """Check every value before anything runs (``ValueError``/``FileNotFoundError`` naming the bad one).

        Each run's training settings go through :func:`softreach.agents.train.resolve`, the check that
        ``softreach train`` makes; each evaluation through :func:`softreach.agents.evaluate.check_spec`.
        """
        from softreach.reach.models import get_model

        from .evaluate import EvalSpec, check_spec
        from .safe_rl import METHODS
        from .safe_train import check_method, safe_config
        from .train import resolve

        axes = {"models": (self.models, MODELS), "algos": (self.algos, ALGOS), "methods": (self.methods, METHODS),
                "rules": (self.rules, FILTER_RULES),
                "winds": (self.winds, WINDS), "eval_winds": (self.eval_winds or (), WINDS),
                "eval_filters": (self.eval_filters or (), EVAL_FILTERS)}
        for name, (values, choices) in axes.items():
            if name not in ("eval_winds", "eval_filters") and not values:
                raise ValueError(f"{name} must not be empty")
            for v in values:
                check_choice(name.rstrip("s").replace("_", " "), v, choices)
        check_choice("checkpoint", self.checkpoint, CHECKPOINTS)
        if self.starts is not None:
            check_choice("start distribution", self.starts, STARTS)
        for s in self.seeds:
            if isinstance(s, bool) or not isinstance(s, int):
                raise ValueError(f"seeds must be integers, got {s!r}")
        if not self.seeds:
            raise ValueError("seeds must not be empty")
        if not self.variants:
            raise ValueError("variants must not be empty (the default is {'default': {}})")
        for m, path in self.tables.items():
            check_choice("model of a table", m, MODELS)
            if not Path(path).is_file():
                raise FileNotFoundError(f"table {path} of {m} does not exist (solve one with `softreach solve {m}`)")
        for where, block in [("overrides", self.overrides)] + [(f"variant {k!r}", b) for k, b in self.variants.items()]:
            if not isinstance(block, dict) or set(block) - set(OVERRIDE_SECTIONS):
                raise ValueError(f"{where} must be a table with sections {list(OVERRIDE_SECTIONS)}, got {block!r}")
        for b in self.budgets:
            parse_budget(b)
        for q in self.eval_budgets or ():
            if isinstance(q, bool) or not isinstance(q, (int, float)):
                raise ValueError(f"eval budgets must be numbers Q in seconds, got {q!r}")
        if not self.runs():
            raise ValueError(f"the grid has no run: methods {list(self.methods)} train only with rule 'none', "
                             f"and rules are {list(self.rules)}")
        for run in self.runs():
            if run.table is None and (run.rule != "none" or run.wind == "adversarial"):
                why = f"rule {run.rule!r}" if run.rule != "none" else "wind 'adversarial'"
                raise ValueError(f"{why} needs a table for {run.model}: give --table {run.model}=PATH")
            try:
                resolve(run.train_spec(out="unused"))
                check_method(run.method, run.train_spec(out="unused"))
                safe_config(run.safe_overrides)
            except TypeError as exc:  # dataclasses.replace with a field the config does not have
                raise ValueError(f"run {run.run_id} (variant {run.variant!r}): {exc}") from None
        if not isinstance(self.eval_own_budget, bool):
            raise ValueError(f"eval_own_budget must be true or false, got {self.eval_own_budget!r}")
        for run in self.runs():
            if not self.run_evaluations(run):
                raise ValueError(f"run {run.run_id} trains at Q={budget_text(run.budget)} and eval_own_budget "
                                 f"evaluates it only there: add {budget_text(run.budget)} to the evaluation budgets "
                                 f"{list(self.eval_budgets or get_model(run.model).paper_budgets)}")
        for model in self.models:
            horizon = get_model(model).horizon
            for ev in self.evaluations(model):
                check_budget(ev.budget, horizon)
                check_spec(EvalSpec(model=model, policy="random", filter=ev.table if ev.filter == "on" else None,
                                    budget=ev.budget, wind=ev.wind, table=ev.table, episodes=ev.episodes,
                                    starts=ev.starts, seed=ev.seed), policy_given=True)

    # ------------------------------------------------------------------------------------------ files

    def to_dict(self) -> dict[str, Any]:
        """The JSON form (the format of a sweep file, written into the output folder as ``sweep.json``)."""
        d = asdict(self)
        d["budgets"] = [budget_text(parse_budget(b)) for b in self.budgets]
        return {"schema": SWEEP_SCHEMA, **d}

    @classmethod
    def from_dict(cls, data: dict[str, Any]) -> SweepSpec:
        """A spec from a sweep file's contents; unknown keys are an error naming them."""
        data = {k: v for k, v in data.items() if k != "schema"}
        known = {f.name for f in fields(cls)}
        unknown = sorted(set(data) - known)
        if unknown:
            raise ValueError(f"unknown sweep setting(s) {unknown}; known: {sorted(known)}")
        for key in ("models", "algos", "methods", "rules", "budgets", "winds", "seeds", "eval_winds", "eval_budgets",
                    "eval_filters"):
            if key in data and data[key] is not None:
                value = data[key]
                data[key] = tuple(value) if isinstance(value, (list, tuple)) else (value,)
        if "budgets" in data:
            data["budgets"] = tuple(parse_budget(b) for b in data["budgets"])
        return cls(**data)


def load_sweep_file(path: str | Path) -> SweepSpec:
    """A :class:`SweepSpec` from a ``.json`` or ``.toml`` sweep file (keys: the fields of :class:`SweepSpec`).

    :raises FileNotFoundError: the file does not exist
    :raises ValueError: another format, a parse error or an unknown key (naming it)
    """
    path = Path(path)
    if not path.is_file():
        raise FileNotFoundError(f"sweep file {path} does not exist")
    text = path.read_text()
    try:
        if path.suffix == ".json":
            data = json.loads(text)
        elif path.suffix == ".toml":
            data = tomllib.loads(text)
        else:
            raise ValueError(f"sweep file {path} must end in .json or .toml")
    except (json.JSONDecodeError, tomllib.TOMLDecodeError) as exc:
        raise ValueError(f"sweep file {path}: {exc}") from None
    if not isinstance(data, dict):
        raise ValueError(f"sweep file {path} must hold a table/object of settings")
    return SweepSpec.from_dict(data)


__all__ = ["CHECKPOINTS", "EVAL_FILTERS", "EvalSetting", "FILTER_RULES", "SWEEP_SCHEMA", "SweepRun", "SweepSpec",
           "budget_text", "load_sweep_file", "parse_budget", "stable_hash"]
