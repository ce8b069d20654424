"""The evaluation report's JSON document (schema below, checked by :func:`validate_evaluation`).

The plots are in :mod:`softreach.agents.report_plots` and the text forms (summary lines, the markdown comparison
table) in :mod:`softreach.agents.report_text`; both are re-exported here.

JSON (``softreach evaluate --json PATH``), schema ``softreach.evaluation/1``::

    {
      "schema": "softreach.evaluation/1",
      "created": "2025-01-01T12:00:00",            # local time, ISO 8601
      "config": {...},                             # the evaluation's settings (EvalSpec fields and more)
      "aggregates": {...},                         # see AGGREGATE_FIELDS
      "episodes": [{...}, ...]                     # one row per episode, see EPISODE_FIELDS
    }

A rate is ``{"value", "low", "high", "count", "n"}`` (Wilson 95 % interval); a mean is
``{"mean", "low", "high", "std", "min", "max", "n"}`` (Student-t 95 % interval). ``null`` where there is no
data (e.g. the intervention rate without a filter, the sink rate when nothing landed).

Plots (``--plots DIR``): ``trajectories.png`` (Fig. 1 style: the sets and the closed-loop paths, filter
interventions marked), ``budget.png`` (Fig. 5/9 style: remaining budget ``z(t)``), ``budget_hist.png``
(budget used, against ``Q``), ``interventions.png`` (how often the filter acts along the episode) and, for a
trained policy, ``learning_curves.png`` (periodic evaluations and training episodes).
"""

from __future__ import annotations

import datetime as _dt
import json
import math
from pathlib import Path
from typing import Any

import numpy as np

# re-exported: callers take the whole report (document, plots, text) from this module
from .report_plots import (OUTCOME_COLOURS, learning_data, plot_budget_curves, plot_budget_histogram,
                           plot_interventions, plot_learning_curves, plot_trajectories, write_plots)
from .report_text import COMPARISON_HEADER, comparison_row, comparison_table, summary_lines

EVAL_SCHEMA = "softreach.evaluation/1"

RATE = "rate"
MEAN = "mean"
#: aggregate name -> (kind, meaning); kind "rate" / "mean" as in the module docstring, "rate?"/"mean?" may be null
AGGREGATE_FIELDS: dict[str, tuple[str, str]] = {
    "episodes": ("int", "number of episodes"),
    "landing_rate": (RATE, "episodes that reached the target inside C2"),
    "hard_violation_rate": (RATE, "episodes that left the hard constraint C1"),
    "over_budget_rate": (RATE, "episodes that used more than Q + budget_tol of budget"),
    "budget_used": (MEAN, "budget used Q - z_final [s]; also p50, p90 and excess_max = max(used - Q)"),
    "time_outside_c2": (MEAN, "control periods that ended outside C2, times their length [s]"),
    "touchdown_sink_rate": (MEAN, "downward speed at touchdown [m/s], landed episodes only"),
    "control_effort": (MEAN, "mean squared normalised applied action over the horizon (1 = full deflection throughout)"),
    "time_to_land": (MEAN, "episode duration [s], landed episodes only"),
    "return": (MEAN, "sum of the environment's rewards (unscaled)"),
    "intervention_rate": (MEAN + "?", "per episode: steps in which the filter changed the action / steps; null without a filter"),
    "intervened_episodes": (RATE + "?", "episodes in which the filter acted at least once; null without a filter"),
    "outcomes": ("dict", "counts of 'landed', 'hard_violation', 'timeout'"),
}
#: aggregates added to ``softreach.evaluation/1`` after its first documents: written always, required never
ADDED_AGGREGATES = frozenset({"time_to_land"})
#: per-episode field -> (type, meaning)
EPISODE_FIELDS: dict[str, tuple[str, str]] = {
    "episode": ("int", "index"),
    "seed": ("int", "reset seed of the episode (gusts)"),
    "start_state": ("list", "physical start state"),
    "budget": ("float", "budget Q [s]"),
    "start_value": ("float?", "W_eps(0, x0, max(Q, r)) of the table; null without a table or outside it"),
    "start_inside": ("bool?", "x0 in RA~_Q (the table's set); null without a table"),
    "landed": ("bool", "reached the target inside C2"),
    "hard_violation": ("bool", "left C1"),
    "over_budget": ("bool", "budget_used > Q + budget_tol"),
    "budget_used": ("float", "Q - z at the end [s]"),
    "budget_left": ("float", "z at the end [s] (negative once exceeded)"),
    "time_outside_c2": ("float", "control periods ending outside C2 times their length [s]"),
    "touchdown_sink_rate": ("float?", "downward speed at touchdown [m/s]; null if not landed or the model has none"),
    "control_effort": ("float", "mean squared normalised applied action over the horizon"),
    "interventions": ("int?", "steps in which the filter changed the action; null without a filter"),
    "intervention_rate": ("float?", "interventions / steps; null without a filter"),
    "min_value": ("float?", "smallest W~ the filter saw; null without a filter"),
    "steps": ("int", "control periods"),
    "duration": ("float", "simulated time [s]"),
    "return": ("float", "sum of rewards"),
    "outcome": ("str", "'landed', 'hard_violation' or 'timeout'"),
    "final_state": ("list", "physical state at the end"),
}
CONFIG_FIELDS = ("model", "policy", "filter", "rule", "budget", "wind", "table", "episodes", "starts", "seed",
                 "filtered", "budget_tol")


