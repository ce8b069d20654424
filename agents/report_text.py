"""The evaluation report as text: the summary lines ``softreach evaluate`` prints and the markdown comparison
table of the demo report."""

from __future__ import annotations

from typing import Any, Sequence


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


def summary_lines(result) -> list[str]:
    """A few human-readable lines of an evaluation's aggregates."""
    a = result.aggregates
    lines = [_title(result), f"  episodes: {a['episodes']}  outcomes: {a['outcomes']}",
             f"  landing rate: {_pct(a['landing_rate'])}   hard violations: {_pct(a['hard_violation_rate'])}",
             f"  budget used: mean {_num(a['budget_used'])}  max {_num(a['budget_used'], 'max')}  "
             f"over Q (+{result.config['budget_tol']:g} s): {_pct(a['over_budget_rate'])}",
             f"  return: {_num(a['return'], fmt='{:.1f}')}  control effort: {_num(a['control_effort'])}  "
             f"touchdown sink rate: {_num(a['touchdown_sink_rate'])} m/s  time to land: "
             f"{_num(a.get('time_to_land'))} s"]
    if a["intervention_rate"] is not None:
        lines.append(f"  interventions: {_num(a['intervention_rate'])} of steps (mean per episode), in "
                     f"{_pct(a['intervened_episodes'])} of episodes")
    if "by_start" in a:
        bs = a["by_start"]
        lines.append(f"  starts inside RA~_Q: {bs['inside']['episodes']} (landed {_pct(bs['inside']['landing_rate'])}, "
                     f"hard {_pct(bs['inside']['hard_violation_rate'])}); outside: {bs['outside']['episodes']} "
                     f"(landed {_pct(bs['outside']['landing_rate'])}, hard {_pct(bs['outside']['hard_violation_rate'])})")
    return lines


COMPARISON_HEADER = ("| policy | wind | Q | landing rate | hard violations | budget used: mean | max | over Q | "
                     "interventions | control effort | touchdown sink rate [m/s] | time to land [s] |\n"
                     "|---|---|---|---|---|---|---|---|---|---|---|---|")


def comparison_row(label: str, result) -> str:
    a = result.aggregates
    c = result.config
    q = "drawn" if c.get("budget") is None else f"{c['budget']:g}"
    inter = "—" if a["intervention_rate"] is None else f"{100 * a['intervention_rate']['mean']:.1f}%"
    hard = a["hard_violation_rate"]
    return (f"| {label} | {c['wind']} | {q} | {_pct(a['landing_rate'])} | {hard['count']}/{hard['n']} | "
            f"{_num(a['budget_used'])} | {_num(a['budget_used'], 'max')} | {a['over_budget_rate']['count']}/{a['episodes']} | "
            f"{inter} | {_ci(a['control_effort'])} | {_ci(a.get('touchdown_sink_rate'))} | "
            f"{_ci(a.get('time_to_land'))} |")


def comparison_table(rows: Sequence[tuple[str, Any]]) -> str:
    """A markdown table of ``(label, EvaluationResult)`` pairs."""
    return "\n".join([COMPARISON_HEADER] + [comparison_row(label, r) for label, r in rows])


__all__ = ["COMPARISON_HEADER", "comparison_row", "comparison_table", "summary_lines"]
