"""The evaluation report as text: the summary lines ``softreach evaluate`` prints and the markdown comparison
table of the demo report."""

from __future__ import annotations

from typing import Any, Sequence

from softreach.reach.model_report import LANDING_WORDS, TaskWords


def _title(result) -> str:
    c = result.config
    if c.get("budget") is not None:
        q = f"Q={c['budget']:g}"
    else:
        q = "Q of each paper point" if c.get("starts") == "paper" else "Q drawn per episode"
    return (f"{c['model']}: {c['policy_name']}{' + filter (' + c['rule'] + ')' if c['filtered'] else ' (no filter)'}, "
            f"{c['wind']} wind, {c['starts']} starts, {q}")


def _pct(rate: dict[str, Any] | None) -> str:
    if rate is None or rate.get("value") is None:
        return "—"
    return f"{100 * rate['value']:.0f}% [{100 * rate['low']:.0f}, {100 * rate['high']:.0f}]"


def _num(m: dict[str, Any] | None, key: str = "mean", fmt: str = "{:.3f}") -> str:
    if m is None or m.get(key) is None:
        return "—"
    return fmt.format(m[key])


def _ci(m: dict[str, Any] | None) -> str:
    """``mean [low, high]`` of a Student-t interval, ``—`` where there is no sample."""
    if m is None or m.get("mean") is None:
        return "—"
    if m.get("low") is None or m.get("high") is None:
        return f"{m['mean']:.3f}"
    return f"{m['mean']:.3f} [{m['low']:.3f}, {m['high']:.3f}]"


def task_words(result) -> TaskWords:
    """The words of the evaluated model's task (:class:`~softreach.reach.problem.TaskWords`); the report's keys
    (``landing_rate``, ``touchdown_sink_rate``, ...) stay the same for every model."""
    from softreach.reach.registry import model_class

    return model_class(result.config["model"]).words


def summary_lines(result) -> list[str]:
    """A few human-readable lines of an evaluation's aggregates."""
    a = result.aggregates
    w = task_words(result)
    speed = (f"{w.arrival_speed}: {_num(a['touchdown_sink_rate'])} m/s  " if w.arrival_speed else "")
    names = {"landed": w.reached, "hard_violation": "hard violation", "timeout": "timeout"}
    outcomes = ", ".join(f"{names.get(k, k)} {v}" for k, v in a["outcomes"].items())
    lines = [_title(result), f"  episodes: {a['episodes']}  outcomes: {outcomes}",
             f"  {w.success}: {_pct(a['landing_rate'])}   hard violations: {_pct(a['hard_violation_rate'])}",
             f"  budget used: mean {_num(a['budget_used'])}  max {_num(a['budget_used'], 'max')}  "
             f"over Q (+{result.config['budget_tol']:g} s): {_pct(a['over_budget_rate'])}",
             f"  return: {_num(a['return'], fmt='{:.1f}')}  control effort: {_num(a['control_effort'])}  "
             f"{speed}{w.duration}: {_num(a.get('time_to_land'))} s"]
    if a["intervention_rate"] is not None:
        lines.append(f"  interventions: {_num(a['intervention_rate'])} of steps (mean per episode), in "
                     f"{_pct(a['intervened_episodes'])} of episodes")
    if "by_start" in a:
        bs = a["by_start"]
        lines.append(f"  starts inside RA~_Q: {bs['inside']['episodes']} ({w.reached} {_pct(bs['inside']['landing_rate'])}, "
                     f"hard {_pct(bs['inside']['hard_violation_rate'])}); outside: {bs['outside']['episodes']} "
                     f"({w.reached} {_pct(bs['outside']['landing_rate'])}, hard {_pct(bs['outside']['hard_violation_rate'])})")
    return lines


def comparison_header(words: TaskWords = TaskWords()) -> str:
    """The markdown header of :func:`comparison_row`'s columns, in the words of the model's task."""
    speed = f" {words.arrival_speed} [m/s] |" if words.arrival_speed else ""
    cols = 11 + (1 if words.arrival_speed else 0)
    return (f"| policy | wind | Q | {words.success} | hard violations | budget used: mean | max | over Q | "
            f"interventions | control effort |{speed} {words.duration} [s] |\n" + "|---" * cols + "|")


#: the header of the landing tasks' comparison table
COMPARISON_HEADER = comparison_header(LANDING_WORDS)


def comparison_row(label: str, result, words: TaskWords = TaskWords()) -> str:
    a = result.aggregates
    c = result.config
    q = "drawn" if c.get("budget") is None else f"{c['budget']:g}"
    inter = "—" if a["intervention_rate"] is None else f"{100 * a['intervention_rate']['mean']:.1f}%"
    hard = a["hard_violation_rate"]
    return (f"| {label} | {c['wind']} | {q} | {_pct(a['landing_rate'])} | {hard['count']}/{hard['n']} | "
            f"{_num(a['budget_used'])} | {_num(a['budget_used'], 'max')} | {a['over_budget_rate']['count']}/{a['episodes']} | "
            f"{inter} | {_ci(a['control_effort'])} |"
            + (f" {_ci(a.get('touchdown_sink_rate'))} |" if words.arrival_speed else "")
            + f" {_ci(a.get('time_to_land'))} |")


def comparison_table(rows: Sequence[tuple[str, Any]]) -> str:
    """A markdown table of ``(label, EvaluationResult)`` pairs, in the words of their model's task."""
    words = task_words(rows[0][1]) if rows else TaskWords()
    return "\n".join([comparison_header(words)] + [comparison_row(label, r, words) for label, r in rows])


__all__ = ["COMPARISON_HEADER", "comparison_header", "comparison_row", "comparison_table", "summary_lines", "task_words"]