def _json_default(o: Any):
    if isinstance(o, (np.floating,)):
        return float(o)
    if isinstance(o, (np.integer,)):
        return int(o)
    if isinstance(o, np.bool_):
        return bool(o)
    if isinstance(o, np.ndarray):
        return o.tolist()
    if isinstance(o, Path):
        return str(o)
    raise TypeError(f"not JSON serialisable: {type(o).__name__}")


def _finite(o: Any) -> Any:
    """Replace non-finite floats by ``None`` (JSON has no inf/NaN)."""
    if isinstance(o, dict):
        return {k: _finite(v) for k, v in o.items()}
    if isinstance(o, (list, tuple)):
        return [_finite(v) for v in o]
    if isinstance(o, (float, np.floating)) and not math.isfinite(float(o)):
        return None
    return o


def evaluation_document(result) -> dict[str, Any]:
    """The JSON document of an :class:`~softreach.agents.evaluate.EvaluationResult`."""
    doc = {"schema": EVAL_SCHEMA, "created": _dt.datetime.now().isoformat(timespec="seconds"),
           "config": result.config, "aggregates": result.aggregates, "episodes": result.episodes}
    return _finite(json.loads(json.dumps(doc, default=_json_default)))


def write_json(result, path: str | Path) -> Path:
    """Write :func:`evaluation_document` to ``path`` (checked against the schema first)."""
    doc = evaluation_document(result)
    validate_evaluation(doc)
    path = Path(path)
    if str(path.parent) and not path.parent.is_dir():
        raise ValueError(f"--json directory {path.parent} does not exist")
    path.write_text(json.dumps(doc, indent=1, allow_nan=False))
    return path


def _check_type(where: str, value: Any, kind: str) -> None:
    optional = kind.endswith("?")
    kind = kind.rstrip("?")
    if value is None:
        if optional:
            return
        raise ValueError(f"{where} must not be null")
    ok = {
        "int": lambda v: isinstance(v, int) and not isinstance(v, bool),
        "float": lambda v: isinstance(v, (int, float)) and not isinstance(v, bool),
        "bool": lambda v: isinstance(v, bool),
        "str": lambda v: isinstance(v, str),
        "list": lambda v: isinstance(v, list),
        "dict": lambda v: isinstance(v, dict),
    }
    if kind == RATE:
        if not isinstance(value, dict) or set(value) != {"value", "low", "high", "count", "n"}:
            raise ValueError(f"{where} must be a rate {{value, low, high, count, n}}, got {value!r}")
        if value["n"] and not (0 <= value["low"] <= value["value"] <= value["high"] <= 1):
            raise ValueError(f"{where}: need 0 <= low <= value <= high <= 1, got {value!r}")
        return
    if kind == MEAN:
        need = {"mean", "low", "high", "std", "min", "max", "n"}
        if not isinstance(value, dict) or not need <= set(value):
            raise ValueError(f"{where} must be a mean with {sorted(need)}, got {value!r}")
        if value["n"] and not (value["low"] <= value["mean"] + 1e-12 and value["mean"] <= value["high"] + 1e-12
                               and value["min"] <= value["max"]):
            raise ValueError(f"{where}: need low <= mean <= high and min <= max, got {value!r}")
        return
    if not ok[kind](value):
        raise ValueError(f"{where} must be of type {kind}, got {value!r}")


def validate_evaluation(doc: dict[str, Any]) -> None:
    """Check a document against schema ``softreach.evaluation/1``; ``ValueError`` naming the first problem."""
    if not isinstance(doc, dict):
        raise ValueError(f"an evaluation document is a JSON object, got {type(doc).__name__}")
    if doc.get("schema") != EVAL_SCHEMA:
        raise ValueError(f"schema must be {EVAL_SCHEMA!r}, got {doc.get('schema')!r}")
    for key in ("created", "config", "aggregates", "episodes"):
        if key not in doc:
            raise ValueError(f"missing top-level field {key!r}")
    for key in CONFIG_FIELDS:
        if key not in doc["config"]:
            raise ValueError(f"config lacks {key!r}")
    agg = doc["aggregates"]
    for key, (kind, _) in AGGREGATE_FIELDS.items():
        if key not in agg and key in ADDED_AGGREGATES:
            continue  # a document written before the field was added to the schema
        if key not in agg:
            raise ValueError(f"aggregates lack {key!r}")
        _check_type(f"aggregates.{key}", agg[key], kind)
    if not isinstance(doc["episodes"], list) or len(doc["episodes"]) != agg["episodes"]:
        raise ValueError(f"episodes must be a list of {agg['episodes']} rows")
    for i, row in enumerate(doc["episodes"]):
        for key, (kind, _) in EPISODE_FIELDS.items():
            if key not in row:
                raise ValueError(f"episodes[{i}] lacks {key!r}")
            _check_type(f"episodes[{i}].{key}", row[key], kind)
    landed = sum(r["landed"] for r in doc["episodes"])
    if agg["landing_rate"]["count"] != landed:
        raise ValueError(f"aggregates.landing_rate.count {agg['landing_rate']['count']} != {landed} landed episodes")


__all__ = ["AGGREGATE_FIELDS", "COMPARISON_HEADER", "CONFIG_FIELDS", "EPISODE_FIELDS", "EVAL_SCHEMA", "OUTCOME_COLOURS",
           "comparison_row", "comparison_table", "evaluation_document",
           "learning_data", "plot_budget_curves", "plot_budget_histogram", "plot_interventions",
           "plot_learning_curves", "plot_trajectories", "summary_lines", "validate_evaluation", "write_json",
           "write_plots"]
