"""softreach.filters: a least-restrictive safety filter on a ``W_eps`` table (paper §V; docs/filters.md): the batched
core :class:`ValueFilter`, the ``gymnasium.Wrapper`` :class:`SafetyFilter`, and :class:`VecSafetyFilter` for SB3
(loaded at its first use: it imports stable-baselines3, and so torch, which the filter itself does not need)."""

from typing import Any

from .core import (AFTER_HORIZON, BLEND, CERTIFY_REASONS, FALLBACK, NO_PLAN, OPTIMAL, OUTSIDE, PASS,
                   PLAN_LAND, PLAN_SAFE, REASONS, RULES, UNCERTIFIED, ValueFilter)
from softreach.reach.proof.lookahead import Lookahead
from softreach.reach.tables.field import TableField
from .wrapper import SafetyFilter


def __getattr__(name: str) -> Any:
    if name != "VecSafetyFilter":
        raise AttributeError(f"module {__name__!r} has no attribute {name!r}")
    from .vector import VecSafetyFilter

    globals()[name] = VecSafetyFilter  # later look-ups skip this function
    return VecSafetyFilter


__all__ = ["AFTER_HORIZON", "BLEND", "CERTIFY_REASONS", "FALLBACK", "Lookahead", "NO_PLAN", "OPTIMAL",
           "OUTSIDE", "PASS", "PLAN_LAND", "PLAN_SAFE", "REASONS", "RULES", "SafetyFilter", "TableField",
           "UNCERTIFIED", "ValueFilter", "VecSafetyFilter"]
