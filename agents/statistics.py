"""The statistics of an evaluation: rates with Wilson score intervals, means with Student-t intervals (both
95 %), and the aggregates of the per-episode rows (:func:`aggregate`)."""

from __future__ import annotations

import math
from typing import Any

import numpy as np

Z95 = 1.959963984540054


def wilson(successes: int, n: int, z: float = Z95) -> dict[str, Any]:
    """A rate with its Wilson score interval: ``{"value", "low", "high", "count", "n"}`` (``value`` is ``None``
    for ``n = 0``)."""
    if n == 0:
        return {"value": None, "low": None, "high": None, "count": 0, "n": 0}
    p = successes / n
    den = 1.0 + z * z / n
    centre = (p + z * z / (2 * n)) / den
    half = z * math.sqrt(p * (1 - p) / n + z * z / (4 * n * n)) / den
    return {"value": p, "low": min(p, max(0.0, centre - half)), "high": max(p, min(1.0, centre + half)), "count": int(successes),
            "n": int(n)}


def mean_ci(values: Any, lower: float = -math.inf, upper: float = math.inf) -> dict[str, Any]:
    """Mean with a Student-t 95 % interval, plus ``std``, ``min``, ``max``, ``n`` (NaNs dropped; ``None`` where
    there is no data; the interval collapses to the mean for one value).

    :param lower: the smallest value the quantity can take (0 for a duration): the interval is cut there, which
        keeps its coverage (the true mean lies in the range) and never reports, say, a negative time
    :param upper: the largest such value
    """
    v = np.asarray([x for x in values if x is not None and not (isinstance(x, float) and math.isnan(x))],
                   dtype=np.float64)
    n = len(v)
    if n == 0:
        return {"mean": None, "low": None, "high": None, "std": None, "min": None, "max": None, "n": 0}
    m = float(v.mean())
    if n > 1:
        from scipy.stats import t as student

        s = float(v.std(ddof=1))
        half = float(student.ppf(0.975, n - 1)) * s / math.sqrt(n)
    else:
        s, half = 0.0, 0.0
    return {"mean": m, "low": max(m - half, lower), "high": min(m + half, upper), "std": s, "min": float(v.min()), "max": float(v.max()),
            "n": int(n)}


def aggregate(rows: list[dict[str, Any]], filtered: bool) -> dict[str, Any]:
    """The aggregates of per-episode rows (see ``docs/agents.md`` for the fields)."""
    n = len(rows)
    col = lambda k: [r[k] for r in rows]  # noqa: E731
    used = np.array(col("budget_used"), dtype=np.float64)
    out: dict[str, Any] = {
        "episodes": n,
        "landing_rate": wilson(sum(col("landed")), n),
        "hard_violation_rate": wilson(sum(col("hard_violation")), n),
        "over_budget_rate": wilson(sum(col("over_budget")), n),
        "budget_used": {**mean_ci(used, lower=0.0), "p50": float(np.median(used)) if n else None,
                        "p90": float(np.quantile(used, 0.9)) if n else None,
                        "excess_max": float(np.max(used - np.array(col("budget")))) if n else None},
        "time_outside_c2": mean_ci(col("time_outside_c2"), lower=0.0),
        "touchdown_sink_rate": mean_ci([r["touchdown_sink_rate"] for r in rows if r["landed"]]),
        "control_effort": mean_ci(col("control_effort"), lower=0.0, upper=1.0),
        "time_to_land": mean_ci([r["duration"] for r in rows if r["landed"]], lower=0.0),
        "return": mean_ci(col("return")),
        "intervention_rate": mean_ci(col("intervention_rate"), lower=0.0, upper=1.0) if filtered else None,
        "intervened_episodes": wilson(sum(1 for r in rows if r["interventions"]), n) if filtered else None,
        "outcomes": {k: sum(1 for r in rows if r["outcome"] == k) for k in ("landed", "hard_violation", "timeout")},
    }
    inside = [r for r in rows if r["start_inside"] is not None]
    if inside:
        split = {}
        for key, sel in (("inside", True), ("outside", False)):
            rs = [r for r in inside if r["start_inside"] is sel]
            split[key] = {"episodes": len(rs),
                          "landing_rate": wilson(sum(r["landed"] for r in rs), len(rs)),
                          "hard_violation_rate": wilson(sum(r["hard_violation"] for r in rs), len(rs)),
                          "over_budget_rate": wilson(sum(r["over_budget"] for r in rs), len(rs))}
        out["by_start"] = split
    return out


__all__ = ["Z95", "aggregate", "mean_ci", "wilson"]
